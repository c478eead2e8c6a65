//! Encode and scan throughput of the actuator-bus codecs, in wire bytes per second.
//!
//! Each benchmark processes one bus cycle of the 41-joint Hubo case (41 devices), so the
//! figures also say how much CPU a cycle's codec work costs. Scanners are fed in 64-byte chunks,
//! the size a non-blocking serial read typically returns. After criterion's report a one-line
//! summary per codec gives the mean MB/s over all of criterion's timed iterations.

use conductor_protocols::can::CanFrame;
use conductor_protocols::dynamixel1 as d1;
use conductor_protocols::dynamixel2 as d2;
use conductor_protocols::mit_can::{self, Command, Model, Reply};
use conductor_protocols::odrive_can::{self, Message};
use conductor_protocols::slcan::{self, Dialect, HostScanner, Response};
use criterion::{black_box, BenchmarkGroup, Criterion, Throughput};
use embedded_can::Frame;
use std::cell::RefCell;
use std::time::{Duration, Instant};

const JOINTS: usize = 41;
const CHUNK: usize = 64;

thread_local! {
    /// (codec, bytes processed, time spent) over every timed iteration.
    static TOTALS: RefCell<Vec<(String, u64, Duration)>> = const { RefCell::new(Vec::new()) };
}

/// Registers a benchmark that processes `bytes` wire bytes per call of `f`, and records the
/// totals for the summary line.
fn bench<M: criterion::measurement::Measurement<Value = Duration>>(
    (g, codec): (&mut BenchmarkGroup<'_, M>, &str),
    name: &str,
    bytes: usize,
    mut f: impl FnMut() -> u64,
) {
    let label = format!("{codec}/{name}");
    g.throughput(Throughput::Bytes(bytes as u64));
    g.bench_function(name, |b| {
        b.iter_custom(|iters| {
            let start = Instant::now();
            for _ in 0..iters {
                black_box(f());
            }
            let dt = start.elapsed();
            TOTALS.with(|t| {
                let mut t = t.borrow_mut();
                match t.iter_mut().find(|e| e.0 == label) {
                    Some(e) => {
                        e.1 += iters * bytes as u64;
                        e.2 += dt;
                    }
                    None => t.push((label.clone(), iters * bytes as u64, dt)),
                }
            });
            dt
        })
    });
}

fn group<'a>(
    c: &'a mut Criterion,
    name: &str,
) -> BenchmarkGroup<'a, criterion::measurement::WallTime> {
    let mut g = c.benchmark_group(name);
    g.warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2));
    g
}

fn dynamixel2(c: &mut Criterion) {
    let goals: Vec<[u8; 4]> = (0..JOINTS as u32)
        .map(|i| (2048 + 10 * i).to_le_bytes())
        .collect();
    let mut out = [0u8; 1024];
    let tx_len = d2::sync_write(
        &mut out,
        116,
        4,
        goals.iter().enumerate().map(|(i, g)| (i as u8 + 1, &g[..])),
    )
    .unwrap();
    let mut stream = Vec::new();
    for i in 0..JOINTS {
        let mut buf = [0u8; 64];
        let n = d2::status(
            &mut buf,
            i as u8 + 1,
            0,
            &(1000 + i as u32 * 7).to_le_bytes(),
        )
        .unwrap();
        stream.extend_from_slice(&buf[..n]);
    }
    let slices: Vec<[u8; 4]> = (0..JOINTS as u32)
        .map(|i| (1000 + i).to_le_bytes())
        .collect();
    let fast: Vec<_> = slices
        .iter()
        .enumerate()
        .map(|(i, d)| d2::FastStatusSlice {
            error: 0,
            id: i as u8 + 1,
            data: d,
        })
        .collect();
    let mut fast_wire = [0u8; 1024];
    let fast_len = d2::fast_status(&mut fast_wire, &fast).unwrap();

    let mut g = group(c, "dynamixel2");
    bench((&mut g, "dynamixel2"), "encode_sync_write", tx_len, || {
        d2::sync_write(
            &mut out,
            116,
            4,
            goals.iter().enumerate().map(|(i, g)| (i as u8 + 1, &g[..])),
        )
        .unwrap() as u64
    });
    let mut s = d2::Scanner::<512>::new();
    bench((&mut g, "dynamixel2"), "scan_status", stream.len(), || {
        let mut sum = 0u64;
        for chunk in stream.chunks(CHUNK) {
            s.feed(chunk, |p| {
                sum += d2::Status::from_packet(&p).unwrap().data_u32().unwrap() as u64
            });
        }
        sum
    });
    let mut s = d2::Scanner::<512>::new();
    let fast_bytes = &fast_wire[..fast_len];
    bench((&mut g, "dynamixel2"), "scan_fast_reply", fast_len, || {
        let mut sum = 0u64;
        for chunk in fast_bytes.chunks(CHUNK) {
            s.feed(chunk, |p| {
                for sl in d2::FastReply::from_packet(&p)
                    .unwrap()
                    .slices(std::iter::repeat(4))
                {
                    sum += sl.unwrap().data[0] as u64;
                }
            });
        }
        sum
    });
    g.finish();
}

