// Runs the maxl cycle probe (maxl/cycle-probe, thumbv6m-none-eabi ELF
// linked into SRAM) on rp2040js's Cortex-M0+ core and prints the cycles
// between its bkpt marker pairs. Usage: node maxl-cycles.js ELF RP2040JS_DIR
'use strict';
const path = require('path');
const { runProbe } = require(path.join(__dirname, 'cycle-probe.js'));

const [elfPath, jsDir] = process.argv.slice(2);
const marks = {};
const r0At = {};
runProbe(elfPath, jsDir, (code, core) => {
  marks[code] = core.cycles;
  r0At[code] = core.registers[0];
}, 50e6);

// Cycles between markers a and b, less the cost of an empty marker pair.
const overhead = marks[1] - marks[0];
const span = (a, b) => marks[b] - marks[a] - overhead;
const perSeg = r0At[7];
const rows = [
  ['TickEval::load (per segment, 1024 us / 10 us ticks, du0 = 3)', span(2, 3)],
  ['TickEval::load at 16384 us / 10 us ticks', span(22, 23)],
  ['TickEval::load, differences >= 2^27 raw (i128 path)', span(24, 25)],
  ['TickEval::next (one tick, call + return)', span(4, 5)],
  [`TickEval::next in a loop, per tick (${perSeg} ticks)`, (span(6, 7) / perSeg).toFixed(1)],
  ['Point::eval for Fx (i64), position only', span(8, 9)],
  ['Point::eval for Fx (i64), pos + vel + acc + jerk', span(10, 11)],
  ['StepGen::tick (with a step)', span(12, 13)],
  ['PhaseOut::coils', span(14, 15)],
  ['ISR body: TickEval::next + StepGen::tick', span(16, 17)],
  ['Limiter<Fx>::push (clamped point)', span(18, 19)],
  ['Limiter<Fx>::push (point within limits)', span(20, 21)],
];
const ticks = perSeg + 1;
const load = span(2, 3);
const loop = span(6, 7) / perSeg;
console.log('Cortex-M0+ cycles (rp2040js 1.4.1 core model, code and data in SRAM;');
console.log(`marker overhead ${overhead} cycle(s) subtracted)`);
for (const [name, c] of rows) console.log(`${String(c).padStart(8)}  ${name}`);
console.log(`amortized per tick at 1024 us / 10 us: ${(loop + load / ticks).toFixed(1)} ` +
  `(${loop.toFixed(1)} per tick + ${load} setup / ${ticks} ticks)`);
console.log(`share of a 125 MHz core at 100 kHz: ${((loop + load / ticks) / 1250 * 100).toFixed(1)} %`);
