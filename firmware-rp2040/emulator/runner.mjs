// Drives the core: executes instructions, advances the clock 8 ns per cycle,
// runs PIO in step, and when the core sleeps (WFI/WFE) jumps the clock to the
// next event. Free-running by default; with realtime, emulated time is paced
// to wall time (times `pace`, 1 by default) and any lag is reported.

import { NS_PER_CYCLE } from './chip.mjs';

// Wall time per slice: host input is only seen between slices, so this bounds
// the input latency when the firmware never sleeps idle.
const SLICE_MS = 2;
const OUTPUT_BATCH_MS = 0.25;
const CHECK_EVERY = 2048; // instructions between wall-clock checks
const PIO_BATCH_NS = 1e6; // emulated time one PIO batch may cover while the core sleeps
const PIO_BATCH_WEIGHT = 64; // a batch counts as this many instructions toward CHECK_EVERY
const LAG_REPORT_INTERVAL_MS = 1000;
const STARTUP_GRACE_MS = 500;
const HARDFAULT = 3;

const nowMs = () => performance.now();

export class Runner {
  /**
   * build(): returns a new wired Chip (called at start and on every reset).
   * afterSlice(): flush output, persist flash, feed links.
   * hasOutput(): device output is waiting to be sent (ends a slice early).
   */
  constructor({ build, afterSlice, hasOutput, realtime = false, pace = 1, lagWarnMs = 20, maxLagMs = Infinity, log }) {
    this.build = build;
    this.hasOutput = hasOutput ?? (() => false);
    this.afterSlice = afterSlice ?? (() => {});
    this.realtime = realtime;
    this.pace = pace; // emulated seconds per wall second when realtime
    this.lagWarnMs = lagWarnMs;
    this.maxLagMs = maxLagMs; // beyond this, wall time is given up instead of caught up
    this.droppedMs = 0;
    this.log = log ?? ((m) => process.stderr.write(`${m}\n`));
    this.halted = null;
    this.breakFlag = false;
    this.resetReason = null;
    this.stopping = false;
    this.wakeResolve = null;
    this.resets = 0;
    this.startWall = nowMs();
    this.doneNs = 0; // emulated time of chips before the last reset
    this.instrCycles = 0; // cycles spent executing (not sleeping)
    this.sliceWallMs = 0; // wall time inside slices that executed instructions
    this.maxLagSeen = 0;
    this.busySpeed = null; // emulated seconds per wall second while saturated
    this.lagMs = 0;
    this.lastLagReport = 0;
    this.lagEvents = 0;
    this.chip = this.build();
    this.anchor();
  }

  anchor() {
    this.anchorWall = nowMs();
    this.anchorNs = this.chip.nanos;
  }

  targetNs(wall) {
    return this.anchorNs + (wall - this.anchorWall) * 1e6 * this.pace;
  }

  /** How far emulated time is behind its wall-time target now, ms (≥ 0). */
  behindNowMs() {
    return Math.max(0, (this.targetNs(nowMs()) - this.chip.nanos) / 1e6);
  }

  halt(reason) {
    if (this.halted) return;
    this.halted = reason;
    this.breakFlag = true;
    this.log(`[emu] core halted: ${reason}`);
  }

  requestReset(reason) {
    this.resetReason = reason;
    this.breakFlag = true;
    this.wake();
  }

  wake() {
    const r = this.wakeResolve;
    this.wakeResolve = null;
    r?.();
  }

  waitWake(ms) {
    return new Promise((resolve) => {
      const t = Number.isFinite(ms) ? setTimeout(() => resolve(), Math.max(0, ms)) : null;
      this.wakeResolve = () => {
        if (t) clearTimeout(t);
        resolve();
      };
    });
  }

  doReset() {
    const reason = this.resetReason;
    this.resetReason = null;
    this.doneNs += this.chip.nanos;
    this.chip = this.build(this.chip);
    this.halted = null;
    this.breakFlag = false;
    this.resets++;
    this.inHardFault = false;
    this.anchor();
    this.log(`[emu] reset (${reason}); flash kept`);
  }

