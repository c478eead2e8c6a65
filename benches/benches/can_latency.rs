//! Request → reply latency of an MIT motor through the kernel's CAN stack beside the SLCAN
//! adapter over a pseudo-terminal, in one run on one (emulated) machine.
//!
//! The build machines' kernel has no CAN, so this boots Debian's kernel in QEMU
//! (conductor-testkit's `can_vm`, prepared by `cargo xtask setup`) and runs itself inside it:
//!
//! * **SocketCAN**: the project's `SocketCanHardware` on `vcan0`, an MIT motor simulator
//!   (`SocketCanSim`) on the same interface. Request time: just before `write`; reply time: the
//!   kernel's receive timestamp of the reply (SO_TIMESTAMPNS, what the executor stamps samples
//!   with) and the moment the non-blocking read returned it.
//! * **SLCAN over a pty**: the project's `SlcanHardware` on the pty of the SLCAN adapter
//!   simulator (`run_slcan`) with the same motor behind it; reply time: the read that returned it.
//!
//! Both sides poll without sleeping; 2 000 round trips each, one in flight. Under emulation the
//! absolute figures mean little: the ratio between the two paths is the result.
//!
//! `cargo bench -p conductor-benches --bench can_latency`

use std::time::{Duration, Instant};

use conductor_benches::percentiles::Percentiles;
use conductor_bus::monotonic_ns;
use conductor_devices::hw::{
    SerialHardware, SerialOptions, SlcanHardware, SlcanOptions, SocketCanHardware,
};
use conductor_devices::protocol_stage::mit_limits;
use conductor_devices::sim::can_motors::{CanNode, MitMotorSim};
use conductor_devices::sim::runner::{run_slcan, Endpoint, Pty};
use conductor_devices::sim::slcan_adapter::SlcanAdapterSim;
use conductor_devices::sim::socketcan_bus::SocketCanSim;
use conductor_devices::{Hardware, TickCtx};
use conductor_protocols::can::CanFrame;
use conductor_protocols::mit_can;
use conductor_protocols::slcan::Dialect;
use conductor_testkit::can_vm::{CanVm, Unavailable};
use embedded_can::Frame;

const GUEST: &str = "CONDUCTOR_IN_CAN_VM";
const ROUNDS: usize = 2000;

fn main() {
    if std::env::var_os(GUEST).is_some() {
        guest();
        return;
    }
    let vm = match CanVm::find() {
        Ok(vm) => vm,
        Err(Unavailable::NoQemu(why)) => {
            println!("can_latency: SKIPPED, QEMU cannot run here: {why}");
            return;
        }
        Err(Unavailable::NotPrepared(why)) => panic!("can_latency: {why}"),
    };
    let exe = std::env::current_exe().unwrap();
    let out = CanVm::cache_dir().join(format!("bench-{}", std::process::id()));
    let script = format!("export {GUEST}=1\nexec {} --guest\n", exe.display());
    let run = vm
        .run(&script, &out, Duration::from_secs(600))
        .expect("QEMU starts");
    print!("{}", run.stdout);
    eprint!("{}", run.stderr);
    assert_eq!(
        run.status,
        Some(0),
        "the bench failed in the VM: {}",
        out.display()
    );
    let _ = std::fs::remove_dir_all(&out);
}

fn motor() -> Vec<Box<dyn CanNode>> {
    vec![Box::new(MitMotorSim::new(
        1,
        mit_limits("ak80-9").unwrap(),
        0,
        false,
    ))]
}

fn command() -> CanFrame {
    let l = mit_limits("ak80-9").unwrap();
    let cmd = mit_can::Command {
        p: 0.1,
        v: 0.0,
        kp: 20.0,
        kd: 1.0,
        t: 0.0,
    };
    mit_can::command(1, &cmd, &l).unwrap()
}

fn ctx() -> TickCtx {
    TickCtx {
        tick: 0,
        now_ns: monotonic_ns(),
    }
}

