// A fake RP2040 boot ROM. The real ROM is not in rp2040js, but firmware finds
// ROM routines through the ROM table (pico-sdk and embassy-rp both do:
// rom_table_lookup at the 16-bit pointer 0x18, the function table at 0x14,
// the data table at 0x16). Each routine here is a two-instruction stub,
// `bkpt #n; bx lr`: the core stops at the BKPT, we do the work in JS on the
// emulated memory and flash, and the `bx lr` returns to the caller.

export const ROM_SIZE = 16 * 1024;
const STUB_BASE = 0x100;
const FUNC_TABLE = 0x200;
const DATA_TABLE = 0x300;
const STRINGS = 0x380;
const INITIAL_SP = 0x20042000;

export const SECTOR_SIZE = 4096;
export const PAGE_SIZE = 256;
// Typical W25Q16JV timings (datasheet tSE / tPP), charged as emulated time so
// a flash write stalls the firmware about as long as on a Pico.
const ERASE_NS_PER_SECTOR = 45e6;
const PROGRAM_NS_PER_PAGE = 0.4e6;

export function romCode(tag) {
  return tag.charCodeAt(0) | (tag.charCodeAt(1) << 8);
}

// Index in this list = BKPT immediate = stub number.
export const ROM_FUNCTIONS = [
  ['rom_table_lookup', null],
  ['popcount32', 'P3'],
  ['reverse32', 'R3'],
  ['clz32', 'L3'],
  ['ctz32', 'T3'],
  ['memset', 'MS'],
  ['memset4', 'S4'],
  ['memcpy', 'MC'],
  ['memcpy44', 'C4'],
  ['connect_internal_flash', 'IF'],
  ['flash_exit_xip', 'EX'],
  ['flash_range_erase', 'RE'],
  ['flash_range_program', 'RP'],
  ['flash_flush_cache', 'FC'],
  ['flash_enter_cmd_xip', 'CX'],
  ['reset_to_usb_boot', 'UB'],
  ['wait_for_vector', 'WV'],
  ['unexpected_exception', null], // NMI / HardFault vectors of the ROM itself
];
const STUB = Object.fromEntries(ROM_FUNCTIONS.map(([name], i) => [name, i]));

export function stubAddress(name) {
  return STUB_BASE + 4 * STUB[name];
}

/** Builds the ROM image: vectors, magic, table pointers, stubs, tables. */
export function buildRomImage() {
  const rom = new Uint8Array(ROM_SIZE);
  const dv = new DataView(rom.buffer);
  dv.setUint32(0x00, INITIAL_SP, true);
  dv.setUint32(0x04, stubAddress('unexpected_exception') | 1, true);
  dv.setUint32(0x08, stubAddress('unexpected_exception') | 1, true);
  dv.setUint32(0x0c, stubAddress('unexpected_exception') | 1, true);
  rom.set([0x4d, 0x75, 0x01, 0x03], 0x10); // 'M' 'u' 1, version 3 (RP2040-B2)
  dv.setUint16(0x14, FUNC_TABLE, true);
  dv.setUint16(0x16, DATA_TABLE, true);
  dv.setUint16(0x18, stubAddress('rom_table_lookup') | 1, true);
  ROM_FUNCTIONS.forEach((_, i) => {
    dv.setUint16(STUB_BASE + 4 * i, 0xbe00 | i, true); // bkpt #i
    dv.setUint16(STUB_BASE + 4 * i + 2, 0x4770, true); // bx lr
  });
  let o = FUNC_TABLE;
  for (const [name, tag] of ROM_FUNCTIONS) {
    if (!tag) continue;
    dv.setUint16(o, romCode(tag), true);
    dv.setUint16(o + 2, stubAddress(name) | 1, true);
    o += 4;
  }
  dv.setUint16(o, 0, true);
  const copyright = 'osap-rs emulator fake boot ROM (not the Raspberry Pi ROM)\0';
  rom.set(new TextEncoder().encode(copyright), STRINGS + 8);
  dv.setUint32(STRINGS, 0, true); // git revision
  o = DATA_TABLE;
  dv.setUint16(o, romCode('CR'), true);
  dv.setUint16(o + 2, STRINGS + 8, true);
  dv.setUint16(o + 4, romCode('GR'), true);
  dv.setUint16(o + 6, STRINGS, true);
  dv.setUint16(o + 8, 0, true);
  return rom;
}

/** The lookup the real ROM does: walk (code, pointer) u16 pairs until code 0. */
export function tableLookup(read16, table, code) {
  for (let a = table; a < table + 1024; a += 4) {
    const c = read16(a);
    if (c === 0) return 0;
    if (c === code) return read16(a + 2);
  }
  return 0;
}

/**
 * Serves the ROM stubs for one chip. `mem` is the RP2040 object (for memory
 * access), `flash` the flash array (offset 0 = 0x10000000), `flashSize` the
 * emulated part's size. Hooks: onFlashWrite(kind, offset, length),
 * onHalt(reason), charge(ns) to account emulated time, warn(msg).
 */
