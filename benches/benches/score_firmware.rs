//! Score firmware figures, measured on the real ELF in the rp2040js emulator (not criterion
//! timings: the emulator's clock is what counts). Prints:
//!
//! * flash and static RAM of the firmware image;
//! * CPU cycles per update of the thesis' Fig. 5.20 PID (playback, derivative, integral, PID
//!   evaluation), f32 and f64, timed by the firmware itself with SysTick (`bench` command);
//!   the thesis' goal is 20 kHz at 133 MHz, i.e. at most 6 650 cycles;
//! * end-to-end latency from an ADC change to the new value arriving as a bus sample through
//!   score-gateway, in emulated time (the harness's clock when the ADC changed, and when the
//!   subscriber had the sample) and in wall time.
//!
//! Needs the firmware ELF (`cargo run -p score-firmware-tools --bin score-fw -- build`) and
//! `npm ci` in score/firmware/emulator.
//! Run: `cargo bench -p conductor-benches --bench score_firmware`.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use conductor_benches::Percentiles;
use conductor_bus::{Bus, Domain, StateSubscriber};
use score_firmware_tools::emulator::Emulator;
use score_firmware_tools::image;
use score_firmware_tools::port::Port;
use score_gateway::{Gateway, Options};

const WAIT: Duration = Duration::from_secs(30);

fn terminal(emu: &mut Emulator) -> Port {
    let mut t = Port::open(&emu.term, WAIT).expect("terminal");
    emu.dtr("term", true).unwrap();
    t.read_until_suffix("$> ", WAIT).unwrap();
    t
}

fn type_line(t: &mut Port, line: &str) -> String {
    t.write_all(format!("{line}\r").as_bytes()).unwrap();
    t.read_until_suffix("$> ", Duration::from_secs(120))
        .unwrap()
}

fn main() {
    let elf = score_firmware_tools::paths::firmware_elf().unwrap_or_else(|e| panic!("{e}"));
    let usage = image::usage(&std::fs::read(&elf).unwrap()).unwrap();
    println!("score_firmware/image: {usage}");

    let mut emu = Emulator::start().unwrap_or_else(|e| panic!("{e}"));
    let mut t = terminal(&mut emu);
    let (ns0, cycles0) = emu.time().unwrap();
    let out = type_line(&mut t, "bench 2000");
    let (ns1, cycles1) = emu.time().unwrap();
    for line in out.lines().filter(|l| l.starts_with("bench")) {
        println!("score_firmware/pid: {}", line.trim());
    }
    println!(
        "score_firmware/pid: cross-check: the emulator executed {} CPU cycles in {:.1} ms of emulated time for the whole command (setup and printing included)",
        cycles1 - cycles0,
        (ns1 - ns0) / 1e6
    );
    println!("score_firmware/pid: goal (thesis): <= 6650 cycles per update (20 kHz at 133 MHz)");

    // End-to-end: ADC sampled at 1 kHz, published by the gateway at 1 kHz.
    type_line(&mut t, "adc 0 1000");
    let domain = Domain::unique("scorebench").unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let gw = {
        let (link, domain, stop) = (emu.link.clone(), domain.clone(), stop.clone());
        std::thread::spawn(move || {
            let bus = Bus::open(&domain, "score-gateway-bench").unwrap();
            let opts = Options {
                port: link,
                ..Options::default()
            };
            Gateway::new(opts, bus, stop).run()
        })
    };
    let bus = Bus::open(&domain, "score-bench-client").unwrap();
    let end = Instant::now() + WAIT;
    let mut sub = loop {
        match StateSubscriber::new(&bus, "score-rp2040/adc0") {
            Ok(s) => break s,
            Err(e) if Instant::now() > end => panic!("gateway did not publish adc0: {e}"),
            Err(_) => std::thread::sleep(Duration::from_millis(50)),
        }
    };
    let mut emu_ms = Vec::new();
    let mut wall_ms = Vec::new();
    for k in 0..40 {
        let v = if k % 2 == 0 { 0.5 } else { 2.5 };
        while sub.receive().unwrap().is_some() {}
        let w0 = Instant::now();
        let (code, t0) = emu.set_adc_volts_timed(0, v).unwrap();
        let want = code as f64 * 3.3 / 4095.0;
        loop {
            if let Some(s) = sub.receive().unwrap() {
                if (s.value - want).abs() < 2e-6 {
                    break;
                }
            } else {
                std::thread::sleep(Duration::from_micros(200));
            }
            assert!(w0.elapsed() < WAIT, "no sample of {want} V");
        }
        let wall = w0.elapsed().as_secs_f64() * 1e3;
        let (t1, _) = emu.time().unwrap();
        emu_ms.push((t1 - t0) / 1e6);
        wall_ms.push(wall);
    }
    stop.store(true, Ordering::Relaxed);
    let _ = gw.join();
    let p = |v: &mut Vec<f64>| {
        let mut ns: Vec<u64> = v.iter().map(|x| (x * 1e6) as u64).collect();
        let s = Percentiles::from_samples(&mut ns).expect("samples");
        format!(
            "{s} min={:.2} ms mean={:.2} ms",
            s.min as f64 / 1e6,
            s.mean / 1e6
        )
    };
    println!(
        "score_firmware/latency: ADC change -> bus sample (1 kHz ADC and publish rate), emulated time: {}",
        p(&mut emu_ms)
    );
    println!(
        "score_firmware/latency: the same in wall time: {}",
        p(&mut wall_ms)
    );
    println!("score_firmware/latency: emulated times are read between the emulator's execution slices (up to ~8 ms of emulated time each), so they bound the latency from above");
}
