// The firmware's cost per counted edge, on the emulated chip: boots the
// firmware with no host, then compares the core's busy cycles over 1 s of
// emulated time idle, with a 10 kHz square wave on a digital pin, and
// idle again. Cycles are rp2040js's Cortex-M0+ counts (code runs from its
// flash model, without a real chip's XIP cache misses).
//
// Usage: node edge-cost.mjs FIRMWARE.elf [GPIO, default 10]
import { spawn } from 'node:child_process';
import net from 'node:net';
import readline from 'node:readline';
const elf = process.argv[2];
if (!elf) { console.error("usage: node edge-cost.mjs FIRMWARE.elf [GPIO]"); process.exit(2); }
const child = spawn('node', ['bridge.mjs', '--elf', elf, '--control', '0'], { stdio: ['ignore', 'pipe', 'inherit'] });
const rl = readline.createInterface({ input: child.stdout });
const ready = JSON.parse(await new Promise((r) => rl.once('line', r)));
const sock = net.connect(ready.control, '127.0.0.1');
const lines = readline.createInterface({ input: sock });
const queue = [];
lines.on('line', (l) => queue.shift()(JSON.parse(l)));
const cmd = (o) => new Promise((r) => { queue.push(r); sock.write(JSON.stringify(o) + '\n'); });
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
async function until(us) { for (;;) { const t = (await cmd({ cmd: 'time' })).us; if (t >= us) return t; await sleep(5); } }
async function window(label, lenUs) {
  const a = await cmd({ cmd: 'stats' }); const t0 = (await cmd({ cmd: 'time' })).us;
  const t1 = await until(t0 + lenUs);
  const b = await cmd({ cmd: 'stats' });
  const cyc = b.cycles_executed - a.cycles_executed;
  console.log(`${label}: ${cyc} busy cycles over ${((t1 - t0) / 1e6).toFixed(3)} s emulated`);
  return { cyc, s: (t1 - t0) / 1e6 };
}
await until(1_500_000); // boot
const idle = await window('idle', 1_000_000);
const r = await cmd({ cmd: 'square', pin: Number(process.argv[3] ?? 10), period_us: 100 });
const wave = await window('10 kHz on GP' + (process.argv[3] ?? 10), 1_000_000);
const s = await cmd({ cmd: 'square' });
const idle2 = await window('idle again', 1_000_000);
const base = (idle.cyc / idle.s + idle2.cyc / idle2.s) / 2;
const perEdge = (wave.cyc / wave.s - base) / 10_000;
console.log(`rising edges made: ${s.rising}; extra cycles per rising edge: ${perEdge.toFixed(0)} (${(perEdge * 8 / 1000).toFixed(2)} µs at 125 MHz)`);
child.kill(); process.exit(0);