  async run() {
    while (!this.stopping) {
      if (this.resetReason) this.doReset();
      if (this.halted) {
        this.afterSlice();
        await this.waitWake(100);
        continue;
      }
      let r;
      try {
        r = this.slice();
      } catch (err) {
        this.halt(`emulation error: ${err.message}`);
        continue;
      }
      // Still in the HardFault handler a slice later: it is the usual `loop {}`
      // (a handler that resets or returns would have done so by now).
      if (this.chip.core.IPSR === HARDFAULT) {
        if (this.inHardFault) this.halt(`HardFault (PC 0x${this.chip.core.PC.toString(16)})`);
        this.inHardFault = true;
      } else {
        this.inHardFault = false;
      }
      this.afterSlice();
      if (r.state === 'busy') {
        await new Promise((res) => setImmediate(res));
      } else if (!this.realtime) {
        await this.waitWake(Infinity); // asleep with no alarm: only host data can wake it
      } else {
        // Ahead of wall time: wait until the next event is due or host data
        // arrives. Timers have ~1 ms resolution; an event due sooner is run up
        // to 1 ms late rather than spun for (spinning would take a whole core
        // from the host under test on a 2-core CI machine).
        const aheadMs = Number.isFinite(r.nextNs) ? (r.nextNs - this.targetNs(nowMs())) / 1e6 / this.pace : 5;
        await this.waitWake(Math.max(1, Math.min(aheadMs, 5) - 0.5));
      }
    }
  }

  /** Runs for at most SLICE_MS of wall time. Returns { state: busy | ahead | idle, nextNs }. */
  slice() {
    const chip = this.chip;
    const { core, clock, pio } = chip;
    const wall0 = nowMs();
    const deadline = wall0 + SLICE_MS;
    const limitNs = this.realtime ? this.targetNs(wall0) : Infinity;
    const ns0 = clock.nanos;
    let n = 0;
    let executed = 0;
    let result = { state: 'busy', nextNs: Infinity };
    this.breakFlag = !!(this.halted || this.resetReason);
    while (!this.breakFlag) {
      if (core.waiting) {
        const now = clock.nanos;
        if (pio.next * NS_PER_CYCLE <= now) pio.advance(now / NS_PER_CYCLE);
        const alarm = clock.nextAlarm;
        const t = alarm ? Math.max(alarm.nanos, now) : Infinity;
        const horizon = t < limitNs ? t : limitNs; // nothing but PIO can happen before this
        if (pio.next * NS_PER_CYCLE < horizon) {
          // Run the PIO ahead in one batch while the core sleeps, instead of
          // one runner iteration per PIO instruction.
          const end = Math.min(horizon, now + PIO_BATCH_NS);
          pio.advance(end / NS_PER_CYCLE, () => !core.waiting || clock.nextAlarm !== alarm);
          if (core.waiting && clock.nextAlarm === alarm && clock.nanos < end) clock.nanosCounter = end;
          n += PIO_BATCH_WEIGHT;
          continue;
        }
        if (t > limitNs) {
          if (limitNs > now) {
            clock.tick(limitNs - now);
            pio.advance(limitNs / NS_PER_CYCLE);
          }
          result = { state: t === Infinity ? 'idle' : 'ahead', nextNs: t };
          break;
        }
        if (t === Infinity) {
          result = { state: 'idle', nextNs: t };
          break;
        }
        clock.tick(t - now);
      } else {
        let ns = core.executeInstruction() * NS_PER_CYCLE;
        executed += ns;
        if (chip.extraNs) {
          ns += chip.extraNs;
          chip.extraNs = 0;
        }
        clock.tick(ns);
        if (pio.next * NS_PER_CYCLE <= clock.nanos) pio.advance(clock.nanos / NS_PER_CYCLE);
      }
      if (++n >= CHECK_EVERY) {
        n = 0;
        if (clock.nanos >= limitNs) break;
        const wall = nowMs();
        if (wall >= deadline) break;
        // Send replies soon, but not one slice per byte.
        if (wall - wall0 >= OUTPUT_BATCH_MS && this.hasOutput()) break;
      }
    }
    const wall1 = nowMs();
    if (executed) {
      this.instrCycles += executed / NS_PER_CYCLE;
      this.sliceWallMs += wall1 - wall0;
    }
    // Emulated time per wall time over slices that ran out of wall time: how
    // fast the emulator goes when it cannot keep up (recent average).
    if (result.state === 'busy' && wall1 - wall0 >= SLICE_MS * 0.9) {
      const x = (clock.nanos - ns0) / ((wall1 - wall0) * 1e6);
      this.busySpeed = this.busySpeed === null ? x : this.busySpeed * 0.9 + x * 0.1;
    }
    if (this.realtime) this.trackLag(wall1, result.state === 'busy');
    return result;
  }

