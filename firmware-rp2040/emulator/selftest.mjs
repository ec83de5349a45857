// Self-test of the bridge's pieces that need no firmware: ELF loading, the
// fake ROM (table lookup, erase/program through the real BKPT path), the SSI
// flash-id replies, XIP_CTRL, the UART fixes, PIO timing and edge counting,
// CDC descriptor parsing, and the CLI's error exits.
//   node selftest.mjs   (or npm test)

import test from 'node:test';
import assert from 'node:assert/strict';
import { spawnSync, spawn } from 'node:child_process';
import net from 'node:net';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { parseElf, loadElfIntoFlash, checkBootImage, ElfError } from './elf.mjs';
import { buildRomImage, tableLookup, romCode, stubAddress, ROM_FUNCTIONS } from './rom.mjs';
import { Chip, makeLogger, NS_PER_CYCLE } from './chip.mjs';
import { parseUniqueId } from './ssi.mjs';
import { EdgeCounter } from './edges.mjs';
import { parseCdcConfig } from './usb-host.mjs';
import { gpioReport } from './control.mjs';
import { PinInputs } from './pins.mjs';
import { TcpLink } from './tcp-link.mjs';
import { Runner } from './runner.mjs';
import { ControlServer } from './control.mjs';

const here = path.dirname(fileURLToPath(import.meta.url));
const FLASH_SIZE = 256 * 1024;
const UID = '0123456789abcdef';

function newChip(hooks = {}, fastPath = true) {
  return new Chip({
    fastPath,
    flash: new Uint8Array(FLASH_SIZE).fill(0xff),
    flashSize: FLASH_SIZE,
    uniqueId: parseUniqueId(UID),
    logger: makeLogger(),
    hooks,
  });
}

/** ELF32 LE ARM with the given program headers ({type, paddr, vaddr, data, memsz}). */
function makeElf(phdrs, machine = 40) {
  const ehsize = 52;
  const phentsize = 32;
  let dataOff = ehsize + phentsize * phdrs.length;
  const blobs = [];
  const table = phdrs.map((p) => {
    const off = dataOff;
    dataOff += p.data.length;
    blobs.push(p.data);
    return { ...p, off };
  });
  const out = new Uint8Array(dataOff);
  const dv = new DataView(out.buffer);
  out.set([0x7f, 0x45, 0x4c, 0x46, 1, 1, 1], 0);
  dv.setUint16(16, 2, true); // ET_EXEC
  dv.setUint16(18, machine, true);
  dv.setUint32(20, 1, true);
  dv.setUint32(24, 0x10000101, true);
  dv.setUint32(28, ehsize, true);
  dv.setUint16(40, ehsize, true);
  dv.setUint16(42, phentsize, true);
  dv.setUint16(44, phdrs.length, true);
  table.forEach((p, i) => {
    const o = ehsize + i * phentsize;
    dv.setUint32(o, p.type ?? 1, true);
    dv.setUint32(o + 4, p.off, true);
    dv.setUint32(o + 8, p.vaddr ?? p.paddr, true);
    dv.setUint32(o + 12, p.paddr, true);
    dv.setUint32(o + 16, p.data.length, true);
    dv.setUint32(o + 20, p.memsz ?? p.data.length, true);
    dv.setUint32(o + 24, 5, true);
  });
  let o = ehsize + phentsize * phdrs.length;
  for (const b of blobs) {
    out.set(b, o);
    o += b.length;
  }
  return out;
}

/** Minimal boot image: boot2 bytes, vector table (SP, reset) at 0x100. */
function bootImageSegments() {
  const boot2 = new Uint8Array(256).fill(0x11);
  const vectors = new Uint8Array(8);
  new DataView(vectors.buffer).setUint32(0, 0x20040000, true);
  new DataView(vectors.buffer).setUint32(4, 0x10000201, true);
  return [
    { paddr: 0x10000000, data: boot2 },
    { paddr: 0x10000100, data: vectors },
    { paddr: 0x10000300, vaddr: 0x20000000, data: Uint8Array.of(1, 2, 3, 4) }, // .data: stored in flash
    { paddr: 0x20000100, data: new Uint8Array(0), memsz: 64 }, // .bss: nothing stored
    { type: 4, paddr: 0, data: Uint8Array.of(9, 9) }, // PT_NOTE: ignored
  ];
}

