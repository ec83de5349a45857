// A square wave on an input pin in emulated time: a tachometer's pulses at
// a known rate ({"cmd":"square"} on the control channel). Each half period
// is an alarm on the chip's clock, so the edges land at exact emulated
// times however the emulator is paced, and a sleeping core wakes for them.

import { makeAlarm } from './alarm.mjs';

export class SquareWave {
  /** inputs: the bridge's PinInputs, which drives the pin. */
  constructor(inputs) {
    this.inputs = inputs;
    this.pin = null;
    this.halfNs = 0;
    this.level = false;
    this.rising = 0;
    this.alarm = null;
  }

  /** On every (re)built chip: the wave goes on at its rate. */
  attach(clock) {
    this.alarm?.cancel();
    this.alarm = makeAlarm(clock, () => this.toggle());
    if (this.pin !== null) this.alarm.schedule(this.halfNs);
  }

  /** Starts a wave on GPIO `pin`, period `periodUs` µs, from low. */
  start(pin, periodUs) {
    if (!(Number.isInteger(pin) && pin >= 0)) throw new Error(`no GPIO ${pin}`);
    if (!(periodUs >= 2 && periodUs <= 10_000_000)) throw new Error('period_us must be 2 to 10 000 000');
    this.stop();
    this.inputs.force(pin, false);
    this.pin = pin;
    this.halfNs = periodUs * 500;
    this.level = false;
    this.rising = 0;
    this.alarm.schedule(this.halfNs);
    return this.report();
  }

  /** Stops the wave and releases the pin. */
  stop() {
    const r = this.report();
    this.alarm?.cancel();
    if (this.pin !== null) this.inputs.force(this.pin, null);
    this.pin = null;
    return r;
  }

  toggle() {
    if (this.pin === null) return;
    this.level = !this.level;
    if (this.level) this.rising += 1;
    this.inputs.force(this.pin, this.level);
    this.alarm.schedule(this.halfNs);
  }

  report() {
    return { pin: this.pin, period_us: this.halfNs / 500, rising: this.rising };
  }
}
