// What a GPIO's input reads. In rp2040js every input reads low unless someone
// calls setInputValue, so a limit switch input with a pull-up reads "pressed"
// and a pin never reads back its own output. Here, unless a test drives the
// pin (control channel {"cmd":"input"}), its input follows the pad: its own
// output level when it drives the pin, else its pull-up/pull-down; a floating
// pin or a bus keeper holds the last level.

const LOW = 0;
const HIGH = 1;
const PULL_UP = 3;
const PULL_DOWN = 4;

export class PinInputs {
  constructor() {
    this.forced = new Map(); // pin -> boolean, kept across resets
    this.unlisten = [];
    this.pins = null;
  }

  attach(pins) {
    for (const u of this.unlisten) u();
    this.pins = pins;
    this.unlisten = pins.map((pin, i) => pin.addListener((value) => this.follow(i, value)));
    pins.forEach((pin, i) => (this.forced.has(i) ? pin.setInputValue(this.forced.get(i)) : this.follow(i, pin.value)));
  }

  follow(i, value) {
    if (this.forced.has(i)) return;
    let level;
    if (value === HIGH || value === PULL_UP) level = true;
    else if (value === LOW || value === PULL_DOWN) level = false;
    else return;
    const pin = this.pins[i];
    if (pin.rawInputValue !== level) pin.setInputValue(level);
  }

  /** Drives pin i from outside (level true/false), or releases it (null). */
  force(i, level) {
    if (!this.pins || !(i >= 0 && i < this.pins.length)) throw new Error(`no GPIO ${i}`);
    if (level === null || level === undefined) {
      this.forced.delete(i);
      this.follow(i, this.pins[i].value);
    } else {
      this.forced.set(i, !!level);
      this.pins[i].setInputValue(!!level);
    }
  }
}
