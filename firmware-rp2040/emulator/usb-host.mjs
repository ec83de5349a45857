// A minimal USB host for one CDC-ACM function, driving rp2040js's USB device
// controller model. rp2040js ships its own CDC host, but with embassy-usb it
// sends SET_CONTROL_LINE_STATE to the device instead of the interface (so
// `wait_connection()` never returns) and answers every armed OUT endpoint
// with a zero-length packet when it has no data. This one enumerates like a
// PC does, raises DTR on the communication interface, then moves bulk data.

import { makeAlarm } from './alarm.mjs';

const EP0_IN_BUF_CTRL = 0x80;
const EP0_OUT_BUF_CTRL = 0x84;
const AVAILABLE = 1 << 10;
const FULL = 1 << 15;
const LEN_MASK = 0x3ff;
const MAX_PACKET = 64;
// Host-side turnaround, emulated time: long enough for the firmware to see
// one stage finish before the next starts, short next to a 1 ms USB frame.
const PACKET_NS = 10_000;
const NEXT_REQUEST_NS = 50_000;
const CONTROL_TIMEOUT_NS = 100e6;

const DESC_DEVICE = 1;
const DESC_CONFIG = 2;
const DESC_INTERFACE = 4;
const DESC_ENDPOINT = 5;

function setup(bmRequestType, bRequest, wValue, wIndex, wLength) {
  return Uint8Array.of(bmRequestType, bRequest, wValue & 0xff, wValue >> 8, wIndex & 0xff, wIndex >> 8, wLength & 0xff, wLength >> 8);
}

/** Finds the CDC communication interface and the data interface's bulk endpoints. */
export function parseCdcConfig(desc) {
  const out = { configValue: desc[5] ?? 1, commInterface: -1, dataInterface: -1, bulkIn: -1, bulkOut: -1 };
  let iface = null;
  for (let i = 0; i + 2 <= desc.length && desc[i] >= 2; i += desc[i]) {
    const type = desc[i + 1];
    if (type === DESC_INTERFACE) {
      iface = { number: desc[i + 2], cls: desc[i + 5] };
      if (iface.cls === 0x02 && out.commInterface < 0) out.commInterface = iface.number;
      if (iface.cls === 0x0a && out.dataInterface < 0) out.dataInterface = iface.number;
    } else if (type === DESC_ENDPOINT && iface && iface.cls === 0x0a && iface.number === out.dataInterface) {
      const addr = desc[i + 2];
      if ((desc[i + 3] & 3) === 2) {
        if (addr & 0x80) out.bulkIn = addr & 0xf;
        else out.bulkOut = addr & 0xf;
      }
    }
  }
  if (out.commInterface < 0) out.commInterface = 0;
  return out;
}

export class CdcHost {
  /** usb: rp2040js RPUSBController; onData(Uint8Array) gets bulk IN data. */
  constructor(usb, clock, { onData, onReady, log }) {
    this.usb = usb;
    this.view = usb.rp2040.usbDPRAMView;
    this.onData = onData;
    this.onReady = onReady;
    this.log = log ?? (() => {});
    this.state = 'detached';
    this.dtr = true;
    this.sentDtr = null;
    this.pending = []; // host -> device chunks
    this.pendingBytes = 0;
    this.armed = new Map(); // OUT endpoint -> requested length, while AVAILABLE is held
    this.deliveries = new Map(); // OUT endpoint -> { alarm, data }
    this.cdc = null;
    this.bytesIn = 0;
    this.bytesOut = 0;
    this.nextAlarm = makeAlarm(clock, () => this.nextRequest());
    // A request the firmware STALLs (or never answers) would otherwise hang enumeration.
    this.timeoutAlarm = makeAlarm(clock, () => this.controlTimeout());
    this.clock = clock;
    this.attach();
  }

