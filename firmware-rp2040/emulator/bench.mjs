// Measures how fast the emulator executes a busy Thumb loop in SRAM (no
// firmware needed): the bare core with the fast decoder and with rp2040js's
// own, then through the Runner the bridge uses, alone and beside a PIO state
// machine at three clock dividers. Prints JSON.
//   node bench.mjs [seconds]

import { Chip, makeLogger } from './chip.mjs';
import { Runner } from './runner.mjs';

const seconds = Number(process.argv[2] ?? 2);
// loop: adds r0,#1; ldr r1,[r2]; str r1,[r3]; b loop  (RAM load/store, ALU, branch)
const LOOP = [0x3001, 0x6811, 0x6019, 0xe7fb];

/** A PIO0 state machine toggling GPIO2 every instruction, at clock divider `div`. */
function startPio(chip, div) {
  const { rp } = chip;
  const P = 0x50200000;
  [0xe081, 0xe001, 0xe000].forEach((op, i) => rp.writeUint32(P + 0x48 + 4 * i, op));
  rp.writeUint32(P + 0xc8, div << 16);
  rp.writeUint32(P + 0xcc, (2 << 12) | (1 << 7));
  rp.writeUint32(P + 0xdc, (1 << 26) | (2 << 5));
  rp.writeUint32(0x40014000 + 8 * 2 + 4, 6);
  rp.writeUint32(P, 1);
}

function busyChip(fastPath = true) {
  const chip = new Chip({
    fastPath,
    flash: new Uint8Array(64 * 1024).fill(0xff),
    flashSize: 64 * 1024,
    uniqueId: new Uint8Array(8),
    logger: makeLogger(),
    hooks: {},
  });
  const { rp, core } = chip;
  LOOP.forEach((op, i) => rp.writeUint16(0x20000000 + 2 * i, op));
  core.registers[2] = core.registers[3] = 0x20001000;
  core.PC = 0x20000000;
  return chip;
}

function bare(fastPath) {
  const chip = busyChip(fastPath);
  const { core, clock } = chip;
  const t0 = performance.now();
  let cycles = 0;
  while (performance.now() - t0 < (seconds * 1000) / 4) {
    for (let i = 0; i < 100000; i++) {
      const c = core.executeInstruction();
      cycles += c;
      clock.tick(c * 8);
    }
  }
  return cycles / ((performance.now() - t0) / 1000);
}

async function viaRunner(pioDiv = 0) {
  const build = () => {
    const chip = busyChip();
    if (pioDiv) startPio(chip, pioDiv);
    return chip;
  };
  const runner = new Runner({ build, log: () => {} });
  const run = runner.run();
  await new Promise((r) => setTimeout(r, seconds * 1000));
  runner.stopping = true;
  await run;
  return runner.busyCyclesPerSecond();
}

// Best of two interleaved runs each: the machine may be shared.
const best = (a, b) => Math.round(Math.max(a, b));
const fast1 = bare(true);
const ref1 = bare(false);
const fast2 = bare(true);
const ref2 = bare(false);
const runnerRate = await viaRunner();
const out = {
  core_loop_fast_decoder_cycles_per_s: best(fast1, fast2),
  core_loop_rp2040js_decoder_cycles_per_s: best(ref1, ref2),
  runner_cycles_per_s: Math.round(runnerRate),
  runner_x_realtime_125MHz: +(runnerRate / 125e6).toFixed(3),
};
// PIO cost: one state machine running flat out (no stalls) beside the busy core.
for (const div of [125, 10, 1]) {
  const rate = await viaRunner(div);
  out[`with_pio_clkdiv_${div}_cycles_per_s`] = Math.round(rate);
}
process.stdout.write(`${JSON.stringify(out)}\n`);
