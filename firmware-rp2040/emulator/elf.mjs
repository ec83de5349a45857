// Minimal ELF32 reader: just enough to place a firmware image's PT_LOAD
// segments at their physical (load) addresses, the way a flasher does.
// Physical, not virtual: .data lives in RAM at run time but is stored in flash.

export const FLASH_BASE = 0x10000000;
export const SRAM_BASE = 0x20000000;

const PT_LOAD = 1;
const EM_ARM = 40;

export class ElfError extends Error {}

/** Parses an ELF32 little-endian ARM file; returns { entry, segments: [{ paddr, vaddr, data, memsz }] }. */
export function parseElf(buf) {
  const u8 = buf instanceof Uint8Array ? buf : new Uint8Array(buf);
  if (u8.length < 52 || u8[0] !== 0x7f || u8[1] !== 0x45 || u8[2] !== 0x4c || u8[3] !== 0x46) {
    throw new ElfError('not an ELF file (bad magic)');
  }
  if (u8[4] !== 1) throw new ElfError('not a 32-bit ELF (the RP2040 is a 32-bit Cortex-M0+)');
  if (u8[5] !== 1) throw new ElfError('not a little-endian ELF');
  const dv = new DataView(u8.buffer, u8.byteOffset, u8.byteLength);
  const machine = dv.getUint16(18, true);
  if (machine !== EM_ARM) throw new ElfError(`ELF is for machine ${machine}, not ARM (40)`);
  const entry = dv.getUint32(24, true);
  const phoff = dv.getUint32(28, true);
  const phentsize = dv.getUint16(42, true);
  const phnum = dv.getUint16(44, true);
  if (phoff === 0 || phnum === 0) throw new ElfError('ELF has no program headers');
  if (phoff + phnum * phentsize > u8.length) throw new ElfError('ELF program headers run past the end of the file');
  const segments = [];
  for (let i = 0; i < phnum; i++) {
    const o = phoff + i * phentsize;
    if (dv.getUint32(o, true) !== PT_LOAD) continue;
    const offset = dv.getUint32(o + 4, true);
    const vaddr = dv.getUint32(o + 8, true);
    const paddr = dv.getUint32(o + 12, true);
    const filesz = dv.getUint32(o + 16, true);
    const memsz = dv.getUint32(o + 20, true);
    if (filesz === 0) continue; // .bss and stack: nothing stored
    if (offset + filesz > u8.length) throw new ElfError(`segment ${i} runs past the end of the file`);
    segments.push({ paddr, vaddr, memsz, data: u8.subarray(offset, offset + filesz) });
  }
  return { entry, segments };
}

/**
 * Copies the segments stored in flash into `flash` (offset 0 = 0x10000000).
 * Returns the number of bytes written. Segments outside flash are an error:
 * the image must be what a flasher would write.
 */
export function loadElfIntoFlash(flash, elf) {
  let written = 0;
  for (const seg of elf.segments) {
    const off = seg.paddr - FLASH_BASE;
    if (off < 0 || off + seg.data.length > flash.length) {
      throw new ElfError(
        `segment at physical 0x${seg.paddr.toString(16)} (${seg.data.length} bytes) is outside flash ` +
          `0x10000000..0x${(FLASH_BASE + flash.length).toString(16)}`,
      );
    }
    flash.set(seg.data, off);
    written += seg.data.length;
  }
  if (written === 0) throw new ElfError('ELF has no loadable bytes');
  return written;
}

/** Sanity check after loading: boot2 in the first 256 bytes and a vector table at 0x100. */
export function checkBootImage(flash) {
  const dv = new DataView(flash.buffer, flash.byteOffset, flash.byteLength);
  const sp = dv.getUint32(0x100, true);
  const reset = dv.getUint32(0x104, true);
  const problems = [];
  if (flash.subarray(0, 256).every((b) => b === 0xff)) problems.push('no boot2 in the first 256 bytes of flash');
  if (sp < SRAM_BASE || sp > SRAM_BASE + 0x42000) problems.push(`initial SP 0x${sp.toString(16)} at 0x10000100 is not in SRAM`);
  if (!(reset & 1) || reset < FLASH_BASE || reset >= FLASH_BASE + flash.length) {
    problems.push(`reset vector 0x${reset.toString(16)} at 0x10000104 is not a Thumb address in flash`);
  }
  return problems;
}