  attach() {
    const { usb } = this;
    usb.onUSBEnabled = () => {
      this.state = 'resetting';
      this.cdc = null;
      usb.resetDevice();
    };
    usb.onResetReceived = () => {
      this.state = 'enumerating';
      this.requests = this.enumeration();
      this.control = null;
      this.nextAlarm.schedule(NEXT_REQUEST_NS);
    };
    usb.onEndpointWrite = (ep, data) => this.inPacket(ep, data);
    usb.onEndpointRead = (ep, size) => {
      this.armed.set(ep, size);
      this.outArmed(ep);
    };
    // rp2040js clears AVAILABLE as soon as firmware arms an OUT buffer, and
    // embassy-rp takes a cleared AVAILABLE as "packet received": it would read
    // 64 zero bytes in a loop. Hold AVAILABLE until we really deliver.
    const dpramUpdated = usb.DPRAMUpdated.bind(usb);
    usb.DPRAMUpdated = (offset, value) => {
      dpramUpdated(offset, value);
      if (!usb.hostMode && value & AVAILABLE && offset >= EP0_IN_BUF_CTRL && offset <= 0xfc && offset & 4) {
        this.view.setUint32(offset, this.view.getUint32(offset, true) | AVAILABLE, true);
      }
    };
  }

  /** Host -> device bytes (from the TCP client). */
  write(bytes) {
    if (!bytes.length) return;
    this.pending.push(Uint8Array.from(bytes));
    this.pendingBytes += bytes.length;
    if (this.state === 'ready') this.outArmed(this.cdc.bulkOut);
  }

  *enumeration() {
    yield { setup: setup(0x00, 5, 1, 0, 0), name: 'SET_ADDRESS' };
    const dev = yield { setup: setup(0x80, 6, DESC_DEVICE << 8, 0, 18), name: 'GET_DESCRIPTOR(device)' };
    this.deviceDescriptor = dev;
    const head = yield { setup: setup(0x80, 6, DESC_CONFIG << 8, 0, 9), name: 'GET_DESCRIPTOR(config, 9)' };
    if (!head || head.length < 4) {
      this.log('USB: no configuration descriptor; enumeration failed');
      return;
    }
    const total = head[2] | (head[3] << 8);
    const config = yield { setup: setup(0x80, 6, DESC_CONFIG << 8, 0, total), name: 'GET_DESCRIPTOR(config)' };
    if (!config) {
      this.log('USB: no configuration descriptor; enumeration failed');
      return;
    }
    this.cdc = parseCdcConfig(config);
    if (this.cdc.bulkIn < 0 || this.cdc.bulkOut < 0) {
      this.log(`USB: no CDC data interface with bulk IN/OUT in the configuration descriptor`);
      return;
    }
    yield { setup: setup(0x00, 9, this.cdc.configValue, 0, 0), name: 'SET_CONFIGURATION' };
    const lineCoding = Uint8Array.of(0x00, 0xc2, 0x01, 0x00, 0, 0, 8); // 115200 8N1, as a terminal would
    yield { setup: setup(0x21, 0x20, 0, this.cdc.commInterface, 7), data: lineCoding, name: 'SET_LINE_CODING' };
    yield this.lineStateRequest();
  }

  lineStateRequest() {
    const v = this.dtr ? 0x0003 : 0x0000;
    this.sentDtr = this.dtr;
    return { setup: setup(0x21, 0x22, v, this.cdc.commInterface, 0), name: `SET_CONTROL_LINE_STATE(${v ? 'DTR|RTS' : '0'})` };
  }

  /** DTR follows the TCP client, as a PC raises it when a program opens the port. */
  setDtr(on) {
    this.dtr = on;
    if (this.state === 'ready' && !this.control && !this.nextAlarm.pending) this.updateLineState();
  }

  updateLineState() {
    if (this.sentDtr === this.dtr) return;
    const self = this;
    this.requests = (function* () {
      yield self.lineStateRequest();
    })();
    this.state = 'line-state';
    this.nextRequest();
  }

  nextRequest() {
    const step = this.requests.next(this.control?.result);
    this.control = null;
    if (step.done) {
      if (this.cdc && this.cdc.bulkIn >= 0) {
        const first = this.state === 'enumerating';
        this.state = 'ready';
        if (!first) {
          this.outArmed(this.cdc.bulkOut);
          this.updateLineState();
          return;
        }
        this.log(`USB: CDC ready (bulk IN ${this.cdc.bulkIn}, bulk OUT ${this.cdc.bulkOut}, comm interface ${this.cdc.commInterface})`);
        this.onReady?.();
        this.outArmed(this.cdc.bulkOut);
        this.updateLineState();
      } else {
        this.state = 'failed';
      }
      return;
    }
    const req = step.value;
    const dirIn = !!(req.setup[0] & 0x80);
    const wLength = req.setup[6] | (req.setup[7] << 8);
    this.control = {
      ...req,
      phase: dirIn && wLength ? 'data-in' : req.data ? 'data-out' : 'status-in',
      wLength,
      received: [],
      receivedBytes: 0,
      sent: 0,
      result: null,
    };
    this.timeoutAlarm.schedule(CONTROL_TIMEOUT_NS);
    this.usb.sendSetupPacket(req.setup);
  }

