// Counts step pulses the way a stepper driver does: each rising edge on the
// step pin is one step, up if the dir pin is high at that edge, else down.
//
// rp2040js reports a pin's level change through GPIOPin listeners, called
// from GPIOPin.checkForUpdates(); SIO writes call it for SIO-driven pins and
// the PIO calls it (checkChangedPins) for PIO-driven pins, so one listener
// covers both. The level is a GPIOPinState: 0 low, 1 high, >= 2 not driven.

const LOW = 0;
const HIGH = 1;

export class EdgeCounter {
  constructor(nowMicros = () => 0) {
    this.nowMicros = nowMicros;
    this.step = -1;
    this.dir = -1;
    this.unlisten = null;
    this.pins = null;
    this.clear();
  }

  clear() {
    this.position = 0;
    this.up = 0;
    this.down = 0;
    this.firstEdgeUs = null;
    this.lastEdgeUs = null;
  }

  /** Starts counting from zero on (step, dir) of the given pins. */
  start(pins, step, dir) {
    if (!(step >= 0 && step < pins.length) || !(dir >= 0 && dir < pins.length)) {
      throw new Error(`step and dir must be GPIO numbers 0..${pins.length - 1}`);
    }
    this.step = step;
    this.dir = dir;
    this.clear();
    this.attach(pins);
  }

  /** Re-attaches to a new chip's pins (after an emulated reset), keeping the counts. */
  attach(pins) {
    this.unlisten?.();
    this.unlisten = null;
    this.pins = pins;
    if (this.step < 0) return;
    const dirPin = pins[this.dir];
    this.unlisten = pins[this.step].addListener((value, old) => {
      if (value !== HIGH || old !== LOW) return;
      if (dirPin.value === HIGH) {
        this.position++;
        this.up++;
      } else {
        this.position--;
        this.down++;
      }
      const t = this.nowMicros();
      if (this.firstEdgeUs === null) this.firstEdgeUs = t;
      this.lastEdgeUs = t;
    });
  }

  stop() {
    this.unlisten?.();
    this.unlisten = null;
    this.step = this.dir = -1;
  }

  snapshot() {
    return {
      counting: this.step >= 0,
      step: this.step,
      dir: this.dir,
      position: this.position,
      up: this.up,
      down: this.down,
      edges: this.up + this.down,
      first_edge_us: this.firstEdgeUs,
      last_edge_us: this.lastEdgeUs,
    };
  }
}
