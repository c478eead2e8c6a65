#!/usr/bin/env node
// Runs the Score firmware (ELF or UF2) in rp2040js 1.4.1 with its USB CDC-ACM interfaces bridged
// to pseudo-terminals, and a JSON-lines control channel on stdin/stdout for tests.
//
//   node harness.mjs <firmware.elf|.uf2> [--term PATH] [--link PATH] [--bootrom FILE]
//
// Without --bootrom the chip starts at boot2 with SP set by hand (enough for the default
// firmware); firmware built with `rom-floats` calls ROM routines and needs the 16 KiB B1 bootrom.
// * USB: the harness is the USB host. It enumerates the device, finds every CDC function
//   (communications interface + data interface with bulk IN/OUT) and bridges function 0 to the
//   PTY at --term and function 1 to --link, through `socat PTY,link=PATH,raw,echo=0` connected
//   to a loopback TCP socket of this process.
// * rp2040js clears AVAILABLE of a bulk OUT buffer as soon as the firmware arms it, so
//   embassy-rp would read 64 stale bytes; the harness gives bulk OUT endpoints real NAK
//   behaviour (AVAILABLE stays set until host data lands). See shared reference
//   rp2040-emulation.md §3.4 and README.md here.
// * Control (one JSON object per line on stdin, one reply per line on stdout, same "id"):
//     {"id":1,"cmd":"adc","channel":0,"value":2048}     raw 12-bit code (0-4095), or
//     {"id":1,"cmd":"adc","channel":0,"volts":1.65}     (channel 4 = temperature sensor)
//     {"id":2,"cmd":"pwm","pin":2,"periods":8}          duty measured at the pin from its edges
//     {"id":3,"cmd":"dtr","port":"term","on":true}      CDC SET_CONTROL_LINE_STATE (DTR|RTS)
//     {"id":4,"cmd":"gpio","pin":5,"level":1}           drive an input pin
//     {"id":5,"cmd":"time"}                             emulated time (ns) and CPU cycles
//     {"id":6,"cmd":"quit"}
//   Events (no id): {"event":"ready","term":PATH,"link":PATH,"emulated_ms":T} once the device is
//   configured and both PTYs exist. Logs go to stderr.

import fs from 'node:fs';
import net from 'node:net';
import os from 'node:os';
import path from 'node:path';
import readline from 'node:readline';
import { spawn } from 'node:child_process';
import { Simulator, ConsoleLogger, LogLevel } from 'rp2040js';

const log = (...a) => process.stderr.write(`[harness] ${a.join(' ')}\n`);

// ---------------------------------------------------------------- arguments
function parseArgs(argv) {
  const out = { firmware: null, term: null, link: null, bootrom: null };
  for (let i = 0; i < argv.length; i++) {
    const a = argv[i];
    if (a === '--term') out.term = argv[++i];
    else if (a === '--link') out.link = argv[++i];
    else if (a === '--bootrom') out.bootrom = argv[++i];
    else if (!out.firmware) out.firmware = a;
    else throw new Error(`unexpected argument ${a}`);
  }
  if (!out.firmware) throw new Error('usage: harness.mjs <firmware.elf|.uf2> [--term PATH] [--link PATH]');
  const dir = fs.mkdtempSync(path.join(os.tmpdir(), 'score-emu-'));
  out.term ??= path.join(dir, 'term');
  out.link ??= path.join(dir, 'link');
  return out;
}

// ---------------------------------------------------------------- firmware loading
const FLASH_BASE = 0x10000000;

function loadElf(bytes, flash) {
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  if (dv.getUint32(0, false) !== 0x7f454c46 || bytes[4] !== 1 || bytes[5] !== 1) {
    throw new Error('not a 32-bit little-endian ELF');
  }
  const phoff = dv.getUint32(28, true);
  const phentsize = dv.getUint16(42, true);
  const phnum = dv.getUint16(44, true);
  let loaded = 0;
  for (let i = 0; i < phnum; i++) {
    const ph = phoff + i * phentsize;
    const type = dv.getUint32(ph, true);
    const offset = dv.getUint32(ph + 4, true);
    const paddr = dv.getUint32(ph + 12, true);
    const filesz = dv.getUint32(ph + 16, true);
    if (type !== 1 || filesz === 0) continue; // PT_LOAD with bytes
    // The load (physical) address: initialised .data is stored in flash.
    if (paddr < FLASH_BASE || paddr + filesz > FLASH_BASE + flash.length) {
      throw new Error(`segment at 0x${paddr.toString(16)} is outside flash`);
    }
    flash.set(bytes.subarray(offset, offset + filesz), paddr - FLASH_BASE);
    loaded += filesz;
  }
  return loaded;
}