  controlTimeout() {
    const c = this.control;
    if (!c || c.phase === 'done') return;
    this.log(`USB: ${c.name} got no answer within ${CONTROL_TIMEOUT_NS / 1e6} ms (stalled?); going on without it`);
    this.finishControl(null);
  }

  finishControl(result) {
    this.timeoutAlarm.cancel();
    this.control.result = result;
    this.control.phase = 'done';
    this.nextAlarm.schedule(NEXT_REQUEST_NS);
  }

  inPacket(ep, data) {
    const c = this.control;
    if (ep === 0) {
      if (!c) return;
      if (c.phase === 'data-in') {
        c.received.push(data);
        c.receivedBytes += data.length;
        if (data.length < MAX_PACKET || c.receivedBytes >= c.wLength) {
          c.phase = 'status-out';
          this.outArmed(0);
        }
      } else if (c.phase === 'status-in' && data.length === 0) {
        this.finishControl(new Uint8Array(0));
      }
      return;
    }
    if (this.cdc && ep === this.cdc.bulkIn && data.length) {
      this.bytesIn += data.length;
      this.onData(data);
    }
  }

  /** An OUT buffer is armed (or data/phase changed): deliver if there is something for it. */
  outArmed(ep) {
    if (!this.armed.has(ep) || this.deliveries.has(ep)) return;
    let payload = null;
    if (ep === 0) {
      const c = this.control;
      if (!c) return;
      if (c.phase === 'status-out') payload = new Uint8Array(0);
      else if (c.phase === 'data-out') payload = c.data.subarray(c.sent, c.sent + MAX_PACKET);
      else return;
    } else if (this.state === 'ready' && ep === this.cdc.bulkOut && this.pendingBytes) {
      payload = this.takePending(this.armed.get(ep));
    } else {
      return;
    }
    const alarm = makeAlarm(this.clock, () => this.deliver(ep, payload));
    this.deliveries.set(ep, alarm);
    alarm.schedule(PACKET_NS);
  }

  takePending(max) {
    const out = new Uint8Array(Math.min(max, this.pendingBytes));
    let n = 0;
    while (n < out.length) {
      const chunk = this.pending[0];
      const k = Math.min(chunk.length, out.length - n);
      out.set(chunk.subarray(0, k), n);
      n += k;
      if (k === chunk.length) this.pending.shift();
      else this.pending[0] = chunk.subarray(k);
    }
    this.pendingBytes -= n;
    return out;
  }

  deliver(ep, payload) {
    this.deliveries.delete(ep);
    const ctrl = EP0_OUT_BUF_CTRL + ep * 8;
    const bufCtrl = this.view.getUint32(ctrl, true);
    if (!(bufCtrl & AVAILABLE) || !this.armed.has(ep)) {
      // The firmware took the buffer back (e.g. a new SETUP): keep bulk data for later.
      if (ep !== 0 && payload.length) {
        this.pending.unshift(payload);
        this.pendingBytes += payload.length;
      }
      return;
    }
    const offset = this.usb.getEndpointBufferOffset(ep, true);
    const len = Math.min(payload.length, bufCtrl & LEN_MASK);
    if (ep !== 0 && len < payload.length) {
      this.pending.unshift(payload.subarray(len));
      this.pendingBytes += payload.length - len;
    }
    this.usb.rp2040.usbDPRAM.set(payload.subarray(0, len), offset);
    this.view.setUint32(ctrl, (bufCtrl & ~(AVAILABLE | LEN_MASK)) | FULL | len, true);
    this.armed.delete(ep);
    this.usb.indicateBufferReady(ep, true);
    if (ep === 0) {
      const c = this.control;
      if (c.phase === 'status-out') {
        const all = new Uint8Array(c.receivedBytes);
        let o = 0;
        for (const p of c.received) {
          all.set(p, o);
          o += p.length;
        }
        this.finishControl(all);
      } else if (c.phase === 'data-out') {
        c.sent += len;
        if (c.sent >= c.data.length) c.phase = 'status-in';
      }
    } else {
      this.bytesOut += len;
    }
  }
}
