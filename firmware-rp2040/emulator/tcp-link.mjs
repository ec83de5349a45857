// One link as a TCP listener on 127.0.0.1 carrying the raw byte stream, as a
// serial port would. One client at a time: a second one is refused while the
// first is connected; after a disconnect the next client is accepted. Device
// output with no client connected is dropped (and counted), like a serial
// port nobody has open.

import net from 'node:net';

export class TcpLink {
  constructor(name, { onData, onConnect, onDisconnect, log }) {
    this.name = name;
    this.onData = onData;
    this.onConnect = onConnect;
    this.onDisconnect = onDisconnect;
    this.log = log ?? (() => {});
    this.client = null;
    this.outChunks = [];
    this.outBytesArr = [];
    this.outBytes = 0;
    this.stats = { toHost: 0, fromHost: 0, dropped: 0, clients: 0, refused: 0 };
    this.paused = false;
  }

  /** Resolves with the bound port; rejects with a readable message (e.g. port in use). */
  listen(port) {
    this.server = net.createServer((sock) => this.accept(sock));
    return new Promise((resolve, reject) => {
      this.server.once('error', (err) => {
        const why = err.code === 'EADDRINUSE' ? 'is already in use' : err.code === 'EACCES' ? 'is not allowed' : `failed (${err.message})`;
        reject(new Error(`--${this.name} port ${port}: listening on 127.0.0.1:${port} ${why}`));
      });
      this.server.listen(port, '127.0.0.1', () => {
        this.server.on('error', (err) => this.log(`${this.name}: server error ${err.message}`));
        this.port = this.server.address().port;
        resolve(this.port);
      });
    });
  }

  accept(sock) {
    if (this.client) {
      this.stats.refused++;
      this.log(`${this.name}: refused a second client (one at a time)`);
      sock.destroy();
      return;
    }
    this.client = sock;
    this.stats.clients++;
    sock.setNoDelay(true);
    this.log(`${this.name}: client connected`);
    sock.on('data', (data) => {
      this.stats.fromHost += data.length;
      this.onData(data);
    });
    const gone = () => {
      if (this.client !== sock) return;
      this.client = null;
      this.paused = false;
      this.log(`${this.name}: client disconnected`);
      this.onDisconnect?.();
    };
    sock.on('close', gone);
    sock.on('error', () => sock.destroy());
    this.onConnect?.();
  }

  /** Queues device output; flush() sends it (batched per emulation slice). */
  send(bytes) {
    if (!this.client) {
      this.stats.dropped += bytes.length;
      return;
    }
    this.gatherBytes(); // keep the order of mixed byte and chunk output
    this.outChunks.push(Uint8Array.from(bytes));
    this.outBytes += bytes.length;
  }

  get pending() {
    return this.outChunks.length > 0 || this.outBytesArr.length > 0;
  }

  /** Byte-at-a-time output (UART TX), gathered until the next flush. */
  sendByte(b) {
    if (!this.client) {
      this.stats.dropped++;
      return;
    }
    this.outBytesArr.push(b);
  }

  gatherBytes() {
    if (this.outBytesArr.length) {
      this.outChunks.push(Uint8Array.from(this.outBytesArr));
      this.outBytesArr = [];
    }
  }

  flush() {
    this.gatherBytes();
    if (!this.outChunks.length) return;
    const data = Buffer.concat(this.outChunks);
    this.outChunks = [];
    this.outBytes = 0;
    if (!this.client) {
      this.stats.dropped += data.length;
      return;
    }
    this.stats.toHost += data.length;
    this.client.write(data);
  }

  /** Back-pressure toward the host when the device is not reading. */
  throttle(stop) {
    if (!this.client || stop === this.paused) return;
    this.paused = stop;
    if (stop) this.client.pause();
    else this.client.resume();
  }

  close() {
    this.client?.destroy();
    this.server?.close();
  }
}