function loadUf2(bytes, flash) {
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  let loaded = 0;
  for (let off = 0; off + 512 <= bytes.length; off += 512) {
    if (dv.getUint32(off, true) !== 0x0a324655 || dv.getUint32(off + 4, true) !== 0x9e5d5157) {
      throw new Error(`bad UF2 block at ${off}`);
    }
    const addr = dv.getUint32(off + 12, true);
    const size = dv.getUint32(off + 16, true);
    flash.set(bytes.subarray(off + 32, off + 32 + size), addr - FLASH_BASE);
    loaded += size;
  }
  return loaded;
}

// ---------------------------------------------------------------- USB host
const AVAILABLE = 1 << 10;
const LEN_MASK = 0x3ff;

class UsbHost {
  constructor(mcu) {
    this.mcu = mcu;
    this.usb = mcu.usbCtrl;
    this.armed = new Map(); // OUT endpoint -> armed length
    this.ports = []; // { comm, outEp, inEp, queue: Buffer[], sink: fn }
    this.configured = false;
    this.ep0 = null; // current control transfer
    this.onConfigured = () => {};
  }

  install() {
    const usb = this.usb;
    const origUpdated = usb.DPRAMUpdated.bind(usb);
    const origFinish = usb.finishRead.bind(usb);
    // Patch 1: a bulk OUT buffer armed by the firmware stays AVAILABLE (NAK) until data lands.
    usb.DPRAMUpdated = (offset, value) => {
      if (!usb.hostMode && value & AVAILABLE && offset >= 0x80 && offset <= 0xfc && offset & 4) {
        const ep = (offset - 0x80) >> 3;
        if (ep >= 1 && ep <= 15) {
          this.armed.set(ep, value & LEN_MASK);
          this.pump();
          return;
        }
      }
      origUpdated(offset, value);
    };
    // Patch 2: AVAILABLE is cleared only when the data is delivered.
    usb.finishRead = (ep, buffer) => {
      if (ep !== 0) {
        const reg = 0x84 + 8 * ep;
        const view = usb.rp2040.usbDPRAMView;
        view.setUint32(reg, view.getUint32(reg, true) & ~AVAILABLE, true);
      }
      origFinish(ep, buffer);
    };
    usb.onUSBEnabled = () => usb.resetDevice();
    usb.onResetReceived = () => {
      this.enumerate().catch((e) => {
        log('enumeration failed:', e.stack || e);
        process.exit(4);
      });
    };
    usb.onEndpointRead = () => {};
    usb.onEndpointWrite = (ep, buffer) => {
      if (ep === 0) {
        this.ep0?.data(buffer);
        return;
      }
      const port = this.ports.find((p) => p.inEp === ep);
      if (port && buffer.length) port.sink(Buffer.from(buffer));
    };
  }

  control(setup, wLength, dirIn) {
    return new Promise((resolve) => {
      const chunks = [];
      let got = 0;
      this.ep0 = {
        data: (buf) => {
          if (!dirIn) {
            if (buf.length === 0) {
              this.ep0 = null;
              resolve(new Uint8Array());
            }
            return;
          }
          chunks.push(Uint8Array.from(buf));
          got += buf.length;
          if (buf.length < 64 || got >= wLength) {
            this.ep0 = null;
            const all = new Uint8Array(got);
            let o = 0;
            for (const c of chunks) {
              all.set(c, o);
              o += c.length;
            }
            resolve(all);
          }
        },
      };
      this.usb.sendSetupPacket(Uint8Array.from(setup));
    });
  }

  static setup(bmRequestType, bRequest, wValue, wIndex, wLength) {
    return [bmRequestType, bRequest, wValue & 0xff, wValue >> 8, wIndex & 0xff, wIndex >> 8, wLength & 0xff, wLength >> 8];
  }

  async enumerate() {
    const S = UsbHost.setup;
    await this.control(S(0x00, 5, 1, 0, 0), 0, false); // SET_ADDRESS 1
    const dev = await this.control(S(0x80, 6, 0x0100, 0, 18), 18, true);
    const vid = dev[8] | (dev[9] << 8);
    const pid = dev[10] | (dev[11] << 8);
    const head = await this.control(S(0x80, 6, 0x0200, 0, 9), 9, true);
    const total = head[2] | (head[3] << 8);
    const cfg = await this.control(S(0x80, 6, 0x0200, 0, total), total, true);
    this.parseConfig(cfg);
    await this.control(S(0x00, 9, 1, 0, 0), 0, false); // SET_CONFIGURATION 1
    this.configured = true;
    log(`configured ${vid.toString(16)}:${pid.toString(16)} with ${this.ports.length} CDC ports ` +
      this.ports.map((p) => `(comm ${p.comm}, out ${p.outEp}, in ${p.inEp})`).join(' '));
    for (const ep of [...this.armed.keys()]) this.pump(ep);
    this.onConfigured();
  }