fn dynamixel1(c: &mut Criterion) {
    let goals: Vec<[u8; 2]> = (0..JOINTS as u16)
        .map(|i| (512 + i).to_le_bytes())
        .collect();
    let mut out = [0u8; 512];
    let tx_len = d1::sync_write(
        &mut out,
        30,
        2,
        goals.iter().enumerate().map(|(i, g)| (i as u8 + 1, &g[..])),
    )
    .unwrap();
    let mut stream = Vec::new();
    for i in 0..JOINTS {
        let mut buf = [0u8; 16];
        let n = d1::status(
            &mut buf,
            i as u8 + 1,
            d1::ErrorBits(0),
            &(500 + i as u16).to_le_bytes(),
        )
        .unwrap();
        stream.extend_from_slice(&buf[..n]);
    }
    let mut g = group(c, "dynamixel1");
    bench((&mut g, "dynamixel1"), "encode_sync_write", tx_len, || {
        d1::sync_write(
            &mut out,
            30,
            2,
            goals.iter().enumerate().map(|(i, g)| (i as u8 + 1, &g[..])),
        )
        .unwrap() as u64
    });
    let mut s = d1::Scanner::<512>::new();
    bench((&mut g, "dynamixel1"), "scan_status", stream.len(), || {
        let mut sum = 0u64;
        for chunk in stream.chunks(CHUNK) {
            s.feed(chunk, |p| {
                sum += d1::Status::from_packet(&p).data_u16().unwrap() as u64
            });
        }
        sum
    });
    g.finish();
}

fn mit(c: &mut Criterion) {
    let l = Model::Ak80_9.limits();
    let cmds: Vec<Command> = (0..JOINTS)
        .map(|i| Command {
            p: i as f32 * 0.1 - 2.0,
            v: 0.5,
            kp: 20.0,
            kd: 0.5,
            t: 0.1,
        })
        .collect();
    let replies: Vec<[u8; 6]> = (0..JOINTS as u16)
        .map(|i| {
            mit_can::ReplyInts {
                motor_id: i as u8 + 1,
                p: 30000 + i,
                v: 2047,
                t: 2047,
            }
            .pack()
        })
        .collect();
    let mut g = group(c, "mit_can");
    bench((&mut g, "mit_can"), "encode_command", JOINTS * 8, || {
        cmds.iter().map(|c| c.encode(&l).unwrap()[1] as u64).sum()
    });
    bench((&mut g, "mit_can"), "decode_reply", JOINTS * 6, || {
        replies
            .iter()
            .map(|r| Reply::decode(r, &l).unwrap().p.to_bits() as u64)
            .sum()
    });
    g.finish();
}

