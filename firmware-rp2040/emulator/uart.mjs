// UART fixes for rp2040js 1.4.1 and a host-side feeder that delivers bytes
// into the RX FIFO at the configured baud rate.

import { makeAlarm } from './alarm.mjs';

const UARTDR = 0x00;
const UARTRSR = 0x04;
const UARTIFLS = 0x34;
const UARTDMACR = 0x48;
const TXINTR = 1 << 5;
const UARTEN = 1 << 0;
const RXE = 1 << 9;

/**
 * 1. UARTRSR/UARTIFLS/UARTDMACR read as 0xFFFFFFFF in rp2040js; embassy-rp's
 *    BufferedUart handler then sees RXDMAE and returns without serving the
 *    FIFO. Back them with storage.
 * 2. rp2040js raises the TX interrupt on every interrupt check, so UART0_IRQ
 *    re-enters forever after the firmware clears it. On a PL011 the TX
 *    interrupt latches when the FIFO drains past the trigger level; here the
 *    FIFO drains instantly, so that is "after every data write".
 */
export function patchUart(uart) {
  const regs = { [UARTRSR]: 0, [UARTIFLS]: 0x12, [UARTDMACR]: 0 };
  const read = uart.readUint32.bind(uart);
  const write = uart.writeUint32.bind(uart);
  uart.checkInterrupts = function () {
    this.rp2040.setInterrupt(this.irq, !!(this.interruptStatus & this.interruptMask));
  };
  uart.readUint32 = (offset) => (offset in regs ? regs[offset] : read(offset));
  uart.writeUint32 = (offset, value) => {
    if (offset in regs) {
      regs[offset] = offset === UARTRSR ? 0 : value; // writing RSR/ECR clears the error flags
      return;
    }
    write(offset, value);
    if (offset === UARTDR) {
      uart.interruptStatus |= TXINTR;
      uart.checkInterrupts();
    }
  };
}

/**
 * Moves host bytes into the RX FIFO one byte-time apart (10 bit times at the
 * firmware's baud rate), and only while the 32-byte FIFO has room: rp2040js
 * silently drops overflow, and a real host link would not outrun the baud
 * rate either. Bytes wait until the firmware has enabled the UART receiver.
 */
export class UartFeeder {
  constructor(uart, clock, { paced = true } = {}) {
    this.uart = uart;
    this.paced = paced;
    this.queue = [];
    this.head = 0;
    this.fed = 0;
    this.alarm = makeAlarm(clock, () => this.pump());
  }

  get pending() {
    return this.queue.length - this.head;
  }

  push(bytes) {
    for (const b of bytes) this.queue.push(b);
    if (!this.alarm.pending) this.pump();
  }

  byteNanos() {
    const baud = this.uart.baudRate;
    return this.paced && Number.isFinite(baud) && baud > 0 ? 10e9 / baud : 0;
  }

  pump() {
    const { uart } = this;
    const ready = (uart.ctrlRegister & (UARTEN | RXE)) === (UARTEN | RXE);
    if (ready) {
      const step = this.byteNanos();
      while (this.pending && !uart.rxFIFO.full) {
        uart.feedByte(this.queue[this.head++]);
        this.fed++;
        if (step) break;
      }
      if (this.head > 4096 && this.head * 2 > this.queue.length) {
        this.queue = this.queue.slice(this.head);
        this.head = 0;
      }
    }
    // Retry later when waiting for the receiver, for FIFO room, or for the next byte time.
    if (this.pending) this.alarm.schedule(this.byteNanos() || 10_000);
  }
}