/** Calls a ROM routine through the core: LR points at `b .` in RAM. */
function romCall(chip, fnAddr, args) {
  const { rp, core } = chip;
  rp.writeUint16(0x20000000, 0xe7fe); // b .
  args.forEach((a, i) => (core.registers[i] = a >>> 0));
  core.LR = 0x20000001;
  core.PC = fnAddr & ~1;
  for (let i = 0; i < 4 && core.PC !== 0x20000000; i++) core.executeInstruction();
  assert.equal(core.PC, 0x20000000, 'ROM stub returned to the caller');
  return core.registers[0];
}

function romFunction(chip, tag) {
  const { rp } = chip;
  const lookup = rp.readUint16(0x18);
  const table = rp.readUint16(0x14);
  return romCall(chip, lookup, [table, romCode(tag)]);
}

test('ELF: PT_LOAD segments land in flash by physical address', () => {
  const elf = parseElf(makeElf(bootImageSegments()));
  assert.equal(elf.segments.length, 3);
  const flash = new Uint8Array(FLASH_SIZE).fill(0xff);
  assert.equal(loadElfIntoFlash(flash, elf), 256 + 8 + 4);
  assert.equal(flash[0], 0x11);
  assert.deepEqual([...flash.subarray(0x300, 0x304)], [1, 2, 3, 4]);
  assert.equal(flash[0x304], 0xff);
  assert.deepEqual(checkBootImage(flash), []);
});

test('ELF: clear errors for bad input', () => {
  assert.throws(() => parseElf(new Uint8Array(64)), /not an ELF/);
  assert.throws(() => parseElf(makeElf(bootImageSegments(), 62)), /not ARM/);
  const outside = parseElf(makeElf([{ paddr: 0x10000000 + FLASH_SIZE, data: Uint8Array.of(1) }]));
  assert.throws(() => loadElfIntoFlash(new Uint8Array(FLASH_SIZE), outside), ElfError);
  const blank = new Uint8Array(FLASH_SIZE).fill(0xff);
  assert.ok(checkBootImage(blank).some((p) => /boot2/.test(p)));
});

test('ROM: table layout and lookup', () => {
  const rom = buildRomImage();
  const dv = new DataView(rom.buffer);
  const read16 = (a) => dv.getUint16(a, true);
  assert.deepEqual([...rom.subarray(0x10, 0x13)], [0x4d, 0x75, 0x01]);
  assert.equal(read16(0x18) & 1, 1, 'lookup pointer is a Thumb address');
  for (const [name, tag] of ROM_FUNCTIONS) {
    if (!tag) continue;
    assert.equal(tableLookup(read16, read16(0x14), romCode(tag)), stubAddress(name) | 1, tag);
  }
  assert.equal(tableLookup(read16, read16(0x14), romCode('ZZ')), 0, 'unknown code gives 0, as the real ROM');
  assert.notEqual(tableLookup(read16, read16(0x16), romCode('CR')), 0, 'data table has the copyright string');
});

test('ROM: lookup, erase and program through the core (BKPT stubs)', () => {
  let writes = 0;
  const chip = newChip({ onFlashWrite: () => writes++ });
  const { rp } = chip;
  chip.rp.flash.fill(0x00, 0, 0x3000);
  const erase = romFunction(chip, 'RE');
  const program = romFunction(chip, 'RP');
  assert.equal(erase, stubAddress('flash_range_erase') | 1);
  assert.equal(program, stubAddress('flash_range_program') | 1);

  romCall(chip, erase, [0x1000, 4096, 1 << 31, 0]);
  assert.equal(chip.rp.flash[0x0fff], 0x00, 'sector before untouched');
  assert.ok(chip.rp.flash.subarray(0x1000, 0x2000).every((b) => b === 0xff), 'sector erased');
  assert.equal(chip.rp.flash[0x2000], 0x00, 'sector after untouched');
  assert.ok(chip.extraNs >= 40e6, 'erase takes emulated time');

  for (let i = 0; i < 256; i++) rp.writeUint8(0x20001000 + i, i);
  romCall(chip, program, [0x1000, 0x20001000, 256]);
  assert.deepEqual([...chip.rp.flash.subarray(0x1000, 0x1004)], [0, 1, 2, 3]);
  assert.equal(rp.readUint8(0x10001000 + 200), 200, 'visible through XIP');
  for (let i = 0; i < 256; i++) rp.writeUint8(0x20001000 + i, 0xf0);
  romCall(chip, program, [0x1000, 0x20001000, 256]);
  assert.equal(chip.rp.flash[0x1000 + 0x0f], 0x00, 'NOR program only clears bits');
  assert.equal(chip.rp.flash[0x1000 + 0xff], 0xf0);
  assert.equal(writes, 3);

  const flush = romFunction(chip, 'FC');
  romCall(chip, flush, []);
  const memcpy44 = romFunction(chip, 'C4');
  romCall(chip, memcpy44, [0x20002000, 0x10001000, 16]);
  assert.equal(rp.readUint32(0x20002000), 0x03020100 & 0xf0f0f0f0);
});

