#!/usr/bin/env node
// Boots a firmware ELF on an emulated RP2040 (rp2040js 1.4.1) and bridges its
// USB CDC and UART0 links to TCP listeners on 127.0.0.1. See README.md.

import fs from 'node:fs';
import path from 'node:path';
import { parseArgs } from 'node:util';
import { parseElf, loadElfIntoFlash, checkBootImage } from './elf.mjs';
import { Chip, makeLogger } from './chip.mjs';
import { Runner } from './runner.mjs';
import { CdcHost } from './usb-host.mjs';
import { TcpLink } from './tcp-link.mjs';
import { ControlServer, gpioReport } from './control.mjs';
import { EdgeCounter } from './edges.mjs';
import { PinInputs } from './pins.mjs';
import { SquareWave } from './square.mjs';
import { parseUniqueId, DEFAULT_UNIQUE_ID } from './ssi.mjs';

const USAGE = `usage: node bridge.mjs --elf <firmware.elf> [--usb <port>] [--uart0 <port>] [--control <port>]
                      [--realtime [--pace <x>]] [--flash-image <file>] [--flash-size <bytes>] [--flash-id <16 hex>]
                      [--uart-unpaced] [--lag-warn-ms <ms>] [--max-lag-ms <ms>] [--exit-on-halt] [--dtr-always]
                      [--reference-core] [-v|-vv]

  --elf           firmware ELF, the file a user flashes (PT_LOAD segments go to flash by physical address)
  --usb PORT      TCP listener for the USB CDC-ACM link (0 = pick a free port)
  --uart0 PORT    TCP listener for UART0 (0 = pick a free port)
  --control PORT  line-based JSON control channel (0 = pick a free port)
  --realtime      pace emulated time to wall time; lag is reported on stderr
  --pace X        realtime: emulated seconds per wall second (default 1). Below 1 the emulated crystal
                  runs steadily slow, so a machine too slow for real time keeps pace; a host talking to
                  it runs its own clock at the same pace (osap-host's Pace)
  --flash-image   load flash from this file if it exists (the ELF is written over it) and save it back
                  after every flash write and at exit
  --flash-size    emulated flash size in bytes (default 2097152, a Pico's W25Q16JV; suffix k/M allowed)
  --flash-id      the 8-byte SPI flash unique id (command 0x4B), 16 hex digits (default ${DEFAULT_UNIQUE_ID})
  --uart-unpaced  deliver host bytes into the UART RX FIFO as fast as it has room, not at the baud rate
  --lag-warn-ms   realtime lag that is reported on stderr (default 20)
  --max-lag-ms    realtime: never fall further behind than this; wall time beyond it is given up
                  (emulated time then runs slow) instead of caught up later (default: catch up)
  --exit-on-halt  exit with status 3 when the core halts (HardFault, BKPT, UDF, emulation error)
  --dtr-always    keep USB DTR raised even with no TCP client (default: DTR follows the client)
  --reference-core  execute every instruction with rp2040js's own decoder (no fast path)
  -v, -vv         log links and rp2040js warnings; -vv also rp2040js debug output

Once listening, one JSON line goes to stdout: {"ready":true,"usb":PORT,"uart0":PORT,"control":PORT,...}.`;

function fail(msg, code = 2) {
  process.stderr.write(`bridge: ${msg}\n`);
  process.exit(code);
}

function parseSize(text) {
  const m = /^(\d+)([kKmM]?)$/.exec(String(text));
  if (!m) fail(`--flash-size: not a size: ${text}`);
  const n = Number(m[1]) * (m[2] ? (m[2].toLowerCase() === 'k' ? 1024 : 1024 * 1024) : 1);
  if (n < 64 * 1024 || n > 16 * 1024 * 1024 || n % 4096) fail('--flash-size must be a multiple of 4096 between 64k and 16M');
  return n;
}

function parsePort(name, text) {
  if (text === undefined) return undefined;
  const n = Number(text);
  if (!Number.isInteger(n) || n < 0 || n > 65535) fail(`--${name}: not a TCP port: ${text}`);
  return n;
}

