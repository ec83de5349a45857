// Answers the two SPI flash identification commands firmware sends by hand
// through the SSI (embassy-rp's blocking_unique_id / blocking_jedec_id):
// 0x4B read unique id (4 dummy bytes, then 8 id bytes) and 0x9F JEDEC id.
// rp2040js's SSI only knows enough for boot2 (SR always "RX not empty", DR
// reads 0), so we queue the reply frames ourselves and leave every other
// command to it: boot2 must keep working unchanged.

const SSIENR = 0x08;
const RXFLR = 0x24;
const DR0 = 0x60;

export const CMD_UNIQUE_ID = 0x4b;
export const CMD_JEDEC_ID = 0x9f;
// Winbond W25Q16JV, the Pico's flash.
export const DEFAULT_JEDEC_ID = [0xef, 0x40, 0x15];
export const DEFAULT_UNIQUE_ID = 'e6614c311b4f5a01';

export function parseUniqueId(text) {
  const hex = String(text).replace(/^0x/i, '').replace(/[:\s-]/g, '');
  if (!/^[0-9a-fA-F]{16}$/.test(hex)) {
    throw new Error(`flash unique id must be 16 hex digits (8 bytes), got "${text}"`);
  }
  return Uint8Array.from(hex.match(/../g).map((h) => parseInt(h, 16)));
}

export function patchSsi(ssi, { uniqueId, jedecId = DEFAULT_JEDEC_ID }) {
  let firstAfterEnable = false;
  let rx = [];
  const read = ssi.readUint32.bind(ssi);
  const write = ssi.writeUint32.bind(ssi);
  ssi.commandsSeen = { uniqueId: 0, jedecId: 0 };

  ssi.writeUint32 = (offset, value) => {
    if (offset === SSIENR && value & 1 && !(ssi.ssienr & 1)) {
      firstAfterEnable = true;
      rx = [];
    } else if (offset === DR0 && firstAfterEnable) {
      firstAfterEnable = false;
      const cmd = value & 0xff; // byte stores arrive replicated on all 4 lanes
      const frames = (ssi.crtlr1 & 0xffff) + 1; // CTRLR1.NDF + 1 in EEPROM-read mode
      let reply = null;
      if (cmd === CMD_UNIQUE_ID) {
        reply = [0, 0, 0, 0, ...uniqueId];
        ssi.commandsSeen.uniqueId++;
      } else if (cmd === CMD_JEDEC_ID) {
        reply = [...jedecId];
        ssi.commandsSeen.jedecId++;
      }
      if (reply) {
        const tmod = (ssi.crtlr0 >>> 8) & 3;
        if (tmod === 0) reply.unshift(0xff); // TX-and-RX mode also clocks in a frame for the command byte
        while (reply.length < frames) reply.push(0xff);
        rx = reply;
      }
    }
    write(offset, value);
  };

  ssi.readUint32 = (offset) => {
    if (rx.length) {
      if (offset === DR0) return rx.shift();
      if (offset === RXFLR) return rx.length;
    }
    return read(offset);
  };
}
