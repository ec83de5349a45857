// Runs the maxl cycle probe (maxl/cycle-probe, thumbv6m-none-eabi ELF
// linked into SRAM) on rp2040js's Cortex-M0+ core and prints the cycles
// between its bkpt marker pairs. Usage: node maxl-cycles.js ELF RP2040JS_DIR
'use strict';
const fs = require('fs');
const path = require('path');

const [elfPath, jsDir] = process.argv.slice(2);
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

const marks = {};
const r0At = {};
let done = false;
mcu.onBreak = (code) => {
  if (code === 0xff) { done = true; return; }
  if (code === 0xee) throw new Error('probe panicked');
  marks[code] = core.cycles;
  r0At[code] = core.registers[0];
};
for (let n = 0; !done; n++) {
  if (n > 50e6) throw new Error('probe did not finish');
  core.executeInstruction();
}

// Cycles between markers a and b, less the cost of an empty marker pair.
const overhead = marks[1] - marks[0];
const span = (a, b) => marks[b] - marks[a] - overhead;
const perSeg = r0At[7];
const rows = [
  ['TickEval::load (per segment, 1024 us / 10 us ticks, du0 = 3)', span(2, 3)],
  ['TickEval::load at 16384 us / 10 us ticks', span(22, 23)],
  ['TickEval::load, differences >= 2^27 raw (i128 path)', span(24, 25)],
  ['TickEval::next (one tick, call + return)', span(4, 5)],
  [`TickEval::next in a loop, per tick (${perSeg} ticks)`, (span(6, 7) / perSeg).toFixed(1)],
  ['Point::eval for Fx (i64), position only', span(8, 9)],
  ['Point::eval for Fx (i64), pos + vel + acc + jerk', span(10, 11)],
  ['StepGen::tick (with a step)', span(12, 13)],
  ['PhaseOut::coils', span(14, 15)],
  ['ISR body: TickEval::next + StepGen::tick', span(16, 17)],
  ['Limiter<Fx>::push (clamped point)', span(18, 19)],
  ['Limiter<Fx>::push (point within limits)', span(20, 21)],
];
const ticks = perSeg + 1;
const load = span(2, 3);
const loop = span(6, 7) / perSeg;
console.log('Cortex-M0+ cycles (rp2040js 1.4.1 core model, code and data in SRAM;');
console.log(`marker overhead ${overhead} cycle(s) subtracted)`);
for (const [name, c] of rows) console.log(`${String(c).padStart(8)}  ${name}`);
console.log(`amortized per tick at 1024 us / 10 us: ${(loop + load / ticks).toFixed(1)} ` +
  `(${loop.toFixed(1)} per tick + ${load} setup / ${ticks} ticks)`);
console.log(`share of a 125 MHz core at 100 kHz: ${((loop + load / ticks) / 1250 * 100).toFixed(1)} %`);
