//! The firmware's logic on the host: the RP2040 HAL over in-memory registers, the link server
//! answering real frames, the sampler's timestamps, the terminal's echo and prompt.

use conductor_protocols::score_link::*;
use score_board::hal::{BoardHal, MemIo, PinFunction};
use score_board::link::LinkServer;
use score_board::out::{FrameOut, TextOut};
use score_board::terminal::Terminal;
use score_board::{Board, BoardInfo};

type TestBoard = Board<f64, BoardHal<MemIo>>;

const INFO: BoardInfo = BoardInfo {
    firmware: "score-firmware test",
    board: "bench",
};

fn board() -> Box<TestBoard> {
    Box::new(Board::new(BoardHal::new(MemIo::default()), INFO))
}

fn no_extra(_: &str, _: &mut dyn core::fmt::Write) -> Option<bool> {
    None
}

fn run(b: &mut TestBoard, line: &str) -> String {
    let mut out = TextOut::<4096>::new(false);
    let ok = b.run_line(line, b.engine.now_us(), &mut out, &mut no_extra);
    assert!(ok, "{line}: {}", out.as_str());
    out.as_str().to_string()
}

struct Host {
    server: LinkServer,
    seq: u16,
}

impl Host {
    fn new() -> Self {
        Self {
            server: LinkServer::new(),
            seq: 0,
        }
    }

    /// Sends one request through real framing and returns the decoded replies (owned copies).
    fn ask(&mut self, b: &mut TestBoard, now: u64, req: Request<'_>) -> Vec<(u16, String)> {
        self.seq += 1;
        let mut f = [0u8; MAX_FRAME];
        let n = encode_request(self.seq, &req, &mut f).unwrap();
        let mut out = FrameOut::<8192>::new();
        self.server.feed(&f[..n], b, now, &mut out, &mut no_extra);
        assert_eq!(out.dropped(), 0);
        let mut replies = Vec::new();
        let mut sc = FrameScanner::<MAX_FRAME>::new();
        sc.feed(out.as_bytes(), |m| {
            let (seq, r) = decode_reply(m).unwrap();
            replies.push((seq, format!("{r:?}")));
        });
        for (seq, _) in &replies {
            assert_eq!(*seq, self.seq);
        }
        replies
    }
}

fn samples(b: &mut TestBoard, now: u64) -> Vec<(u64, Vec<(u8, f64)>)> {
    let mut got = Vec::new();
    b.collect_samples(now, |t, s| got.push((t, s.to_vec())));
    got
}

#[test]
fn adc_reads_12_bit_codes_and_software_pairs() {
    let mut b = board();
    b.hal.io.adc = [1241, 1000, 4000, 100, 876];
    run(&mut b, "adc 0 100");
    run(&mut b, "adc A 100");
    run(&mut b, "adc T 10");
    b.tick(0);
    assert_eq!(b.engine.value_of("ADC0"), Some(1241.0));
    // 1241 * 3.3 / 4095 = 1.000073 V (the HAL's reference is the f32 3.3; one f64 product
    // and one quotient: 2 roundings of 1.1e-16 relative).
    let v = b.engine.value_of("adc0").unwrap();
    assert!((v - 1241.0 * (3.3f32 as f64) / 4095.0).abs() < 1e-15);
    // Pair A: 2048 + 1000 - 1000... here 2048 + 1241 - 1000 = 2289.
    assert_eq!(b.engine.value_of("ADCA"), Some(2289.0));
    assert_eq!(b.engine.value_of("ADCT"), Some(876.0));
    let mut out = TextOut::<256>::new(false);
    assert!(!b.run_line("adc 4 100", 0, &mut out, &mut no_extra));
    assert!(out.as_str().contains("error: adc: '4'"), "{}", out.as_str());
}

