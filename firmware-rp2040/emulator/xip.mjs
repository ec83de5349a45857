// XIP_CTRL (0x14000000) is missing from rp2040js: reads return 0xFFFFFFFF,
// and embassy-rp's flash driver spins on `while STREAM_CTR > 0` before every
// flash operation. The cache and the streaming engine are not modelled: the
// cache is always flushed and idle, the stream FIFO always empty.

import { BasePeripheral } from 'rp2040js';

const CTRL = 0x00;
const STAT = 0x08;
const STREAM_ADDR = 0x14;
const STREAM_CTR = 0x18;
const STAT_FLUSH_READY = 1 << 0;
const STAT_FIFO_EMPTY = 1 << 1;

export class XipCtrl extends BasePeripheral {
  constructor(rp2040) {
    super(rp2040, 'XIP_CTRL');
    this.ctrl = 0x3;
    this.streamAddr = 0;
  }

  readUint32(offset) {
    switch (offset) {
      case CTRL:
        return this.ctrl;
      case STAT:
        return STAT_FLUSH_READY | STAT_FIFO_EMPTY;
      case STREAM_ADDR:
        return this.streamAddr;
      case STREAM_CTR:
        return 0; // a stream finishes at once (and delivers nothing: not modelled)
      default:
        return 0; // FLUSH, hit/access counters
    }
  }

  writeUint32(offset, value) {
    if (offset === CTRL) this.ctrl = value & 0xb;
    else if (offset === STREAM_ADDR) this.streamAddr = value & ~3;
  }
}

export function installXipCtrl(rp2040) {
  rp2040.peripherals[0x14000000 >>> 12] = new XipCtrl(rp2040);
}