  trackLag(wall, busy) {
    let lag = (this.targetNs(wall) - this.chip.nanos) / 1e6;
    // Start-up (JIT warm-up, boot) is slow; catching that up later would run
    // the clock fast for a while. Give it up instead: only the rate matters.
    const maxLag = wall - this.anchorWall < STARTUP_GRACE_MS ? 0 : this.maxLagMs;
    if (lag > maxLag) {
      // Saturated for good: let emulated time run slow rather than chase wall time.
      this.droppedMs += (lag - maxLag) / this.pace; // lag is emulated ms; this counts wall ms
      this.anchorNs -= (lag - maxLag) * 1e6;
      lag = maxLag;
    }
    this.lagMs = Math.max(0, lag);
    if (!busy || lag <= this.lagWarnMs) return;
    this.maxLagSeen = Math.max(this.maxLagSeen, lag);
    this.lagEvents++;
    // The first slices after (re)start include JIT warm-up: not printed.
    if (wall - this.anchorWall >= STARTUP_GRACE_MS && wall - this.lastLagReport >= LAG_REPORT_INTERVAL_MS) {
      this.lastLagReport = wall;
      const speed = this.busySpeed === null ? '' : `; saturated it runs at ${this.busySpeed.toFixed(2)}x realtime`;
      const dropped = this.droppedMs ? `; ${this.droppedMs.toFixed(0)} ms of wall time given up so far` : '';
      this.log(`[emu] behind realtime by ${lag.toFixed(1)} ms (max ${this.maxLagSeen.toFixed(1)} ms)${speed}${dropped}`);
    }
  }

  busyCyclesPerSecond() {
    return this.sliceWallMs ? this.instrCycles / (this.sliceWallMs / 1000) : 0;
  }

  stats() {
    const wallS = (nowMs() - this.startWall) / 1000;
    const emulatedUs = this.chip.nanos / 1000;
    const totalUs = (this.doneNs + this.chip.nanos) / 1000;
    return {
      realtime: this.realtime,
      pace: this.realtime ? this.pace : null,
      emulated_us: emulatedUs,
      emulated_us_total: totalUs,
      wall_s: wallS,
      cpu_s: (process.cpuUsage().user + process.cpuUsage().system) / 1e6,
      emulated_per_wall: wallS ? totalUs / 1e6 / wallS : 0,
      cycles_executed: this.instrCycles,
      cycles_total: (this.doneNs + this.chip.nanos) / NS_PER_CYCLE,
      exec_cycles_per_wall_s: this.busyCyclesPerSecond(),
      saturated_speed_x_realtime: this.busySpeed,
      behind_ms: this.realtime ? this.lagMs : null,
      max_behind_ms: this.realtime ? this.maxLagSeen : null,
      lag_events: this.lagEvents,
      lag_dropped_ms: this.droppedMs,
      pio_steps: this.chip.pio.steps,
      resets: this.resets,
      halted: this.halted,
    };
  }
}