fn odrive(c: &mut Criterion) {
    let msgs: Vec<Message> = (0..JOINTS)
        .map(|i| Message::SetInputPos {
            pos: i as f32,
            vel_ff: 0.5,
            torque_ff: -0.25,
        })
        .collect();
    let est: Vec<CanFrame> = (0..JOINTS as u8)
        .map(|i| {
            odrive_can::frame(
                i % 64,
                &Message::GetEncoderEstimates {
                    pos: i as f32,
                    vel: 0.0,
                },
            )
            .unwrap()
        })
        .collect();
    let mut g = group(c, "odrive_can");
    bench(
        (&mut g, "odrive_can"),
        "encode_set_input_pos",
        JOINTS * 8,
        || {
            msgs.iter()
                .enumerate()
                .map(|(i, m)| odrive_can::to_can_frame(i as u8 % 64, m).unwrap().data()[0] as u64)
                .sum()
        },
    );
    bench(
        (&mut g, "odrive_can"),
        "decode_encoder_estimates",
        JOINTS * 8,
        || {
            est.iter()
                .map(|f| match odrive_can::decode_frame(f).unwrap().1 {
                    Message::GetEncoderEstimates { pos, .. } => pos as u64,
                    _ => 0,
                })
                .sum()
        },
    );
    g.finish();
}

fn slcan_codec(c: &mut Criterion) {
    let l = Model::Ak80_9.limits();
    let frames: Vec<CanFrame> = (0..JOINTS as u16)
        .map(|i| {
            mit_can::command_frame(
                i + 1,
                &Command {
                    p: 1.0,
                    v: 0.0,
                    kp: 20.0,
                    kd: 0.5,
                    t: 0.0,
                },
                &l,
            )
            .unwrap()
        })
        .collect();
    let d = Dialect::CANABLE;
    let mut out = [0u8; 32];
    let tx_bytes: usize = frames
        .iter()
        .map(|f| slcan::Command::Transmit(*f).encode(&d, &mut out).unwrap())
        .sum();
    // What an adapter sends back in a cycle: an ack per transmitted frame and a reply frame.
    let mut rx = Vec::new();
    for f in &frames {
        rx.push(slcan::CR);
        let reply =
            CanFrame::standard(0, &[f.raw_id() as u8, 0x8A, 0x3C, 0x7A, 0xD8, 0x38]).unwrap();
        let n = Response::Frame {
            frame: reply,
            timestamp: None,
        }
        .encode(&mut out)
        .unwrap();
        rx.extend_from_slice(&out[..n]);
    }
    let mut g = group(c, "slcan");
    bench((&mut g, "slcan"), "encode_transmit", tx_bytes, || {
        frames
            .iter()
            .map(|f| slcan::Command::Transmit(*f).encode(&d, &mut out).unwrap() as u64)
            .sum()
    });
    let mut s = HostScanner::<64>::new();
    bench((&mut g, "slcan"), "scan_responses", rx.len(), || {
        let mut n = 0u64;
        for chunk in rx.chunks(CHUNK) {
            s.feed(chunk, |r| {
                if let Response::Frame { frame, .. } = r {
                    n += frame.data()[0] as u64;
                }
            });
        }
        n
    });
    g.finish();
}

fn main() {
    let mut c = Criterion::default().configure_from_args();
    dynamixel2(&mut c);
    dynamixel1(&mut c);
    mit(&mut c);
    odrive(&mut c);
    slcan_codec(&mut c);
    c.final_summary();
    println!(
        "\ncodec throughput summary (mean over all timed iterations, {JOINTS} devices per cycle):"
    );
    TOTALS.with(|t| {
        for (name, bytes, dt) in t.borrow().iter() {
            if dt.is_zero() {
                continue;
            }
            let mbps = *bytes as f64 / dt.as_secs_f64() / 1e6;
            println!("  {name:<40} {mbps:>9.1} MB/s");
        }
    });
}