  parseConfig(cfg) {
    const comms = [];
    const datas = [];
    let current = null;
    for (let i = 0; i + 1 < cfg.length && cfg[i] > 0; i += cfg[i]) {
      const type = cfg[i + 1];
      if (type === 4) {
        const number = cfg[i + 2];
        const cls = cfg[i + 5];
        current = null;
        if (cls === 0x02) comms.push(number);
        if (cls === 0x0a) {
          current = { outEp: null, inEp: null };
          datas.push(current);
        }
      } else if (type === 5 && current && (cfg[i + 3] & 3) === 2) {
        const addr = cfg[i + 2];
        if (addr & 0x80) current.inEp = addr & 0x0f;
        else current.outEp = addr & 0x0f;
      }
    }
    this.ports = datas.map((d, k) => ({ comm: comms[k], outEp: d.outEp, inEp: d.inEp, queue: [], sink: () => {} }));
  }

  async setLines(port, dtr) {
    const value = dtr ? 3 : 0; // DTR | RTS
    await this.control(UsbHost.setup(0x21, 0x22, value, port.comm, 0), 0, false);
  }

  send(port, bytes) {
    port.queue.push(Buffer.from(bytes));
    this.pump(port.outEp);
  }

  pump(only) {
    if (!this.configured) return;
    for (const port of this.ports) {
      const ep = port.outEp;
      if ((only !== undefined && ep !== only) || !this.armed.has(ep) || port.queue.length === 0) continue;
      const max = Math.min(this.armed.get(ep) || 64, 64);
      const chunk = [];
      let n = 0;
      while (port.queue.length && n < max) {
        const head = port.queue[0];
        const take = Math.min(head.length, max - n);
        chunk.push(head.subarray(0, take));
        n += take;
        if (take === head.length) port.queue.shift();
        else port.queue[0] = head.subarray(take);
      }
      this.armed.delete(ep);
      this.usb.endpointReadDone(ep, new Uint8Array(Buffer.concat(chunk)));
    }
  }
}

// ---------------------------------------------------------------- PTY bridges
const children = [];
const heldSlaves = [];
let quitting = false;

function shutdown(code) {
  quitting = true;
  for (const c of children) {
    try {
      c.kill('SIGTERM');
    } catch {}
  }
  for (const fd of heldSlaves) {
    try {
      fs.closeSync(fd);
    } catch {}
  }
  process.exit(code);
}

async function bridge(host, port, linkPath) {
  const pending = [];
  let sock = null;
  port.sink = (buf) => (sock ? sock.write(buf) : pending.push(buf));
  const server = net.createServer((s) => {
    sock = s;
    s.setNoDelay(true);
    for (const b of pending.splice(0)) s.write(b);
    s.on('data', (d) => host.send(port, d));
    s.on('error', () => {});
  });
  await new Promise((r) => server.listen(0, '127.0.0.1', r));
  try {
    fs.unlinkSync(linkPath);
  } catch {}
  const socat = spawn('socat', [`PTY,link=${linkPath},raw,echo=0`, `TCP:127.0.0.1:${server.address().port}`], {
    stdio: ['ignore', 'ignore', 'inherit'],
  });
  children.push(socat);
  socat.on('error', (e) => {
    log(`cannot run socat (${e.message}); install it (Debian: apt-get install socat)`);
    shutdown(5);
  });
  socat.on('exit', (code) => {
    if (!quitting) {
      log(`socat for ${linkPath} exited (${code})`);
      shutdown(6);
    }
  });
  // Wait for the PTY, then hold its slave open: when the last slave fd closes, the master
  // reads EIO and socat would exit, so a client closing and reopening the port (a gateway
  // reconnecting) would end the emulator.
  for (let i = 0; i < 400 && !fs.existsSync(linkPath); i++) await new Promise((r) => setTimeout(r, 25));
  if (!fs.existsSync(linkPath)) throw new Error(`socat did not create ${linkPath}`);
  heldSlaves.push(fs.openSync(linkPath, fs.constants.O_RDWR | fs.constants.O_NOCTTY | fs.constants.O_NONBLOCK));
}