function parsePace(text, realtime) {
  const pace = Number(text);
  if (!(Number.isFinite(pace) && pace > 0 && pace <= 1)) fail(`--pace must be a number in (0, 1], not ${JSON.stringify(text)}\n${USAGE}`);
  if (pace !== 1 && !realtime) fail(`--pace needs --realtime\n${USAGE}`);
  return pace;
}

function parseCli(argv) {
  let parsed;
  try {
    parsed = parseArgs({
      args: argv,
      options: {
        elf: { type: 'string' },
        usb: { type: 'string' },
        uart0: { type: 'string' },
        control: { type: 'string' },
        realtime: { type: 'boolean', default: false },
        pace: { type: 'string', default: '1' },
        'flash-image': { type: 'string' },
        'flash-size': { type: 'string', default: '2097152' },
        'flash-id': { type: 'string', default: DEFAULT_UNIQUE_ID },
        'uart-unpaced': { type: 'boolean', default: false },
        'lag-warn-ms': { type: 'string', default: '20' },
        'max-lag-ms': { type: 'string' },
        'exit-on-halt': { type: 'boolean', default: false },
        'dtr-always': { type: 'boolean', default: false },
        'reference-core': { type: 'boolean', default: false },
        verbose: { type: 'boolean', short: 'v', multiple: true },
        help: { type: 'boolean', short: 'h' },
      },
    }).values;
  } catch (err) {
    fail(`${err.message}\n${USAGE}`);
  }
  if (parsed.help) {
    process.stdout.write(`${USAGE}\n`);
    process.exit(0);
  }
  if (!parsed.elf) fail(`--elf is required\n${USAGE}`);
  const opts = {
    elf: parsed.elf,
    usb: parsePort('usb', parsed.usb),
    uart0: parsePort('uart0', parsed.uart0),
    control: parsePort('control', parsed.control),
    realtime: parsed.realtime,
    pace: parsePace(parsed.pace, parsed.realtime),
    flashImage: parsed['flash-image'],
    flashSize: parseSize(parsed['flash-size']),
    uartPaced: !parsed['uart-unpaced'],
    lagWarnMs: Number(parsed['lag-warn-ms']),
    maxLagMs: parsed['max-lag-ms'] === undefined ? Infinity : Number(parsed['max-lag-ms']),
    exitOnHalt: parsed['exit-on-halt'],
    dtrAlways: parsed['dtr-always'],
    fastPath: !parsed['reference-core'],
    verbose: parsed.verbose?.length ?? 0,
  };
  if (opts.usb === undefined && opts.uart0 === undefined && opts.control === undefined) {
    fail(`nothing to bridge: give at least one of --usb, --uart0, --control\n${USAGE}`);
  }
  if (!Number.isFinite(opts.lagWarnMs) || opts.lagWarnMs < 0) fail('--lag-warn-ms must be a number >= 0');
  if (!(opts.maxLagMs >= 0)) fail('--max-lag-ms must be a number >= 0');
  try {
    opts.uniqueId = parseUniqueId(parsed['flash-id']);
  } catch (err) {
    fail(`--flash-id: ${err.message}`);
  }
  return opts;
}

function loadFlash(opts) {
  const flash = new Uint8Array(opts.flashSize).fill(0xff);
  if (opts.flashImage && fs.existsSync(opts.flashImage)) {
    const img = fs.readFileSync(opts.flashImage);
    if (img.length > opts.flashSize) fail(`--flash-image ${opts.flashImage} is ${img.length} bytes, larger than the ${opts.flashSize}-byte flash`);
    flash.set(img);
  }
  let elfBytes;
  try {
    elfBytes = fs.readFileSync(opts.elf);
  } catch (err) {
    fail(`cannot read ELF ${opts.elf}: ${err.code === 'ENOENT' ? 'no such file' : err.message}`);
  }
  try {
    loadElfIntoFlash(flash, parseElf(elfBytes));
  } catch (err) {
    fail(`${opts.elf}: ${err.message}`);
  }
  const problems = checkBootImage(flash);
  if (problems.length) fail(`${opts.elf} does not look like an RP2040 flash image: ${problems.join('; ')}`);
  return flash;
}