test('ROM: unknown BKPT and reset_to_usb_boot halt with a reason', () => {
  const reasons = [];
  const chip = newChip({ onHalt: (r) => reasons.push(r) });
  chip.rp.writeUint16(0x20000000, 0xbe07); // bkpt #7 outside the ROM
  chip.core.PC = 0x20000000;
  chip.core.executeInstruction();
  assert.match(reasons[0], /BKPT #7 at 0x20000000/);
  romCall(chip, romFunction(chip, 'UB'), [0, 0]);
  assert.match(reasons[1], /reset_to_usb_boot/);
});

test('SSI: unique id (0x4B) and JEDEC id (0x9F) as embassy-rp reads them', () => {
  const chip = newChip();
  const { rp } = chip;
  const SSI = 0x18000000;
  const command = (cmd, frames) => {
    rp.writeUint32(SSI + 0x08, 0);
    rp.writeUint32(SSI + 0x00, rp.readUint32(SSI) | 0x300); // TMOD = EEPROM read
    rp.writeUint32(SSI + 0x04, frames - 1);
    rp.writeUint32(SSI + 0x08, 1);
    rp.writeUint8(SSI + 0x60, cmd);
    const out = [];
    for (let i = 0; i < frames; i++) {
      assert.ok(rp.readUint32(SSI + 0x28) & 8, 'RX FIFO not empty');
      out.push(rp.readUint8(SSI + 0x60));
    }
    rp.writeUint32(SSI + 0x08, 0);
    return out;
  };
  const uid = command(0x4b, 12).slice(4);
  assert.equal(Buffer.from(uid).toString('hex'), UID);
  assert.deepEqual(command(0x9f, 3), [0xef, 0x40, 0x15]);
  assert.throws(() => parseUniqueId('123'), /16 hex digits/);
  assert.equal(Buffer.from(parseUniqueId('0x00112233:44556677')).toString('hex'), '0011223344556677');
});

test('XIP_CTRL: stream counter reads 0 and FIFO empty', () => {
  const chip = newChip();
  assert.equal(chip.rp.readUint32(0x14000018), 0);
  assert.equal(chip.rp.readUint32(0x14000008) & 2, 2);
});

test('UART: storage-backed registers, TX interrupt only after a data write', () => {
  const chip = newChip();
  const { rp, core } = chip;
  const U = 0x40034000;
  const UART0_IRQ = 20;
  for (const off of [0x04, 0x34, 0x48]) assert.notEqual(rp.readUint32(U + off), 0xffffffff, `0x${off.toString(16)}`);
  rp.writeUint32(U + 0x48, 0);
  assert.equal(rp.readUint32(U + 0x48), 0, 'DMACR: no RXDMAE');
  rp.writeUint32(U + 0x38, 1 << 5); // IMSC: TX
  rp.writeUint32(U + 0x44, 0x7ff); // ICR
  assert.equal(core.pendingInterrupts & (1 << UART0_IRQ), 0, 'no TX interrupt after clearing it');
  rp.readUint32(U + 0x18); // reading flags must not re-raise it
  assert.equal(core.pendingInterrupts & (1 << UART0_IRQ), 0);
  const sent = [];
  rp.uart[0].onByte = (b) => sent.push(b);
  rp.writeUint32(U + 0x00, 0x41);
  assert.deepEqual(sent, [0x41]);
  assert.notEqual(core.pendingInterrupts & (1 << UART0_IRQ), 0, 'TX interrupt after a data write');
});

test('UART feeder: never overfills the 32-byte FIFO, paces at the baud rate', () => {
  const chip = newChip();
  const { rp, clock } = chip;
  const U = 0x40034000;
  rp.writeUint32(U + 0x24, 67); // IBRD/FBRD: 115200 baud at 125 MHz
  rp.writeUint32(U + 0x28, 52);
  rp.writeUint32(U + 0x30, 0x301); // UARTEN | TXE | RXE
  const feeder = chip.uartFeeders[0];
  feeder.push(new Uint8Array(100).fill(7));
  clock.tick(100e6); // 100 ms, nobody reading
  assert.equal(rp.uart[0].rxFIFO.itemCount, 32);
  assert.equal(feeder.pending, 68);
  for (let i = 0; i < 32; i++) rp.readUint32(U);
  const byteNs = 10e9 / rp.uart[0].baudRate;
  clock.tick(byteNs * 10.5);
  assert.ok(Math.abs(rp.uart[0].rxFIFO.itemCount - 11) <= 1, `~11 bytes in 10.5 byte times, got ${rp.uart[0].rxFIFO.itemCount}`);
});

test('edges: SIO-driven step/dir pins counted with sign', () => {
  const chip = newChip();
  const { rp } = chip;
  const edges = new EdgeCounter();
  for (const pin of [2, 3]) rp.writeUint32(0x40014000 + 8 * pin + 4, 5); // funcsel SIO
  rp.writeUint32(0xd0000020, 0b1100); // GPIO_OE
  edges.start(rp.gpio, 2, 3);
  const set = (v) => rp.writeUint32(0xd0000010, v);
  set(0b1000); // dir high
  for (let i = 0; i < 5; i++) {
    set(0b1100);
    set(0b1000);
  }
  set(0b0000); // dir low
  for (let i = 0; i < 3; i++) {
    set(0b0100);
    set(0b0000);
  }
  assert.deepEqual([edges.position, edges.up, edges.down], [2, 5, 3]);
  const report = gpioReport(rp.gpio);
  assert.equal(report.pins[2].func, 'sio');
  assert.equal(report.driven & 0b1100, 0b1100);
});

test('pins: inputs follow pulls and own output unless forced', () => {
  const chip = newChip();
  const { rp } = chip;
  const inputs = new PinInputs();
  inputs.attach(rp.gpio);
  const PADS = 0x4001c000;
  const gpioIn = () => rp.readUint32(0xd0000004);
  rp.writeUint32(PADS + 4 + 4 * 5, 0b1001010); // GPIO5: input enable, pull-up
  assert.ok(gpioIn() & (1 << 5), 'pulled-up input reads high');
  rp.writeUint32(PADS + 4 + 4 * 5, 0b1000110); // pull-down
  assert.equal(gpioIn() & (1 << 5), 0, 'pulled-down input reads low');
  inputs.force(5, true);
  assert.ok(gpioIn() & (1 << 5), 'forced high');
  rp.writeUint32(PADS + 4 + 4 * 5, 0b1000110);
  assert.ok(gpioIn() & (1 << 5), 'forcing wins over the pull');
  inputs.force(5, null);
  assert.equal(gpioIn() & (1 << 5), 0, 'released: back to the pull');
  rp.writeUint32(PADS + 4 + 4 * 4, 0b1000000); // GPIO4: input enable (the pad reads what it drives)
  rp.writeUint32(0x40014000 + 8 * 4 + 4, 5); // GPIO4 SIO output
  rp.writeUint32(0xd0000020, 1 << 4);
  rp.writeUint32(0xd0000010, 1 << 4);
  assert.ok(gpioIn() & (1 << 4), 'an output reads back its level');
  rp.writeUint32(0xd0000010, 0);
  assert.equal(gpioIn() & (1 << 4), 0);
});

test('PIO: runs in emulated time with its clock divider; PIO-driven edges are counted', () => {
  const chip = newChip();
  const { rp, clock, pio } = chip;
  const P = 0x50200000;
  // 0: set pindirs,1   1: set pins,1 [1]   2: set pins,0 [1]   wrap 2 -> 1: 4 PIO cycles per period
  [0xe081, 0xe101, 0xe100].forEach((op, i) => rp.writeUint32(P + 0x48 + 4 * i, op));
  rp.writeUint32(P + 0xc8, 10 << 16); // SM0_CLKDIV = 10
  rp.writeUint32(P + 0xcc, (2 << 12) | (1 << 7)); // EXECCTRL: wrap_top 2, wrap_bottom 1
  rp.writeUint32(P + 0xdc, (1 << 26) | (2 << 5)); // PINCTRL: SET_COUNT 1, SET_BASE 2
  rp.writeUint32(0x40014000 + 8 * 2 + 4, 6); // GPIO2 funcsel PIO0
  const edges = new EdgeCounter();
  edges.start(rp.gpio, 2, 3); // dir GPIO3 undriven: counts down
  rp.writeUint32(P + 0x00, 1); // enable SM0
  const run = (cycles) => {
    for (let c = 0; c < cycles; c++) {
      clock.tick(NS_PER_CYCLE);
      if (pio.next * NS_PER_CYCLE <= clock.nanos) pio.advance(clock.nanos / NS_PER_CYCLE);
    }
  };
  run(40_000); // 1000 periods of 40 system cycles
  assert.ok(Math.abs(edges.down - 1000) <= 1, `expected ~1000 rising edges, got ${edges.down}`);
  assert.ok(pio.steps >= 2000 && pio.steps <= 2003, `2 instructions per period, got ${pio.steps}`);
  rp.writeUint32(P + 0x00, 0); // disable: no more steps
  const steps = pio.steps;
  run(1000);
  assert.equal(pio.steps, steps);
});

test('PIO: FJOIN_TX gives an 8-word TX FIFO (rp2040js keeps 4 otherwise)', () => {
  const chip = newChip();
  const { rp } = chip;
  const P = 0x50200000;
  const FSTAT = 0x04;
  const TXFULL0 = 1 << 16;
  for (let i = 0; i < 4; i++) rp.writeUint32(P + 0x10, i);
  assert.ok(rp.readUint32(P + FSTAT) & TXFULL0, 'unjoined: full after 4');
  rp.writeUint32(P + 0xd0, rp.readUint32(P + 0xd0) | (1 << 30));
  assert.equal(rp.readUint32(P + FSTAT) & TXFULL0, 0, 'join empties the FIFO');
  for (let i = 0; i < 7; i++) rp.writeUint32(P + 0x10, i);
  assert.equal(rp.readUint32(P + FSTAT) & TXFULL0, 0, 'joined: room after 7');
  rp.writeUint32(P + 0x10, 7);
  assert.ok(rp.readUint32(P + FSTAT) & TXFULL0, 'joined: full after 8');
});

/** Deterministic PRNG so a failure can be replayed. */
function rng(seed) {
  let x = seed >>> 0 || 1;
  return () => {
    x ^= x << 13;
    x >>>= 0;
    x ^= x >>> 17;
    x ^= x << 5;
    x >>>= 0;
    return x;
  };
}

test('fast decoder: same state as rp2040js on random instructions', () => {
  const next = rng(Number(process.env.FAST_DECODER_SEED ?? 12345));
  const iterations = Number(process.env.FAST_DECODER_ITERATIONS ?? 40000);
  const rand = (n) => next() % n;
  const fastChip = newChip({}, true);
  const refChip = newChip({}, false);
  const CODE = 0x20001000;
  const STACK = 0x20000800;
  const WINDOW = [0x20000000, 0x20001400];
  // Opcode generators: [template, fixup(op, regs)] where fixup points base registers into RAM.
  const ramWord = () => 0x20000400 + 4 * rand(256);
  const classes = [
    () => [rand(0x2000), null], // 000xx: shifts, add/sub reg/imm3
    () => [0x2000 | rand(0x2000), null], // 001xx: MOVS/CMP/ADDS/SUBS imm8
    () => [0x4000 | rand(0x400), null], // ALU
    () => [0x4400 | rand(0x300), null], // ADD/CMP/MOV hi (BX excluded below)
    () => [0x4800 | rand(0x800), null], // LDR literal
    () => {
      const op = 0x5000 | rand(0x1000); // register offset: Rm + Rn
      return [op, (o, r) => {
        r[(o >> 3) & 7] = ramWord();
        r[(o >> 6) & 7] = 4 * rand(64);
        if (((o >> 3) & 7) === ((o >> 6) & 7)) r[(o >> 3) & 7] = 0x10000200; // same register twice: 2 x a flash word
      }];
    },
    () => {
      const op = 0x6000 | rand(0x3000); // STR/LDR/STRB/LDRB/STRH/LDRH imm5
      return [op, (o, r) => (r[(o >> 3) & 7] = ramWord())];
    },
    () => [0x9000 | rand(0x1000), null], // STR/LDR sp
    () => [0xa000 | rand(0x1000), null], // ADR, ADD sp
    () => [0xb000 | rand(0x100), null], // ADD/SUB SP imm7
    () => [0xb200 | rand(0x100), null], // SXT/UXT
    () => [0xb400 | rand(0x200), null], // PUSH
    () => [0xbc00 | rand(0x100), null], // POP without pc
    () => [0xbd00 | rand(0x100), null], // POP with pc (rp2040js path)
    () => [0xd000 | rand(0xe00), null], // B<cond>
    () => [0xe000 | rand(0x800), null], // B
  ];
  const mem = new Uint8Array(WINDOW[1] - WINDOW[0]);
  const flagsOf = (c) => [c.N, c.Z, c.C, c.V];
  let fastCount = 0;
  for (let iter = 0; iter < iterations; iter++) {
    let [op, fix] = classes[rand(classes.length)]();
    if (op >> 8 === 0x47) continue; // BX/BLX: not ours
    if (iter % 64 === 0) for (let i = 0; i < mem.length; i++) mem[i] = next() & 0xff;
    const regs = new Uint32Array(16);
    for (let i = 0; i < 13; i++) regs[i] = next();
    for (let i = 0; i < 8; i++) if (rand(3) === 0) regs[i] = rand(4); // small values for shifts
    regs[13] = STACK;
    regs[14] = next() | 1;
    fix?.(op, regs);
    const flags = [rand(2) === 1, rand(2) === 1, rand(2) === 1, rand(2) === 1];
    const results = [];
    for (const chip of [fastChip, refChip]) {
      const { rp, core } = chip;
      rp.sram.set(mem, WINDOW[0] - 0x20000000);
      rp.writeUint16(CODE, op);
      core.registers.set(regs);
      core.registers[15] = CODE;
      [core.N, core.Z, core.C, core.V] = flags;
      core.interruptsUpdated = false;
      let cycles;
      let error = null;
      try {
        cycles = core.executeInstruction();
      } catch (err) {
        error = err.message; // e.g. an unaligned access: must match too
      }
      results.push({
        regs: [...core.registers],
        flags: flagsOf(core),
        cycles,
        error,
        mem: Buffer.from(rp.sram.subarray(WINDOW[0] - 0x20000000, WINDOW[1] - 0x20000000)),
      });
    }
    const [a, b] = results;
    const where = `op 0x${op.toString(16)} (iteration ${iter})`;
    assert.deepEqual(a.error, b.error, `error differs for ${where}`);
    assert.deepEqual(a.regs, b.regs, `registers differ for ${where}`);
    assert.deepEqual(a.flags, b.flags, `flags differ for ${where}`);
    assert.equal(a.cycles, b.cycles, `cycles differ for ${where}`);
    assert.ok(a.mem.equals(b.mem), `memory differs for ${where}`);
  }
  fastCount = fastChip.decoderStats.fast;
  assert.ok(fastCount > iterations * 0.75, `most instructions took the fast path (${fastCount})`);
});

test('USB: CDC interfaces and bulk endpoints from a configuration descriptor', () => {
  // config, IAD, comm interface 0 (+functional descriptors, interrupt EP 0x83), data interface 1 (bulk 0x02 OUT, 0x81 IN)
  const desc = Uint8Array.of(
    9, 2, 75, 0, 2, 1, 0, 0x80, 50,
    8, 11, 0, 2, 2, 2, 0, 0,
    9, 4, 0, 0, 1, 2, 2, 0, 0,
    5, 0x24, 0, 0x10, 1,
    7, 5, 0x83, 3, 8, 0, 255,
    9, 4, 1, 0, 2, 0x0a, 0, 0, 0,
    7, 5, 0x02, 2, 64, 0, 0,
    7, 5, 0x81, 2, 64, 0, 0,
  );
  assert.deepEqual(parseCdcConfig(desc), { configValue: 1, commInterface: 0, dataInterface: 1, bulkIn: 1, bulkOut: 2 });
});

test('TCP link: one client at a time, the next after a disconnect, batched output', async () => {
  const got = [];
  const link = new TcpLink('usb', { onData: (d) => got.push(...d) });
  const port = await link.listen(0);
  const connect = () =>
    new Promise((resolve) => {
      const sock = net.connect(port, '127.0.0.1', () => resolve(sock));
      sock.rx = [];
      sock.on('data', (d) => sock.rx.push(...d));
    });
  const until = async (cond) => {
    for (let i = 0; i < 200 && !cond(); i++) await new Promise((r) => setTimeout(r, 5));
    assert.ok(cond());
  };
  try {
    await tcpLinkScenario(link, port, connect, until, got);
  } finally {
    link.close();
  }
});

async function tcpLinkScenario(link, port, connect, until, got) {
  const a = await connect();
  await until(() => link.client !== null);
  const b = net.connect(port, '127.0.0.1');
  b.on('error', () => {});
  await new Promise((r) => b.on('close', r)); // refused while a is connected
  assert.equal(link.stats.refused, 1);
  a.write('hi');
  await until(() => got.length === 2);
  link.sendByte(0x41);
  link.send(Uint8Array.of(0x42, 0x43));
  link.flush();
  await until(() => a.rx.length === 3);
  assert.deepEqual(a.rx, [0x41, 0x42, 0x43]);
  a.destroy();
  await until(() => link.client === null);
  link.send(Uint8Array.of(1, 2));
  assert.equal(link.stats.dropped, 2, 'output with no client is dropped');
  const c = await connect();
  await until(() => link.client !== null);
  c.write('x');
  await until(() => got.length === 3);
  c.destroy();
}

/** A chip whose core sleeps forever: wfi; b back to the wfi. */
function sleepyChip() {
  const chip = newChip();
  chip.rp.writeUint16(0x20000000, 0xbf30);
  chip.rp.writeUint16(0x20000002, 0xe7fd);
  chip.core.PC = 0x20000000;
  return chip;
}

test('runner: an alarm due now fires; with no alarm a free-running core sleeps until woken', async () => {
  let fired = 0;
  const runner = new Runner({ build: sleepyChip, log: () => {} });
  const alarm = runner.chip.clock.createAlarm(() => fired++);
  alarm.schedule(0); // due now: rp2040js reports 0 ns to it, as for "no alarm"
  const run = runner.run();
  await new Promise((r) => setTimeout(r, 100));
  assert.equal(fired, 1);
  assert.ok(runner.chip.nanos < 1e6, `no alarm: emulated time stands still (${runner.chip.nanos} ns)`);
  runner.chip.clock.createAlarm(() => fired++).schedule(5e9); // 5 s ahead: jumped to at once
  runner.wake();
  await new Promise((r) => setTimeout(r, 50));
  assert.equal(fired, 2);
  assert.ok(runner.chip.nanos >= 5e9);
  runner.stopping = true;
  runner.wake();
  await run;
});

/** Emulated and wall ms over `ms` of wall time on a realtime runner at `pace`. */
async function pacedRun(pace, ms) {
  const runner = new Runner({ build: sleepyChip, realtime: true, pace, log: () => {} });
  const run = runner.run();
  const t0 = performance.now();
  const e0 = runner.chip.nanos;
  await new Promise((r) => setTimeout(r, ms));
  const wallMs = performance.now() - t0;
  const emuMs = (runner.chip.nanos - e0) / 1e6;
  runner.stopping = true;
  runner.wake();
  await run;
  return { emuMs, wallMs };
}

test('runner: realtime paces emulated time to wall time', async () => {
  const { emuMs, wallMs } = await pacedRun(1, 300);
  assert.ok(Math.abs(emuMs - wallMs) < 50, `emulated ${emuMs.toFixed(1)} ms vs wall ${wallMs.toFixed(1)} ms`);
});

test('runner: at pace 0.5 emulated time runs at half wall time', async () => {
  const { emuMs, wallMs } = await pacedRun(0.5, 400);
  assert.ok(Math.abs(emuMs - wallMs / 2) < 40, `emulated ${emuMs.toFixed(1)} ms vs half of wall ${wallMs.toFixed(1)} ms`);
});

test('control: JSON lines, replies in order, errors as ok:false', async () => {
  const server = new ControlServer({ echo: (m) => ({ value: m.value }), boom: () => { throw new Error('bang'); } });
  const port = await server.listen(0);
  try {
    const replies = await new Promise((resolve, reject) => {
      const sock = net.connect(port, '127.0.0.1', () => sock.write('{"cmd":"echo","value":1}\nnot json\n{"cmd":"boom"}\n{"cmd":"nope"}\n{"cmd":"echo","value":2}\n'));
      let buf = '';
      sock.on('data', (d) => {
        buf += d;
        const lines = buf.trim().split('\n');
        if (lines.length === 5) {
          sock.end();
          resolve(lines.map((l) => JSON.parse(l)));
        }
      });
      sock.on('error', reject);
    });
    assert.deepEqual(replies[0], { ok: true, value: 1 });
    assert.deepEqual(replies[1], { ok: false, error: 'not JSON' });
    assert.deepEqual(replies[2], { ok: false, error: 'bang' });
    assert.equal(replies[3].ok, false);
    assert.deepEqual(replies[4], { ok: true, value: 2 });
  } finally {
    server.close();
  }
});

test('CLI: missing ELF and a port in use exit nonzero with a clear message', async () => {
  const bridge = path.join(here, 'bridge.mjs');
  const missing = spawnSync(process.execPath, [bridge, '--elf', '/nonexistent.elf', '--usb', '0'], { encoding: 'utf8' });
  assert.equal(missing.status, 2);
  assert.match(missing.stderr, /cannot read ELF .*no such file/);

  const noArgs = spawnSync(process.execPath, [bridge], { encoding: 'utf8' });
  assert.equal(noArgs.status, 2);
  assert.match(noArgs.stderr, /--elf is required/);

  const fast = spawnSync(process.execPath, [bridge, '--elf', '/nonexistent.elf', '--realtime', '--pace', '2'], { encoding: 'utf8' });
  assert.equal(fast.status, 2);
  assert.match(fast.stderr, /--pace must be a number in \(0, 1\], not "2"/);
  const unpaced = spawnSync(process.execPath, [bridge, '--elf', '/nonexistent.elf', '--pace', '0.5'], { encoding: 'utf8' });
  assert.equal(unpaced.status, 2);
  assert.match(unpaced.stderr, /--pace needs --realtime/);

  const dir = fs.mkdtempSync(path.join(os.tmpdir(), 'emu-selftest-'));
  const elfPath = path.join(dir, 'tiny.elf');
  fs.writeFileSync(elfPath, makeElf(bootImageSegments()));
  const blocker = net.createServer();
  await new Promise((r) => blocker.listen(0, '127.0.0.1', r));
  const port = blocker.address().port;
  const busy = spawnSync(process.execPath, [bridge, '--elf', elfPath, '--uart0', String(port)], { encoding: 'utf8' });
  blocker.close();
  assert.equal(busy.status, 2);
  assert.match(busy.stderr, new RegExp(`--uart0 port ${port}: .*already in use`));

  // A good start prints one ready line with the chosen ports, and --flash-image is written at exit.
  const image = path.join(dir, 'flash.bin');
  const child = spawn(process.execPath, [bridge, '--elf', elfPath, '--control', '0', '--flash-size', '256k', '--flash-image', image]);
  const ready = await new Promise((resolve, reject) => {
    let out = '';
    child.stdout.on('data', (d) => {
      out += d;
      if (out.includes('\n')) resolve(JSON.parse(out.split('\n')[0]));
    });
    child.on('exit', (code) => reject(new Error(`bridge exited ${code}`)));
  });
  assert.equal(ready.ready, true);
  assert.ok(ready.control > 0);
  child.kill('SIGTERM');
  await new Promise((r) => child.on('exit', r));
  assert.equal(fs.statSync(image).size, 256 * 1024);
  fs.rmSync(dir, { recursive: true, force: true });
});