#[test]
fn pwm_outputs_program_slices_pins_and_refuse_conflicts() {
    let mut b = board();
    run(&mut b, "pwm 5 1000 25");
    let s = b.hal.io.slices[2];
    assert_eq!(
        (s.div_int, s.div_frac, s.top, s.cc_b, s.enable),
        (2, 0, 62_499, 15_625, true)
    );
    assert_eq!(b.hal.io.function[5], Some(PinFunction::Pwm));
    assert_eq!(b.engine.value_of("PWM5"), Some(25.0));
    // GPIO 5 belongs to the PWM output now.
    let mut out = TextOut::<256>::new(false);
    assert!(!b.run_line("gpio 5 10", 0, &mut out, &mut no_extra));
    assert!(
        out.as_str().contains("no free hardware resource"),
        "{}",
        out.as_str()
    );
    // An inexact frequency is reported by the engine: 7 MHz is 6.993 MHz here.
    let text = run(&mut b, "pwm B 7000000 50");
    assert!(text.contains("note: PWMB runs at"), "{text}");
    let s = b.hal.io.slices[1];
    assert!(s.b_inv && !s.a_inv && s.cc_a == s.cc_b);
    run(&mut b, "del PWM5");
    assert_eq!(b.hal.io.function[5], Some(PinFunction::Off));
    assert!(!b.hal.io.slices[2].enable);
    run(&mut b, "gpio 5 10");
    assert_eq!(b.hal.io.function[5], Some(PinFunction::Input));
}

#[test]
fn defscale_defpwm_chain_sets_the_compare_of_the_scaled_adc() {
    let mut b = board();
    // 2048 counts = 1.650403 V; scaled from [0, 3.3] to [0, 100] % = 50.0122 %.
    b.hal.io.adc[0] = 2048;
    run(&mut b, "adc 0 1000");
    run(&mut b, "defscale P adc0 0 3.3 0 100");
    run(&mut b, "defpwm pw P 1000 2 20000");
    b.tick(0);
    let s = b.hal.io.slices[1];
    // 6250 counts at 20 kHz; duty 2048/4095 -> 3125.76 -> 3126.
    assert_eq!((s.top, s.cc_a), (6249, 3126));
}

#[test]
fn link_lists_subscribes_sets_and_runs_lines() {
    let mut b = board();
    let mut h = Host::new();
    let hello = h.ask(&mut b, 5, Request::Hello);
    assert_eq!(hello.len(), 1);
    assert!(hello[0].1.contains("board: \"bench\"") && hello[0].1.contains("number_type: \"f64\""));
    let done = h.ask(&mut b, 10, Request::Exec { line: "adc 0 100" });
    assert!(done.last().unwrap().1.starts_with("ExecDone { ok: true"));
    let done = h.ask(
        &mut b,
        10,
        Request::Exec {
            line: "pwm 3 1000 10",
        },
    );
    assert!(done.last().unwrap().1.starts_with("ExecDone { ok: true"));
    let g = b.engine.generation();
    let list = h.ask(&mut b, 20, Request::ListVars);
    assert_eq!(list.len(), 4, "{list:?}");
    assert!(list[3].1.starts_with("ListEnd"));
    let adc0 = b.engine.lookup("adc0").unwrap().0;
    let pwm3 = b.engine.lookup("PWM3").unwrap().0;
    assert!(list.iter().any(|(_, r)| r.contains("name: \"adc0\"")
        && r.contains("unit: \"V\"")
        && r.contains("rate_hz: Some(100.0)")
        && r.contains("writable: false")));
    // Subscribe adc0 at 50 Hz: every second 100 Hz update, stamped with the update's instant.
    let ack = h.ask(
        &mut b,
        20,
        Request::Subscribe {
            id: adc0,
            period_us: 20_000,
            generation: g,
        },
    );
    assert_eq!(ack[0].1, "Ack");
    b.hal.io.adc[0] = 4095;
    let mut sent = Vec::new();
    // The first tick anchors the 100 Hz schedule at 1000 us; later ticks come a little late
    // (as a busy firmware's would): the stamps stay on the schedule.
    for (k, late) in [0u64, 37, 5, 120, 0, 999, 3, 64, 1, 0]
        .into_iter()
        .enumerate()
    {
        let t = 1_000 + k as u64 * 10_000 + late;
        b.tick(t);
        sent.extend(samples(&mut b, t));
    }
    let times: Vec<u64> = sent.iter().map(|(t, _)| *t).collect();
    assert_eq!(times, [1_000, 21_000, 41_000, 61_000, 81_000]);
    assert_eq!(sent[0].1, [(adc0, 3.3f32 as f64)]);
    // Set a PWM duty: the slice's compare follows.
    let r = h.ask(
        &mut b,
        30,
        Request::Set {
            id: pwm3,
            value: 75.0,
            generation: g,
        },
    );
    assert_eq!(r[0].1, "SetDone { value: 75.0 }");
    assert_eq!(b.hal.io.slices[1].cc_b, 46_875);
    // Read-only, stale generation, unknown slot.
    let r = h.ask(
        &mut b,
        30,
        Request::Set {
            id: adc0,
            value: 1.0,
            generation: g,
        },
    );
    assert!(r[0].1.contains("NotWritable"));
    let r = h.ask(
        &mut b,
        30,
        Request::Set {
            id: pwm3,
            value: 1.0,
            generation: g + 1,
        },
    );
    assert!(r[0].1.contains("Stale"));
    let r = h.ask(
        &mut b,
        30,
        Request::Subscribe {
            id: 60,
            period_us: 1,
            generation: g,
        },
    );
    assert!(r[0].1.contains("UnknownVariable"));
    // A refused line: its error text, then ok = false.
    let r = h.ask(&mut b, 30, Request::Exec { line: "adc 9 100" });
    assert!(r[0].1.contains("error: adc: '9'"), "{r:?}");
    assert!(r.last().unwrap().1.starts_with("ExecDone { ok: false"));
    // A table change lapses the subscriptions and is announced once.
    assert!(b.take_table_change().is_some());
    assert_eq!(b.take_table_change(), None);
    h.ask(&mut b, 40, Request::Exec { line: "defexp k 2" });
    assert_eq!(b.take_table_change(), Some(b.engine.generation()));
    b.tick(200_000);
    assert!(samples(&mut b, 200_000).is_empty());
    assert!(b.sampler.is_empty());
}

