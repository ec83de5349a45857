// A faster instruction decoder in front of rp2040js's core.
//
// rp2040js decodes each instruction with one long if/else chain of about 80
// tests in alphabetical order, so a STR (sp) — 10 % of what the module
// firmware executes — is found only after ~70 comparisons. This front end
// switches on the top five opcode bits and executes the common Thumb
// instructions itself, with exactly rp2040js's semantics (same flag helpers,
// same cycle counts, same memory functions). Everything else — branches with
// link, BX, POP {pc}, exceptions, system and hint instructions, and any
// instruction while an interrupt check is pending — goes to rp2040js
// unchanged. selftest.mjs checks both paths against each other on random
// instructions.

const SIO_BASE = 0xd0000000;
const APB_BASE = 0x40000000;
const FLASH_BASE = 0x10000000;
const SRAM_BASE = 0x20000000;
const PC = 15;
const SP = 13;

function cyclesIO(addr, write) {
  addr = addr >>> 0;
  if (addr >= SIO_BASE && addr < SIO_BASE + 0x10000000) return 0;
  if (addr >= APB_BASE && addr < APB_BASE + 0x10000000) return write ? 4 : 3;
  return 1;
}

export function installFastPath(rp) {
  const core = rp.core;
  const reference = core.executeInstruction.bind(core);
  const r = core.registers;
  const flash = rp.flashView;
  const flashLen = rp.flash.length;
  const sram = rp.sramView;
  const sramLen = rp.sram.length;
  const stats = { fast: 0, reference: 0 };

  const nz = (v) => {
    core.N = !!(v & 0x80000000);
    core.Z = (v & 0xffffffff) === 0;
  };

  /** Executes one instruction; returns its cycles, or -1 to hand it to rp2040js. */
  function fast(op) {
    switch (op >> 11) {
      case 0b00000: {
        // LSLS (immediate)
        const imm5 = (op >> 6) & 0x1f;
        const input = r[(op >> 3) & 7];
        const result = input << imm5;
        r[op & 7] = result;
        core.N = !!(result & 0x80000000);
        core.Z = result === 0;
        core.C = imm5 ? !!(input & (1 << (32 - imm5))) : core.C;
        return 1;
      }
      case 0b00001: {
        // LSRS (immediate)
        const imm5 = (op >> 6) & 0x1f;
        const input = r[(op >> 3) & 7];
        const result = imm5 ? input >>> imm5 : 0;
        r[op & 7] = result;
        core.N = !!(result & 0x80000000);
        core.Z = result === 0;
        core.C = !!((input >>> (imm5 ? imm5 - 1 : 31)) & 1);
        return 1;
      }
      case 0b00011: {
        const Rn = r[(op >> 3) & 7];
        const x = (op >> 6) & 7;
        switch ((op >> 9) & 3) {
          case 0: // ADDS (register)
            r[op & 7] = core.addUpdateFlags(Rn, r[x]);
            return 1;
          case 1: // SUBS (register)
            r[op & 7] = core.substractUpdateFlags(Rn, r[x]);
            return 1;
          case 2: // ADDS imm3
            r[op & 7] = core.addUpdateFlags(Rn, x);
            return 1;
          default: // SUBS imm3
            r[op & 7] = core.substractUpdateFlags(Rn, x);
            return 1;
        }
      }
      case 0b00100: {
        // MOVS imm8
        const value = op & 0xff;
        r[(op >> 8) & 7] = value;
        core.N = false;
        core.Z = value === 0;
        return 1;
      }
      case 0b00101: // CMP imm8
        core.substractUpdateFlags(r[(op >> 8) & 7], op & 0xff);
        return 1;
      case 0b00110: {
        // ADDS imm8
        const d = (op >> 8) & 7;
        r[d] = core.addUpdateFlags(r[d], op & 0xff);
        return 1;
      }
      case 0b00111: {
        // SUBS imm8
        const d = (op >> 8) & 7;
        r[d] = core.substractUpdateFlags(r[d], op & 0xff);
        return 1;
      }
      case 0b01000:
        return op & 0x400 ? hiRegister(op) : alu(op);
      case 0b01001: {
        // LDR (literal)
        const addr = ((r[PC] + 2) & 0xfffffffc) + ((op & 0xff) << 2);
        const c = 1 + cyclesIO(addr, false);
        r[(op >> 8) & 7] = rp.readUint32(addr);
        return c;
      }
      case 0b01010:
      case 0b01011:
        return registerOffset(op);
      case 0b01100: {
        // STR (immediate)
        const addr = r[(op >> 3) & 7] + (((op >> 6) & 0x1f) << 2);
        const c = 1 + cyclesIO(addr, true);
        rp.writeUint32(addr, r[op & 7]);
        return c;
      }
      case 0b01101: {
        // LDR (immediate)
        const addr = r[(op >> 3) & 7] + (((op >> 6) & 0x1f) << 2);
        const c = 1 + cyclesIO(addr, false);
        r[op & 7] = rp.readUint32(addr);
        return c;
      }
      case 0b01110: {
        // STRB (immediate)
        const addr = r[(op >> 3) & 7] + ((op >> 6) & 0x1f);
        const c = 1 + cyclesIO(addr, true);
        rp.writeUint8(addr, r[op & 7]);
        return c;
      }
      case 0b01111: {
        // LDRB (immediate)
        const addr = r[(op >> 3) & 7] + ((op >> 6) & 0x1f);
        const c = 1 + cyclesIO(addr, false);
        r[op & 7] = rp.readUint8(addr);
        return c;
      }
      case 0b10000: {
        // STRH (immediate)
        const addr = r[(op >> 3) & 7] + (((op >> 6) & 0x1f) << 1);
        const c = 1 + cyclesIO(addr, true);
        rp.writeUint16(addr, r[op & 7]);
        return c;
      }
      case 0b10001: {
        // LDRH (immediate)
        const addr = r[(op >> 3) & 7] + (((op >> 6) & 0x1f) << 1);
        const c = 1 + cyclesIO(addr, false);
        r[op & 7] = rp.readUint16(addr);
        return c;
      }
      case 0b10010: {
        // STR (sp + immediate)
        const addr = r[SP] + ((op & 0xff) << 2);
        const c = 1 + cyclesIO(addr, true);
        rp.writeUint32(addr, r[(op >> 8) & 7]);
        return c;
      }
      case 0b10011: {
        // LDR (sp + immediate)
        const addr = r[SP] + ((op & 0xff) << 2);
        const c = 1 + cyclesIO(addr, false);
        r[(op >> 8) & 7] = rp.readUint32(addr);
        return c;
      }
      case 0b10100: // ADR: PC was already advanced by 2, so opcodePC = PC - 2
        r[(op >> 8) & 7] = ((r[PC] - 2) & 0xfffffffc) + 4 + ((op & 0xff) << 2);
        return 1;
      case 0b10101: // ADD Rd, SP, imm8
        r[(op >> 8) & 7] = r[SP] + ((op & 0xff) << 2);
        return 1;
      case 0b10110:
        return misc(op);
      case 0b10111:
        if (op >> 9 === 0b1011110 && !(op & 0x100)) {
          // POP without PC (with PC it may be an exception return: rp2040js)
          let address = r[SP];
          let c = 1;
          for (let i = 0; i <= 7; i++) {
            if (op & (1 << i)) {
              r[i] = rp.readUint32(address);
              address += 4;
              c++;
            }
          }
          core.SP = address;
          return c;
        }
        return -1;
      case 0b11010:
      case 0b11011: {
        // B<cond>; 0b1110 is UDF, 0b1111 SVC
        const cond = (op >> 8) & 0xf;
        if (cond >= 0b1110) return -1;
        let imm8 = (op & 0xff) << 1;
        if (imm8 & (1 << 8)) imm8 = (imm8 & 0x1ff) - 0x200;
        if (core.checkCondition(cond)) {
          r[PC] += imm8 + 2;
          return 2;
        }
        return 1;
      }
      case 0b11100: {
        // B
        let imm11 = (op & 0x7ff) << 1;
        if (imm11 & (1 << 11)) imm11 = (imm11 & 0x7ff) - 0x800;
        r[PC] += imm11 + 2;
        return 2;
      }
      default:
        return -1;
    }
  }

  function alu(op) {
    const m = (op >> 3) & 7;
    const d = op & 7;
    switch ((op >> 6) & 0xf) {
      case 0b0000: {
        // ANDS
        const result = r[d] & r[m];
        r[d] = result;
        nz(result);
        return 1;
      }
      case 0b0001: {
        // EORS
        const result = r[m] ^ r[d];
        r[d] = result;
        core.N = !!(result & 0x80000000);
        core.Z = result === 0;
        return 1;
      }
      case 0b0101: // ADCS
        r[d] = core.addUpdateFlags(r[m], r[d] + (core.C ? 1 : 0));
        return 1;
      case 0b1000: {
        // TST
        const result = r[d] & r[m];
        core.N = !!(result & 0x80000000);
        core.Z = result === 0;
        return 1;
      }
      case 0b1001: // NEGS
        r[d] = core.substractUpdateFlags(0, r[m]);
        return 1;
      case 0b1010: // CMP (register)
        core.substractUpdateFlags(r[d], r[m]);
        return 1;
      case 0b1100: {
        // ORRS
        const result = r[d] | r[m];
        r[d] = result;
        nz(result);
        return 1;
      }
      case 0b1101: {
        // MULS
        const result = Math.imul(r[m], r[d]);
        r[d] = result;
        nz(result);
        return 1;
      }
      case 0b1110: {
        // BICS
        const result = (r[d] &= ~r[m]);
        core.N = !!(result & 0x80000000);
        core.Z = result === 0;
        return 1;
      }
      case 0b1111: {
        // MVNS
        const result = ~r[m];
        r[d] = result;
        core.N = !!(result & 0x80000000);
        core.Z = result === 0;
        return 1;
      }
      default:
        return -1; // shifts/rotate by register, SBCS, CMN: rp2040js
    }
  }

  function hiRegister(op) {
    const m = (op >> 3) & 0xf;
    const d = ((op >> 4) & 0x8) | (op & 7);
    switch ((op >> 8) & 3) {
      case 0: // ADD (register), not involving PC or writing SP
        if (m === PC || d === PC || d === SP) return -1;
        r[d] = r[d] + r[m];
        return 1;
      case 1: // CMP (register) T2
        core.substractUpdateFlags(r[d], r[m]);
        return 1;
      case 2: // MOV, not involving PC
        if (m === PC || d === PC) return -1;
        r[d] = d === SP ? r[m] & ~3 : r[m];
        return 1;
      default:
        return -1; // BX, BLX
    }
  }

  function registerOffset(op) {
    const addr = r[(op >> 6) & 7] + r[(op >> 3) & 7];
    const t = op & 7;
    switch ((op >> 9) & 7) {
      case 0b000: {
        const c = 1 + cyclesIO(addr, true);
        rp.writeUint32(addr, r[t]);
        return c;
      }
      case 0b001: {
        const c = 1 + cyclesIO(addr, true);
        rp.writeUint16(addr, r[t]);
        return c;
      }
      case 0b010: {
        const c = 1 + cyclesIO(addr, true);
        rp.writeUint8(addr, r[t]);
        return c;
      }
      case 0b011: {
        const c = 1 + cyclesIO(addr, false);
        r[t] = (rp.readUint8(addr) << 24) >> 24;
        return c;
      }
      case 0b100: {
        const c = 1 + cyclesIO(addr, false);
        r[t] = rp.readUint32(addr);
        return c;
      }
      case 0b101: {
        const c = 1 + cyclesIO(addr, false);
        r[t] = rp.readUint16(addr);
        return c;
      }
      case 0b110: {
        const c = 1 + cyclesIO(addr, false);
        r[t] = rp.readUint8(addr);
        return c;
      }
      default: {
        const c = 1 + cyclesIO(addr, false);
        r[t] = (rp.readUint16(addr) << 16) >> 16;
        return c;
      }
    }
  }

  function misc(op) {
    if (op >> 7 === 0b101100000) {
      core.SP += (op & 0x7f) << 2; // ADD SP, imm7
      return 1;
    }
    if (op >> 7 === 0b101100001) {
      core.SP -= (op & 0x7f) << 2; // SUB SP, imm7
      return 1;
    }
    if (op >> 8 === 0b10110010) {
      const v = r[(op >> 3) & 7];
      const d = op & 7;
      switch ((op >> 6) & 3) {
        case 0: // SXTH
          r[d] = (v << 16) >> 16;
          return 1;
        case 1: // SXTB
          r[d] = (v << 24) >> 24;
          return 1;
        case 2: // UXTH
          r[d] = v & 0xffff;
          return 1;
        default: // UXTB
          r[d] = v & 0xff;
          return 1;
      }
    }
    if (op >> 9 === 0b1011010) {
      // PUSH
      let bitCount = 0;
      for (let i = 0; i <= 8; i++) if (op & (1 << i)) bitCount++;
      let address = r[SP] - 4 * bitCount;
      let c = 1;
      for (let i = 0; i <= 7; i++) {
        if (op & (1 << i)) {
          rp.writeUint32(address, r[i]);
          c++;
          address += 4;
        }
      }
      if (op & (1 << 8)) rp.writeUint32(address, r[14]);
      core.SP -= 4 * bitCount;
      return c;
    }
    return -1;
  }

  core.executeInstruction = function executeInstruction() {
    if (core.interruptsUpdated) {
      stats.reference++;
      return reference();
    }
    const pc = r[PC] & ~1;
    let op;
    if (pc >= FLASH_BASE && pc + 1 < FLASH_BASE + flashLen) op = flash.getUint16(pc - FLASH_BASE, true);
    else if (pc >= SRAM_BASE && pc + 1 < SRAM_BASE + sramLen) op = sram.getUint16(pc - SRAM_BASE, true);
    else {
      stats.reference++;
      return reference();
    }
    if (op >> 11 >= 0b11101) {
      stats.reference++;
      return reference(); // 32-bit instructions
    }
    // Decide before touching state: the fallback must see the instruction untouched.
    const saved = r[PC];
    r[PC] = saved + 2;
    const c = fast(op);
    if (c < 0) {
      r[PC] = saved;
      stats.reference++;
      return reference();
    }
    stats.fast++;
    core.cycles += c;
    return c;
  };
  return stats;
}