function saveFlash(file, flash) {
  const tmp = path.join(path.dirname(path.resolve(file)), `.${path.basename(file)}.tmp-${process.pid}`);
  fs.writeFileSync(tmp, flash);
  fs.renameSync(tmp, file);
}

async function main() {
  const opts = parseCli(process.argv.slice(2));
  const log = (m) => process.stderr.write(`${m}\n`);
  const vlog = opts.verbose ? log : () => {};
  const logger = makeLogger({ verbose: opts.verbose });
  const initialFlash = loadFlash(opts);
  let flashDirty = false;
  // The latest flash erases and programs, with the emulated time each
  // started at (µs): a test holds them against the step pins' edges.
  const flashWrites = [];
  if (opts.flashImage) {
    // Written at once, so a bad path fails now rather than at the first flash write.
    try {
      saveFlash(opts.flashImage, initialFlash);
    } catch (err) {
      fail(`--flash-image ${opts.flashImage}: cannot write it (${err.code ?? err.message})`);
    }
  }

  let runner = null;
  const inputs = new PinInputs();
  const square = new SquareWave(inputs);
  const edges = new EdgeCounter(() => (runner ? runner.chip.nanos / 1000 : 0));
  const usbLink = opts.usb !== undefined ? new TcpLink('usb', { onData: (d) => toUsb(d), onConnect: () => dtr(true), onDisconnect: () => dtr(false), log: vlog }) : null;
  const uartLink = opts.uart0 !== undefined ? new TcpLink('uart0', { onData: (d) => toUart(d), log: vlog }) : null;

  const toUsb = (data) => {
    runner.chip.usbHost.write(data);
    runner.wake();
  };
  const toUart = (data) => {
    runner.chip.uartFeeders[0].push(data);
    runner.wake();
  };
  const dtr = (on) => {
    if (opts.dtrAlways) return;
    runner.chip.usbHost.setDtr(on);
    runner.wake();
  };

  const build = (prev) => {
    const chip = new Chip({
      flash: prev ? prev.flash : initialFlash,
      flashSize: opts.flashSize,
      uniqueId: opts.uniqueId,
      logger,
      uartPaced: opts.uartPaced,
      fastPath: opts.fastPath,
      hooks: {
        onHalt: (reason) => runner.halt(reason),
        onResetRequest: (reason) => runner.requestReset(`firmware: ${reason}`),
        onFlashWrite: (kind, offset, length) => {
          flashDirty = true;
          flashWrites.push({ kind, offset, length, us: runner.chip.nanos / 1000 });
          if (flashWrites.length > 64) flashWrites.shift();
        },
        warn: log,
      },
    });
    chip.usbHost = new CdcHost(chip.rp.usbCtrl, chip.clock, { onData: (d) => usbLink?.send(d), log: vlog });
    chip.usbHost.dtr = opts.dtrAlways || !!usbLink?.client;
    chip.rp.uart[0].onByte = (b) => uartLink?.sendByte(b);
    chip.rp.uart[1].onByte = () => {};
    inputs.attach(chip.rp.gpio);
    edges.attach(chip.rp.gpio);
    square.attach(chip.clock);
    return chip;
  };

  const afterSlice = () => {
    usbLink?.flush();
    uartLink?.flush();
    const chip = runner.chip;
    usbLink?.throttle(chip.usbHost.pendingBytes > 65536);
    uartLink?.throttle(chip.uartFeeders[0].pending > 65536);
    if (flashDirty && opts.flashImage) {
      flashDirty = false;
      try {
        saveFlash(opts.flashImage, chip.flash);
      } catch (err) {
        log(`bridge: saving --flash-image ${opts.flashImage} failed: ${err.message}`);
      }
    }
  };

  const hasOutput = () => !!(usbLink?.pending || uartLink?.pending);
  runner = new Runner({ build, afterSlice, hasOutput, realtime: opts.realtime, pace: opts.pace, lagWarnMs: opts.lagWarnMs, maxLagMs: opts.maxLagMs, log });
  if (opts.exitOnHalt) {
    const halt = runner.halt.bind(runner);
    runner.halt = (reason) => {
      halt(reason);
      shutdown(3);
    };
  }

  const control = opts.control !== undefined ? new ControlServer(commands(), { log: vlog }) : null;
  function commands() {
    return {
      gpio: () => gpioReport(runner.chip.rp.gpio),
      count: (m) => {
        edges.start(runner.chip.rp.gpio, Number(m.step), Number(m.dir));
        return edges.snapshot();
      },
      counts: () => edges.snapshot(),
      input: (m) => {
        inputs.force(Number(m.pin), m.level === null || m.level === undefined ? null : !!Number(m.level));
        runner.wake(); // a GPIO interrupt may be due
        // The change takes effect now: at the current emulated time, and at
        // this instant on the host's monotonic clock, the one every byte
        // crossing the bridge also meets. A test holds the module's time
        // stamp of the edge to the host's time at that instant.
        return {
          pin: Number(m.pin),
          forced: inputs.forced.has(Number(m.pin)),
          emulated_ns: runner.chip.nanos,
          monotonic_ns: process.hrtime.bigint().toString(),
          // Behind wall time at this instant: asleep between slices the
          // emulated clock stands still while wall time runs on.
          behind_ms: runner.realtime ? runner.behindNowMs() : null,
        };
      },
      // A square wave on an input: {"pin":10,"period_us":1250} starts
      // it, {} stops it; answers the pin, period and rising edges made.
      square: (m) => {
        const r = m.period_us === undefined || m.period_us === null ? square.stop() : square.start(Number(m.pin), Number(m.period_us));
        runner.wake(); // its first edge is an alarm to run to
        return { ...r, emulated_ns: runner.chip.nanos };
      },
      'count-stop': () => {
        const s = edges.snapshot();
        edges.stop();
        return s;
      },
      time: () => ({ us: runner.chip.nanos / 1000 }),
      reset: () => {
        runner.requestReset('control');
        return {};
      },
      stats: () => ({
        ...runner.stats(),
        usb: usbLink && { state: runner.chip.usbHost.state, dtr: runner.chip.usbHost.sentDtr, ...usbLink.stats, queued_to_device: runner.chip.usbHost.pendingBytes },
        uart0: uartLink && { ...uartLink.stats, queued_to_device: runner.chip.uartFeeders[0].pending, baud: runner.chip.rp.uart[0].baudRate },
        rom_calls: runner.chip.rom.calls,
        flash_writes: flashWrites,
        decoder: runner.chip.decoderStats,
        rp2040js_warnings: logger.warnings,
      }),
      flash: (m) => {
        const off = Number(m.offset ?? 0);
        const len = Math.min(Number(m.length ?? 256), 4096);
        if (!(off >= 0 && off + len <= opts.flashSize)) throw new Error('offset/length outside flash');
        return { offset: off, hex: Buffer.from(runner.chip.flash.subarray(off, off + len)).toString('hex') };
      },
    };
  }

  let shuttingDown = false;
  function shutdown(code) {
    if (shuttingDown) return;
    shuttingDown = true;
    runner.stopping = true;
    try {
      usbLink?.flush();
      uartLink?.flush();
      if (opts.flashImage) saveFlash(opts.flashImage, runner.chip.flash);
    } catch (err) {
      log(`bridge: saving --flash-image failed: ${err.message}`);
    }
    usbLink?.close();
    uartLink?.close();
    control?.close();
    setTimeout(() => process.exit(code), 20);
  }
  process.on('SIGINT', () => shutdown(0));
  process.on('SIGTERM', () => shutdown(0));

  const ports = {};
  try {
    if (usbLink) ports.usb = await usbLink.listen(opts.usb);
    if (uartLink) ports.uart0 = await uartLink.listen(opts.uart0);
    if (control) ports.control = await control.listen(opts.control);
  } catch (err) {
    usbLink?.close();
    uartLink?.close();
    control?.close();
    fail(err.message);
  }
  process.stdout.write(`${JSON.stringify({ ready: true, ...ports, realtime: opts.realtime, pace: opts.pace, pid: process.pid })}\n`);
  await runner.run();
}

main().catch((err) => fail(err.stack || String(err), 1));