// ---------------------------------------------------------------- PWM measurement at a pin
function measurePwm(sim, mcu, pin, periods, timeoutNs) {
  return new Promise((resolve) => {
    const gpio = mcu.gpio[pin];
    const rises = [];
    const falls = [];
    const start = sim.clock.nanos;
    let done = false;
    const finish = (result) => {
      if (done) return;
      done = true;
      remove();
      clearInterval(timer);
      resolve(result);
    };
    const remove = gpio.addListener((state) => {
      const t = sim.clock.nanos;
      // GPIOPinState: Low = 0, High = 1 (inputs add 2/3 for pull states).
      const high = state === 1 || state === 3;
      if (high) rises.push(t);
      else if (rises.length) falls.push(t);
      if (rises.length > periods) {
        // Full periods from the first rise: high time of each, divided by its length.
        let high = 0;
        for (let k = 0; k < periods; k++) {
          const fall = falls.find((f) => f > rises[k] && f < rises[k + 1]);
          high += (fall ?? rises[k + 1]) - rises[k];
        }
        const span = rises[periods] - rises[0];
        finish({ duty: high / span, high_ns: high / periods, period_ns: span / periods, periods, level: null });
      }
    });
    const timer = setInterval(() => {
      if (sim.clock.nanos - start > timeoutNs) {
        // No full period: a constant level (0 % or 100 %, or the output stopped).
        const v = gpio.value;
        finish({ duty: v ? 1 : 0, high_ns: null, period_ns: null, periods: 0, level: v ? 1 : 0 });
      }
    }, 5);
  });
}

// ---------------------------------------------------------------- main
async function main() {
  const opts = parseArgs(process.argv.slice(2));
  const sim = new Simulator();
  const mcu = sim.rp2040;
  mcu.logger = new ConsoleLogger(LogLevel.Error);
  if (opts.bootrom) {
    // loadBootrom() resets the chip (and erases flash): before the firmware is loaded.
    const rom = fs.readFileSync(opts.bootrom);
    if (rom.length !== 16384) throw new Error(`${opts.bootrom}: expected a 16 KiB bootrom`);
    mcu.loadBootrom(new Uint32Array(rom.buffer, rom.byteOffset, rom.length / 4));
  } else {
    mcu.reset();
  }
  const bytes = fs.readFileSync(opts.firmware);
  const n = opts.firmware.endsWith('.uf2') ? loadUf2(bytes, mcu.flash) : loadElf(bytes, mcu.flash);
  log(`loaded ${n} bytes from ${opts.firmware}`);

  const host = new UsbHost(mcu);
  host.install();
  const configured = new Promise((r) => (host.onConfigured = r));

  // No bootrom: boot2 at the start of flash, with a valid stack (boot2 pushes LR).
  mcu.core.SP = 0x20042000;
  mcu.core.PC = 0x10000000;
  sim.execute();

  await configured;
  if (host.ports.length < 2) throw new Error(`expected two CDC interfaces, found ${host.ports.length}`);
  await bridge(host, host.ports[0], opts.term);
  await bridge(host, host.ports[1], opts.link);
  const reply = (o) => process.stdout.write(JSON.stringify(o) + '\n');
  reply({ event: 'ready', term: opts.term, link: opts.link, emulated_ms: sim.clock.nanos / 1e6 });

  const rl = readline.createInterface({ input: process.stdin });
  rl.on('close', () => shutdown(0));
  rl.on('line', async (line) => {
    let req;
    try {
      req = JSON.parse(line);
    } catch {
      reply({ ok: false, error: `not JSON: ${line}` });
      return;
    }
    const { id } = req;
    try {
      switch (req.cmd) {
        case 'adc': {
          const ch = req.channel;
          if (!(ch >= 0 && ch <= 4)) throw new Error('channel must be 0-4');
          const code = req.volts !== undefined ? Math.round((req.volts / 3.3) * 4095) : req.value;
          if (!(code >= 0 && code <= 4095)) throw new Error('code must be 0-4095');
          mcu.adc.channelValues[ch] = code;
          reply({ id, ok: true, code, nanos: sim.clock.nanos });
          break;
        }
        case 'pwm': {
          const r = await measurePwm(sim, mcu, req.pin, req.periods ?? 8, (req.timeout_ms ?? 200) * 1e6);
          reply({ id, ok: true, ...r });
          break;
        }
        case 'dtr': {
          const port = host.ports[req.port === 'link' ? 1 : 0];
          await host.setLines(port, req.on !== false);
          reply({ id, ok: true });
          break;
        }
        case 'gpio':
          mcu.gpio[req.pin].setInputValue(!!req.level);
          reply({ id, ok: true });
          break;
        case 'time':
          reply({ id, ok: true, nanos: sim.clock.nanos, cycles: mcu.core.cycles });
          break;
        case 'quit':
          reply({ id, ok: true });
          shutdown(0);
          break;
        default:
          throw new Error(`unknown command ${req.cmd}`);
      }
    } catch (e) {
      reply({ id, ok: false, error: String(e.message || e) });
    }
  });
}

process.on('SIGTERM', () => shutdown(0));
process.on('SIGINT', () => shutdown(0));
main().catch((e) => {
  log(e.stack || String(e));
  shutdown(2);
});
