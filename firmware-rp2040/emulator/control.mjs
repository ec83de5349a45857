// Line-based JSON control channel for tests: one JSON object per line in,
// one JSON object per line out ({"ok":true,...} or {"ok":false,"error":...}).
// Several clients may be connected; commands run between emulation slices.

import net from 'node:net';

const STATE_NAMES = ['low', 'high', 'input', 'input-pullup', 'input-pulldown', 'input-buskeeper'];
const FUNCS = { 1: 'spi', 2: 'uart', 3: 'i2c', 4: 'pwm', 5: 'sio', 6: 'pio0', 7: 'pio1', 8: 'clock', 9: 'usb', 31: 'null' };

export function gpioReport(pins) {
  let high = 0;
  let driven = 0;
  const list = pins.map((pin, i) => {
    const v = pin.value;
    if (v <= 1) driven |= 1 << i;
    if (v === 1) high |= 1 << i;
    return { pin: i, state: STATE_NAMES[v] ?? String(v), level: v <= 1 ? v : pin.inputValue ? 1 : 0, func: FUNCS[pin.functionSelect] ?? String(pin.functionSelect) };
  });
  return { high: high >>> 0, driven: driven >>> 0, pins: list };
}

/** commands: { name: (msg) => object } */
export class ControlServer {
  constructor(commands, { log } = {}) {
    this.commands = commands;
    this.log = log ?? (() => {});
  }

  listen(port) {
    this.server = net.createServer((sock) => this.accept(sock));
    return new Promise((resolve, reject) => {
      this.server.once('error', (err) => {
        const why = err.code === 'EADDRINUSE' ? 'is already in use' : `failed (${err.message})`;
        reject(new Error(`--control port ${port}: listening on 127.0.0.1:${port} ${why}`));
      });
      this.server.listen(port, '127.0.0.1', () => resolve((this.port = this.server.address().port)));
    });
  }

  accept(sock) {
    let buf = '';
    sock.setEncoding('utf8');
    sock.on('error', () => sock.destroy());
    // Commands are synchronous, so replies keep the order of the requests.
    sock.on('data', (text) => {
      buf += text;
      let nl;
      while ((nl = buf.indexOf('\n')) >= 0) {
        const line = buf.slice(0, nl).trim();
        buf = buf.slice(nl + 1);
        if (!line) continue;
        const reply = this.handle(line);
        if (!sock.destroyed) sock.write(`${JSON.stringify(reply)}\n`);
      }
      if (buf.length > 65536) {
        sock.write(`${JSON.stringify({ ok: false, error: 'line too long' })}\n`);
        sock.destroy();
      }
    });
  }

  handle(line) {
    let msg;
    try {
      msg = JSON.parse(line);
    } catch {
      return { ok: false, error: 'not JSON' };
    }
    const fn = this.commands[msg?.cmd];
    if (!fn) return { ok: false, error: `unknown cmd ${JSON.stringify(msg?.cmd)}; known: ${Object.keys(this.commands).join(', ')}` };
    try {
      return { ok: true, ...fn(msg) };
    } catch (err) {
      return { ok: false, error: err.message };
    }
  }

  close() {
    this.server?.close();
  }
}