/// One round trip on `hw`: (request → read returned it, request → kernel timestamp if any).
fn round_trip<H: Hardware<Word = CanFrame>>(hw: &mut H, frame: CanFrame) -> (u64, Option<u64>) {
    let mut buf = [frame; 16];
    let t0 = monotonic_ns();
    let mut sent = 0;
    while sent == 0 {
        sent = hw.transmit(&[frame], ctx()).expect("transmit");
    }
    let end = Instant::now() + Duration::from_secs(2);
    loop {
        let n = hw.receive(&mut buf, ctx()).expect("receive");
        let t = monotonic_ns();
        let times = hw.rx_times();
        for (i, f) in buf[..n].iter().enumerate() {
            if f.id() == embedded_can::Id::Standard(embedded_can::StandardId::ZERO) {
                let kernel = times.get(i).copied().filter(|&k| k != 0);
                return (t - t0, kernel.map(|k| k.saturating_sub(t0)));
            }
        }
        assert!(Instant::now() < end, "no reply");
        std::hint::spin_loop();
    }
}

fn measure<H: Hardware<Word = CanFrame>>(hw: &mut H) -> (Vec<u64>, Vec<u64>) {
    // Into motor mode, then warm up.
    let enter: CanFrame = mit_can::enter_frame(1).unwrap();
    round_trip(hw, enter);
    for _ in 0..100 {
        round_trip(hw, command());
    }
    let (mut user, mut kernel) = (Vec::new(), Vec::new());
    for _ in 0..ROUNDS {
        let (u, k) = round_trip(hw, command());
        user.push(u);
        if let Some(k) = k {
            kernel.push(k);
        }
    }
    (user, kernel)
}

fn us(p: &Percentiles) -> String {
    format!(
        "p50 {:7.1} µs  p99 {:7.1} µs  max {:8.1} µs",
        p.p50 as f64 / 1e3,
        p.p99 as f64 / 1e3,
        p.max as f64 / 1e3
    )
}

fn guest() {
    let status = std::process::Command::new("sh")
        .args(["-c", "ip link add vcan0 type vcan && ip link set vcan0 up"])
        .status()
        .unwrap();
    assert!(status.success());
    let sim = SocketCanSim::start("vcan0", motor()).unwrap();
    let mut can = SocketCanHardware::open("vcan0").unwrap();
    assert!(can.timestamps(), "the kernel stamps received frames");
    let (can_user, can_kernel) = measure(&mut can);
    drop(can);
    drop(sim);

    let adapter = run_slcan(
        Endpoint::Pty(Pty::open(None).unwrap()),
        SlcanAdapterSim::new(Dialect::CANABLE, motor()),
    );
    let serial = SerialHardware::open(
        adapter.endpoint(),
        &SerialOptions {
            baud: 1_000_000,
            low_latency: true,
            exclusive: true,
        },
    )
    .unwrap();
    let mut slcan = SlcanHardware::open(serial, SlcanOptions::default()).unwrap();
    let (pty_user, _) = measure(&mut slcan);

    let pct = |mut v: Vec<u64>| Percentiles::from_samples(&mut v).expect("samples");
    let cu = pct(can_user);
    let ck = pct(can_kernel);
    let pu = pct(pty_user);
    println!("MIT request → reply, {ROUNDS} round trips each (QEMU, emulated: compare the ratio)");
    println!("  SocketCAN vcan0, reply read by user space  {}", us(&cu));
    println!("  SocketCAN vcan0, reply's kernel timestamp  {}", us(&ck));
    println!("  SLCAN adapter over a pty, reply read       {}", us(&pu));
    println!(
        "  ratio SLCAN-pty / SocketCAN (p50, read by user space): {:.2}",
        pu.p50 as f64 / cu.p50 as f64
    );
    println!(
        "  kernel timestamp before the read: {:.1} µs earlier at p50",
        (cu.p50 as f64 - ck.p50 as f64) / 1e3
    );
}
