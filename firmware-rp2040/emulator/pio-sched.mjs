// Runs rp2040js's PIO state machines in emulated time.
//
// rp2040js 1.4.1 runs PIO on its own: enabling a state machine starts a
// setTimeout loop of 1000 instructions per macrotask, on wall time, ignoring
// the clock divider and [delay] cycles. A 100 kHz step generator would then
// step at whatever rate the event loop allows, unrelated to the firmware's
// timers. Here each state machine instead executes one instruction every
// (1 + delay) * clkdiv system cycles, interleaved with the core.
//
// A state machine that is stalled (blocking PULL/PUSH, WAIT) costs nothing:
// rp2040js re-checks waits itself when the core touches a FIFO or IRQ flag,
// and its time then resumes from "now".

import { FIFO } from 'rp2040js';

const SHIFTCTRL = 0x08; // offset within a state machine's register block
const FJOIN_TX = 1 << 30;
const FJOIN_RX = 1 << 31;

/**
 * rp2040js ignores SHIFTCTRL.FJOIN_TX/RX: a joined FIFO stays 4 deep. Firmware
 * that joins them (8-word TX FIFO) relies on the depth for its timing budget,
 * so resize the FIFOs on a join change; like the hardware, this empties them.
 */
function joinFifosOnShiftctrl(sm) {
  const write = sm.writeUint32.bind(sm);
  sm.writeUint32 = (offset, value) => {
    const before = sm.shiftCtrl;
    write(offset, value);
    if (offset !== SHIFTCTRL || !((before ^ sm.shiftCtrl) & (FJOIN_TX | FJOIN_RX))) return;
    const tx = sm.shiftCtrl & FJOIN_TX;
    const rx = sm.shiftCtrl & FJOIN_RX;
    sm.txFIFO = new FIFO(tx ? 8 : rx ? 0 : 4);
    sm.rxFIFO = new FIFO(rx ? 8 : tx ? 0 : 4);
    sm.updateDMATx();
    sm.updateDMARx();
    sm.pio.checkInterrupts();
  };
}

export class PioScheduler {
  constructor(pios, clock, nsPerCycle) {
    this.pios = pios;
    this.clock = clock;
    this.nsPerCycle = nsPerCycle;
    this.machines = [];
    for (const pio of pios) {
      pio.run = () => {}; // no wall-clock loop: we step it
      for (const sm of pio.machines) {
        sm.nextAt = 0;
        sm.wasEnabled = false;
        joinFifosOnShiftctrl(sm);
        this.machines.push(sm);
      }
      // Any register access can enable a machine or end a FIFO stall.
      const read = pio.readUint32.bind(pio);
      const write = pio.writeUint32.bind(pio);
      pio.readUint32 = (offset) => {
        this.touch(pio);
        return read(offset);
      };
      pio.writeUint32 = (offset, value) => {
        this.touch(pio);
        write(offset, value);
      };
    }
    this.next = Infinity; // earliest cycle at which some machine has work
    this.steps = 0;
  }

  /** Current system cycle count. */
  now() {
    return this.clock.nanos / this.nsPerCycle;
  }

  /** Batch mode: the clock follows the PIO, so anything a step triggers is scheduled at the right time. */
  syncClock(cycle) {
    const ns = cycle * this.nsPerCycle;
    if (ns > this.clock.nanosCounter) this.clock.nanosCounter = ns;
  }

  /** Before the core touches a PIO: stalled machines' time catches up to now. */
  touch(pio) {
    const now = this.now();
    for (const sm of pio.machines) {
      if (sm.waiting && sm.nextAt < now) sm.nextAt = now;
    }
    this.next = 0;
  }

  static divider(sm) {
    const int = sm.clockDivInt === 0 ? 65536 : sm.clockDivInt;
    return int + sm.clockDivFrac / 256;
  }

  /**
   * Runs every machine up to system cycle `to`, in time order.
   *
   * With `stop`, this is a batch while the core sleeps: `to` may lie ahead of
   * the clock (the runner guarantees no clock alarm is due before it), the
   * clock is moved along with each step, and the batch ends early as soon as
   * stop() is true (the core woke up, or a step scheduled a new alarm).
   */
  advance(to, stop) {
    const batch = stop !== undefined;
    const base = batch ? this.now() : to; // "now", for machines whose time floats
    const ms = this.machines;
    let running = null; // the only unstalled machine, or null
    let count = 0;
    for (let i = 0; i < ms.length; i++) {
      const sm = ms[i];
      if (!sm.enabled) {
        sm.wasEnabled = false;
        continue;
      }
      if (!sm.wasEnabled) {
        sm.wasEnabled = true;
        sm.nextAt = base;
      }
      if (sm.waiting) {
        if (sm.nextAt < base) sm.nextAt = base;
        continue;
      }
      running = sm;
      count++;
    }
    if (count === 0) {
      this.next = Infinity;
      return;
    }
    if (count === 1) {
      // Common case (one step generator): no interleaving to work out.
      const sm = running;
      const div = PioScheduler.divider(sm);
      while (sm.nextAt <= to && !sm.waiting) {
        if (batch) this.syncClock(sm.nextAt);
        this.stepOne(sm, div);
        if (batch && stop()) break;
      }
      if (sm.waiting) {
        const now = batch ? this.now() : to;
        if (sm.nextAt < now) sm.nextAt = now;
        this.next = Infinity;
      } else {
        this.next = sm.nextAt;
      }
      return;
    }
    let last = base; // time of the latest step: a machine unblocked by it resumes from there
    for (;;) {
      let best = null;
      for (let i = 0; i < ms.length; i++) {
        const sm = ms[i];
        if (!sm.enabled) continue;
        if (sm.waiting) {
          if (sm.nextAt < last) sm.nextAt = last;
          continue;
        }
        if (best === null || sm.nextAt < best.nextAt) best = sm;
      }
      if (best === null) {
        this.next = Infinity;
        return;
      }
      if (best.nextAt > to) {
        this.next = best.nextAt;
        return;
      }
      last = best.nextAt;
      if (batch) this.syncClock(last);
      this.stepOne(best, PioScheduler.divider(best));
      if (batch && stop()) {
        this.next = 0; // recompute on the next call
        return;
      }
    }
  }

  stepOne(sm, div) {
    const before = sm.cycles;
    sm.step();
    sm.pio.checkChangedPins(); // per instruction, so a short pulse still shows as two edges
    this.steps++;
    const used = sm.cycles - before;
    sm.nextAt += (used > 0 ? used : 1) * div;
  }

  get active() {
    return this.machines.some((sm) => sm.enabled);
  }
}
