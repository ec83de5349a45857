// One emulated RP2040 (core 0), with every fix the firmware needs applied:
// fake boot ROM, flash id replies, UART registers and TX interrupt, PIO in
// emulated time, reset requests (AIRCR.SYSRESETREQ, watchdog) reported.
// A reset builds a new Chip from the old one's flash.

import { RP2040 } from 'rp2040js';
import { buildRomImage, FakeRom } from './rom.mjs';
import { patchSsi } from './ssi.mjs';
import { patchUart, UartFeeder } from './uart.mjs';
import { PioScheduler } from './pio-sched.mjs';
import { installXipCtrl } from './xip.mjs';
import { installFastPath } from './fastcore.mjs';

export const NS_PER_CYCLE = 8; // 125 MHz
const BOOT2_ADDRESS = 0x10000000;
const AIRCR = 0xd0c;
const SSI_KEY = 0x18000;
const WATCHDOG_KEY = 0x40058;
const SRAM_BASE = 0x20000000;
const SRAM_LAST_WORD = 264 * 1024 - 4;
const FIFO_ST = 0x050;
const FIFO_WR = 0x054;
const FIFO_RD = 0x058;
const FIFO_ST_RDY = 1 << 1;

/** rp2040js logs through this: quiet unless verbose; errors become exceptions (we halt). */
export function makeLogger({ verbose = 0, write = (s) => process.stderr.write(s) } = {}) {
  const logger = {
    warnings: 0,
    debug: (c, m) => verbose >= 2 && write(`[rp2040js ${c}] ${m}\n`),
    info: (c, m) => verbose >= 2 && write(`[rp2040js ${c}] ${m}\n`),
    warn: (c, m) => {
      logger.warnings++;
      if (verbose >= 1) write(`[rp2040js ${c}] ${m}\n`);
    },
    error: (c, m) => {
      throw new Error(`rp2040js ${c}: ${m}`);
    },
  };
  return logger;
}

export class Chip {
  /**
   * flash: bytes to put in flash (offset 0 = 0x10000000), flashSize bytes.
   * hooks: onHalt(reason), onResetRequest(reason), onFlashWrite(kind, offset, length), warn(msg).
   */
  constructor({ flash, flashSize, uniqueId, jedecId, logger, hooks, uartPaced = true, fastPath = true }) {
    this.hooks = hooks;
    this.flashSize = flashSize;
    this.extraNs = 0; // emulated time a ROM routine took, added after its BKPT
    const rp = new RP2040();
    this.rp = rp;
    rp.logger = logger;
    this.core = rp.core;
    this.clock = rp.clock;
    // loadBootrom() would call reset(), which wipes flash: set the words directly.
    rp.bootrom.set(new Uint32Array(buildRomImage().buffer));
    rp.flash.set(flash.subarray(0, flashSize));

    this.rom = new FakeRom({
      mem: rp,
      flash: rp.flash,
      flashSize,
      hooks: {
        charge: (ns) => (this.extraNs += ns),
        onFlashWrite: (kind, offset, length) => hooks.onFlashWrite?.(kind, offset, length),
        onHalt: (reason) => hooks.onHalt?.(reason),
        warn: (m) => hooks.warn?.(m),
      },
    });
    rp.onBreak = (code) => {
      if (this.rom.handleBreak(this.core, code)) return;
      const pc = (this.core.PC - this.core.breakRewind) >>> 0;
      const op = rp.readUint16(pc);
      const what = op >> 8 === 0xbe ? `BKPT #${code}` : `UDF #${code} (undefined instruction, e.g. a Rust abort/panic trap)`;
      hooks.onHalt?.(`firmware executed ${what} at 0x${pc.toString(16)}`);
    };

    patchSsi(rp.peripherals[SSI_KEY], { uniqueId, jedecId });
    installXipCtrl(rp);
    for (const uart of rp.uart) patchUart(uart);
    this.uartFeeders = rp.uart.map((u) => new UartFeeder(u, this.clock, { paced: uartPaced }));
    this.pio = new PioScheduler(rp.pio, this.clock, NS_PER_CYCLE);

    // Speed: rp2040js looks up a peripheral before every 32-bit write, RAM
    // included (about 7 % of run time with the module firmware). Stores to
    // SRAM go straight to it.
    const write32 = rp.writeUint32.bind(rp);
    const sram = rp.sramView;
    rp.writeUint32 = (address, value) => {
      const offset = (address >>> 0) - SRAM_BASE;
      if (offset >= 0 && offset <= SRAM_LAST_WORD) sram.setUint32(offset, value, true);
      else write32(address, value);
    };

    this.decoderStats = fastPath ? installFastPath(rp) : null;

    // The inter-core FIFOs are missing from rp2040js (reads give 0xFFFFFFFF and a
    // console warning). With no core 1 they are always empty and never full;
    // a write is the firmware trying to start core 1, which is reported.
    const sioRead = rp.sio.readUint32.bind(rp.sio);
    const sioWrite = rp.sio.writeUint32.bind(rp.sio);
    let core1Reported = false;
    rp.sio.readUint32 = (offset) => {
      if (offset === FIFO_ST) return FIFO_ST_RDY;
      if (offset === FIFO_RD) return 0;
      return sioRead(offset);
    };
    rp.sio.writeUint32 = (offset, value) => {
      if (offset === FIFO_ST) return; // clears sticky error flags: none here
      if (offset === FIFO_WR) {
        if (!core1Reported) hooks.warn?.('[emu] firmware wrote the inter-core FIFO (starting core 1?): only core 0 is emulated');
        core1Reported = true;
        return;
      }
      sioWrite(offset, value);
    };

    // rp2040js ignores SYSRESETREQ and leaves the watchdog reset to its user.
    const ppbWrite = rp.ppb.writeUint32.bind(rp.ppb);
    rp.ppb.writeUint32 = (offset, value) => {
      if (offset === AIRCR && value >>> 16 === 0x05fa && value & 4) {
        hooks.onResetRequest?.('AIRCR.SYSRESETREQ');
        return;
      }
      ppbWrite(offset, value);
    };
    rp.peripherals[WATCHDOG_KEY].onWatchdogTrigger = () => hooks.onResetRequest?.('watchdog');

    // What the real ROM does before boot2: main stack at the top of SRAM, VTOR 0,
    // LR 0 so boot2 "returns" by jumping through the vector table at 0x10000100.
    this.core.SP = 0x20042000;
    this.core.LR = 0;
    this.core.PC = BOOT2_ADDRESS;
  }

  get nanos() {
    return this.clock.nanos;
  }

  get flash() {
    return this.rp.flash.subarray(0, this.flashSize);
  }
}
