// Smoke test of a firmware ELF in the bridge: it must boot, enumerate over
// USB as a CDC-ACM device and not halt; with --expect-usb-output it must also
// send something on the USB link once a client is connected.
//   node smoke.mjs --elf <firmware.elf> [--expect-usb-output] [--timeout-s 30]
// Prints one JSON summary line; exit 0 on success, 1 on failure, 2 on usage.

import { spawn } from 'node:child_process';
import net from 'node:net';
import path from 'node:path';
import { parseArgs } from 'node:util';
import { fileURLToPath } from 'node:url';

const here = path.dirname(fileURLToPath(import.meta.url));
let opts;
try {
  opts = parseArgs({
    options: {
      elf: { type: 'string' },
      'expect-usb-output': { type: 'boolean', default: false },
      'timeout-s': { type: 'string', default: '30' },
    },
  }).values;
} catch (err) {
  process.stderr.write(`smoke: ${err.message}\n`);
  process.exit(2);
}
if (!opts.elf) {
  process.stderr.write('smoke: --elf is required\n');
  process.exit(2);
}
const deadline = Date.now() + Number(opts['timeout-s']) * 1000;

const bridge = spawn(process.execPath, [path.join(here, 'bridge.mjs'), '--elf', opts.elf, '--usb', '0', '--control', '0', '--exit-on-halt'], {
  stdio: ['ignore', 'pipe', 'pipe'],
});
let stderr = '';
bridge.stderr.on('data', (d) => (stderr += d));
const exited = new Promise((resolve) => bridge.on('exit', (code) => resolve(code)));

function finish(ok, summary) {
  process.stdout.write(`${JSON.stringify({ ok, ...summary, stderr: stderr.trim() || undefined })}\n`);
  bridge.kill('SIGTERM');
  process.exit(ok ? 0 : 1);
}

const ready = await Promise.race([
  new Promise((resolve) => {
    let out = '';
    bridge.stdout.on('data', (d) => {
      out += d;
      if (out.includes('\n')) resolve(JSON.parse(out.split('\n')[0]));
    });
  }),
  exited.then((code) => ({ exited: code })),
]);
if (ready.exited !== undefined) finish(false, { error: `bridge exited with status ${ready.exited} before it was ready` });

function control(cmd) {
  return new Promise((resolve, reject) => {
    const sock = net.connect(ready.control, '127.0.0.1', () => sock.write(`${JSON.stringify(cmd)}\n`));
    let buf = '';
    sock.on('data', (d) => {
      buf += d;
      if (buf.includes('\n')) {
        sock.end();
        resolve(JSON.parse(buf.split('\n')[0]));
      }
    });
    sock.on('error', reject);
  });
}

let received = 0;
const usb = net.connect(ready.usb, '127.0.0.1');
usb.on('data', (d) => (received += d.length));
usb.on('error', () => {});

for (;;) {
  const code = await Promise.race([exited, new Promise((r) => setTimeout(() => r(undefined), 200))]);
  if (code !== undefined) finish(false, { error: `bridge exited with status ${code}` });
  const stats = await control({ cmd: 'stats' });
  const summary = { emulated_us: Math.round(stats.emulated_us), usb_state: stats.usb.state, usb_bytes_from_device: received };
  if (stats.halted) finish(false, { ...summary, error: `halted: ${stats.halted}` });
  if (stats.usb.state === 'ready' && (!opts['expect-usb-output'] || received > 0)) finish(true, summary);
  if (Date.now() > deadline) finish(false, { ...summary, error: 'timed out' });
}
