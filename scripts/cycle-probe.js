// Shared by the cycle reports (maxl-cycles.js, module-cycles.js): loads a
// probe ELF (thumbv6m-none-eabi, linked into SRAM) into rp2040js's
// Cortex-M0+ core, which counts cycles per instruction (ALU 1, load/store
// 2, taken branch 2, BL 3, push/pop 1+N, single-cycle MULS), and runs it
// to its final `bkpt 0xff`, handing every other `bkpt` to `onMarker`.
'use strict';
const fs = require('fs');
const path = require('path');

/// Runs the probe at `elfPath` with rp2040js from `jsDir`. `onMarker(code,
/// core)` is called at each `bkpt code` (code 0xee: the probe panicked).
function runProbe(elfPath, jsDir, onMarker, maxInstructions) {
  const { RP2040 } = require(path.join(jsDir, 'node_modules', 'rp2040js'));
  const elf = fs.readFileSync(elfPath);
  if (elf.readUInt32BE(0) !== 0x7f454c46 || elf[4] !== 1 || elf[5] !== 1) {
    throw new Error('not a 32-bit little-endian ELF');
  }
  const entry = elf.readUInt32LE(24);
  const phoff = elf.readUInt32LE(28);
  const phentsize = elf.readUInt16LE(42);
  const phnum = elf.readUInt16LE(44);

  const mcu = new RP2040();
  const RAM = 0x20000000;
  for (let i = 0; i < phnum; i++) {
    const o = phoff + i * phentsize;
    const type = elf.readUInt32LE(o);
    const offset = elf.readUInt32LE(o + 4);
    const paddr = elf.readUInt32LE(o + 12);
    const filesz = elf.readUInt32LE(o + 16);
    if (type !== 1 || filesz === 0) continue; // PT_LOAD with bytes
    if (paddr < RAM || paddr + filesz > RAM + mcu.sram.length) {
      throw new Error(`segment at 0x${paddr.toString(16)} is not in SRAM`);
    }
    mcu.sram.set(elf.subarray(offset, offset + filesz), paddr - RAM);
  }

  const core = mcu.core;
  core.SP = RAM + 256 * 1024;
  core.PC = entry & ~1;
  let done = false;
  mcu.onBreak = (code) => {
    if (code === 0xff) { done = true; return; }
    if (code === 0xee) throw new Error('probe panicked');
    onMarker(code, core);
  };
  for (let n = 0; !done; n++) {
    if (n > maxInstructions) throw new Error('probe did not finish');
    core.executeInstruction();
  }
}

module.exports = { runProbe };