#[test]
fn bare_expressions_are_sampled_on_their_own_period() {
    let mut b = board();
    run(&mut b, "defexp k 2");
    let mut h = Host::new();
    let g = b.engine.generation();
    let k = b.engine.lookup("k").unwrap().0;
    h.ask(
        &mut b,
        1_000,
        Request::Subscribe {
            id: k,
            period_us: 10_000,
            generation: g,
        },
    );
    assert_eq!(b.next_wake(), Some(1_000));
    let mut times = Vec::new();
    for t in [1_000u64, 5_000, 11_000, 35_000, 40_000] {
        for (ts, s) in samples(&mut b, t) {
            assert_eq!(s, [(k, 2.0)]);
            times.push(ts);
        }
    }
    // Due at 1000, 11000, 21000 (sampled late at 35000, then re-anchored to 45000).
    assert_eq!(times, [1_000, 11_000, 35_000]);
    assert_eq!(b.next_wake(), Some(45_000));
}

#[test]
fn garbage_on_the_link_is_answered_with_bad_request_or_ignored() {
    let mut b = board();
    let mut server = LinkServer::new();
    let mut out = FrameOut::<1024>::new();
    // A well-framed message of another version: answered as a bad request with its seq.
    let mut f = [0u8; MAX_FRAME];
    let n = encode_frame(&[9, 1, 7, 0], &mut f).unwrap();
    server.feed(&f[..n], &mut b, 0, &mut out, &mut no_extra);
    let mut got = Vec::new();
    FrameScanner::<MAX_FRAME>::new().feed(out.as_bytes(), |m| {
        got.push(format!("{:?}", decode_reply(m).unwrap()))
    });
    assert_eq!(got.len(), 1);
    assert!(
        got[0].starts_with("(7, Error { code: BadRequest"),
        "{got:?}"
    );
    // Bytes that never form a frame: nothing.
    out.clear();
    server.feed(b"\x05abc\x00\x00", &mut b, 0, &mut out, &mut no_extra);
    assert!(out.as_bytes().is_empty());
    assert_eq!(server.stats().frames, 1);
}

#[test]
fn terminal_echoes_prompts_and_reports_errors() {
    let mut b = board();
    let mut t = Terminal::new();
    let mut out = TextOut::<4096>::new(true);
    t.banner(&b, &mut out);
    assert!(out
        .as_str()
        .contains("Type 'help' for a command listing\r\n"));
    assert!(out.as_str().ends_with("$> "));
    out.clear();
    t.feed(b"adx\x08c 0 100\r", &mut b, 0, &mut out, &mut no_extra);
    assert_eq!(out.as_str(), "adx\x08 \x08c 0 100\r\n$> ");
    out.clear();
    t.feed(b"printvars\r\nbogus\n", &mut b, 0, &mut out, &mut no_extra);
    let s = out.as_str();
    assert!(s.contains("ADC0 - 0.000000\r\nadc0 - 0.000000\r\n"), "{s}");
    assert!(s.contains("bogus\r\nerror: "), "{s}");
    assert!(s.ends_with("$> "));
    // File commands have nothing to act on.
    out.clear();
    t.feed(b"save f.txt\r", &mut b, 0, &mut out, &mut no_extra);
    assert!(out
        .as_str()
        .contains("error: save: not available on the board"));
}