export class FakeRom {
  constructor({ mem, flash, flashSize, hooks }) {
    this.mem = mem;
    this.flash = flash;
    this.flashSize = flashSize;
    this.hooks = hooks;
    this.calls = Object.fromEntries(ROM_FUNCTIONS.map(([name]) => [name, 0]));
  }

  /** True if the BKPT just executed was one of ours (and it has been served). */
  handleBreak(core, code) {
    const pc = (core.PC - 2) >>> 0;
    if (pc >= ROM_SIZE || code >= ROM_FUNCTIONS.length || pc !== STUB_BASE + 4 * code) return false;
    const name = ROM_FUNCTIONS[code][0];
    this.calls[name]++;
    const r = core.registers;
    const result = this.call(name, r[0], r[1], r[2], r[3]);
    if (result !== undefined) r[0] = result >>> 0;
    return true;
  }

  call(name, a0, a1, a2, a3) {
    const { mem } = this;
    switch (name) {
      case 'rom_table_lookup':
        return tableLookup((a) => this.read16(a), a0, a1 & 0xffff);
      case 'popcount32': {
        let n = 0;
        for (let v = a0 >>> 0; v; v >>>= 1) n += v & 1;
        return n;
      }
      case 'reverse32': {
        let v = 0;
        for (let i = 0; i < 32; i++) v = (v << 1) | ((a0 >>> i) & 1);
        return v >>> 0;
      }
      case 'clz32':
        return Math.clz32(a0);
      case 'ctz32':
        return a0 === 0 ? 32 : 31 - Math.clz32(a0 & -a0);
      case 'memset':
      case 'memset4':
        for (let i = 0; i < a2; i++) mem.writeUint8(a0 + i, a1 & 0xff);
        this.hooks.charge?.(a2 * 2);
        return a0;
      case 'memcpy':
      case 'memcpy44':
        for (let i = 0; i < a2; i++) mem.writeUint8(a0 + i, mem.readUint8(a1 + i));
        this.hooks.charge?.(a2 * 2);
        return a0;
      case 'connect_internal_flash':
      case 'flash_exit_xip':
      case 'flash_flush_cache':
      case 'flash_enter_cmd_xip':
        return undefined; // nothing to do: the emulated flash is always readable
      case 'flash_range_erase':
        this.erase(a0, a1);
        return undefined;
      case 'flash_range_program':
        this.program(a0, a1, a2);
        return undefined;
      case 'reset_to_usb_boot':
        this.hooks.onHalt?.('firmware called the ROM reset_to_usb_boot (BOOTSEL mode is not emulated)');
        return undefined;
      case 'wait_for_vector':
        this.hooks.onHalt?.('firmware called the ROM wait_for_vector (core 1 boot path; only core 0 is emulated)');
        return undefined;
      default:
        this.hooks.onHalt?.('core took an exception through the ROM vector table (VTOR still 0)');
        return undefined;
    }
  }

  read16(addr) {
    return this.mem.readUint16(addr >>> 0) & 0xffff;
  }

  offset(addr) {
    // The ROM takes flash offsets; tolerate XIP addresses the way the real
    // ROM's 24-bit SPI address field does (upper bits ignored).
    return addr & 0x00ffffff;
  }

  /** flash_range_erase(addr, count, block_size, block_cmd): whole 4 KiB sectors. */
  erase(addr, count) {
    const off = this.offset(addr);
    if (off % SECTOR_SIZE || count % SECTOR_SIZE) {
      this.hooks.warn?.(`flash_range_erase(0x${off.toString(16)}, ${count}) not sector-aligned; erasing the sectors touched`);
    }
    const start = off - (off % SECTOR_SIZE);
    const end = Math.min(this.flashSize, Math.ceil((off + count) / SECTOR_SIZE) * SECTOR_SIZE);
    if (start >= this.flashSize) {
      this.hooks.warn?.(`flash_range_erase(0x${off.toString(16)}) beyond the ${this.flashSize}-byte flash; ignored`);
      return;
    }
    this.flash.fill(0xff, start, end);
    this.hooks.charge?.(((end - start) / SECTOR_SIZE) * ERASE_NS_PER_SECTOR);
    this.hooks.onFlashWrite?.('erase', start, end - start);
  }

  /** flash_range_program(addr, data, count): NOR semantics, bits only go 1 -> 0. */
  program(addr, data, count) {
    const off = this.offset(addr);
    if (off % PAGE_SIZE || count % PAGE_SIZE) {
      this.hooks.warn?.(`flash_range_program(0x${off.toString(16)}, ${count}) not page-aligned`);
    }
    if (off + count > this.flashSize) {
      this.hooks.warn?.(`flash_range_program(0x${off.toString(16)}, ${count}) beyond the ${this.flashSize}-byte flash; ignored`);
      return;
    }
    for (let i = 0; i < count; i++) this.flash[off + i] &= this.mem.readUint8(data + i);
    this.hooks.charge?.(Math.ceil(count / PAGE_SIZE) * PROGRAM_NS_PER_PAGE);
    this.hooks.onFlashWrite?.('program', off, count);
  }
}
