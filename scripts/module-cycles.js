// Runs the osap-module cycle probe (osap-module/cycle-probe,
// thumbv6m-none-eabi ELF linked into SRAM) on rp2040js's Cortex-M0+ core
// and prints the cycles of each step word it fills. Usage:
// node module-cycles.js ELF RP2040JS_DIR
'use strict';
const path = require('path');
const { runProbe } = require(path.join(__dirname, 'cycle-probe.js'));

const [elfPath, jsDir] = process.argv.slice(2);
// Every span of each marker pair (2k, 2k + 1), in order, with r0..r2 as
// they were at the opening marker.
const open = {};
const spans = {};
let checks = null;
let heaterCheck = null;
runProbe(elfPath, jsDir, (code, core) => {
  const r = core.registers;
  if (code === 6) { checks = { up: r[0], late: r[1], mode: r[2] }; return; }
  if (code === 12) { heaterCheck = { states: r[0] >>> 0, duty: r[1] >>> 0 }; return; }
  if (code % 2 === 0) {
    open[code] = { at: core.cycles, r0: r[0] >>> 0, r1: r[1] >>> 0 };
  } else {
    const o = open[code - 1];
    if (!o) throw new Error(`marker ${code} without ${code - 1}`);
    (spans[code - 1] ??= []).push({ cycles: core.cycles - o.at, r0: o.r0, r1: o.r1 });
    delete open[code - 1];
  }
}, 200e6);

const overhead = spans[0][0].cycles;
const avg = (xs) => xs.reduce((a, b) => a + b, 0) / xs.length;
const max = (xs) => Math.max(...xs);
const min = (xs) => Math.min(...xs);
// Words per second at 100 kHz ticks, 16 ticks a word; share of 125 MHz.
const WORDS_PER_S = 6250;
const share = (c) => `${(c * WORDS_PER_S / 125e6 * 100).toFixed(2)} %`;
const row = (c, name) => console.log(`${String(c).padStart(8)}  ${name}`);

// Every word in call order: idle (2), warm-up (8), tracking (4). The
// module re-reads its time map for a word more than ANCHOR_SPAN_US after
// the last reading and otherwise offsets that reading; a word starts a
// segment when one of its 16 ticks (10 µs apart from the anchored start
// time) is the first past a 1024 µs boundary.
const ANCHOR_SPAN_US = 4096;
const IV = 1024;
const words = [2, 8, 4].flatMap((m) =>
  spans[m].map((s) => ({ phase: m, local: s.r0, sys: s.r1, cycles: s.cycles - overhead })));
words.sort((a, b) => a.local - b.local);
let anchor = null;
for (const w of words) {
  w.anchor = anchor === null || w.local - anchor.local >= ANCHOR_SPAN_US;
  if (w.anchor) anchor = w;
  const t0 = anchor.sys + (w.local - anchor.local);
  w.segment = false;
  for (let k = 0; k < 16; k++) if ((t0 + 10 * k) % IV < 10) w.segment = true;
}

const idle = words.filter((w) => w.phase === 2).map((w) => w.cycles);
const idlePlain = words.filter((w) => w.phase === 2 && !w.anchor).map((w) => w.cycles);
const track = words.filter((w) => w.phase === 4);
const all = track.map((w) => w.cycles);
const cls = (seg, anc) => track.filter((w) => w.segment === seg && w.anchor === anc).map((w) => w.cycles);
const worst = track.reduce((a, b) => (b.cycles > a.cycles ? b : a));
const what = (w) => [w.segment && 'loads a segment', w.anchor && 're-reads the time map'].filter(Boolean).join(' and ') || 'neither';

console.log('Cortex-M0+ cycles per fill_step_word call, call and return included');
console.log(`(rp2040js 1.4.1 core model, code and data in SRAM; marker overhead ${overhead} cycle(s) subtracted)`);
console.log('idle enabled axis (no stream):');
row(avg(idle).toFixed(1), `average over ${idle.length} words; ${share(avg(idle))} of 125 MHz at ${WORDS_PER_S} words/s`);
row(max(idle), 'worst word (re-reads the time map)');
row(avg(idlePlain).toFixed(1), `words that do not re-read the time map (${idlePlain.length}), average (min ${min(idlePlain)}, max ${max(idlePlain)})`);
console.log('tracking a stream (1024 us interval, +400 ppm time map):');
row(avg(all).toFixed(1), `average over ${all.length} words (${(all.length * 160 / IV).toFixed(0)} segments); ${share(avg(all))} of 125 MHz at ${WORDS_PER_S} words/s`);
row(worst.cycles, `worst word (${what(worst)}); ${share(worst.cycles)} if every word cost it`);
for (const [seg, anc, name] of [[false, false, 'plain words'], [true, false, 'words that load a segment'],
  [false, true, 'words that re-read the time map'], [true, true, 'words that do both']]) {
  const xs = cls(seg, anc);
  if (xs.length) row(avg(xs).toFixed(1), `${name} (${xs.length}), average (min ${min(xs)}, max ${max(xs)})`);
}
if (!checks) throw new Error('no checks marker');
const modes = ['disabled', 'idle', 'tracking', 'backstop', 'halted'];
console.log(`checks: ${checks.up} steps up in the stream, ${checks.late} late steps, ` +
  `mode ${modes[checks.mode] ?? checks.mode} at the end`);
if (checks.late !== 0 || checks.mode !== 2) throw new Error('the stream did not track cleanly');

// Heater periods (10/11): each heater's Module::poll_heater in its own
// critical section, two heaters holding their targets.
const heaters = (spans[10] ?? []).map((s) => s.cycles - overhead);
if (heaters.length === 0 || !heaterCheck) throw new Error('no heater periods');
console.log('one heater\'s control period (two heaters holding; Module::poll_heater, each in its own critical section):');
row(avg(heaters).toFixed(1), `average over ${heaters.length} heater periods (${(avg(heaters) / 125).toFixed(1)} us at 125 MHz)`);
row(max(heaters), `worst period (${(max(heaters) / 125).toFixed(1)} us with interrupts masked)`);
console.log(`checks: heater states ${heaterCheck.states & 0xff} and ${heaterCheck.states >> 8} ` +
  `(2: holding), heater 0 duty ${heaterCheck.duty} of 65535`);
if (heaterCheck.states !== 0x0202 || heaterCheck.duty === 0) throw new Error('the heaters did not hold');
