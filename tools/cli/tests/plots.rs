//! Plots people look at (issue 15, part D): `conductor plot --flags` draws several states and,
//! below them, when their flags were set, into a PNG this test opens and inspects;
//! `conductor echo --plot` draws a live braille chart with each state's value and flags.

mod support;

use std::collections::BTreeMap;
use std::path::Path;

use conductor_bus::{status, Domain};
use support::*;

/// A recording in the documented layout: three states of `leg` at 100 Hz for 10 s, with
/// `knee` clamped from 2 s to 4 s, `hip` rejected and tripped from 6 s to 8 s and `current`
/// stale from 5 s to 5.5 s; every sample simulated.
fn recording(path: &Path) {
    use conductor_cli::recording as r;
    let f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = mcap::Writer::new(f).unwrap();
    let schema = w
        .add_schema(r::SCHEMA_NAME, r::SCHEMA_ENCODING, r::SCHEMA.as_bytes())
        .unwrap();
    let mut channels = Vec::new();
    for (i, (name, units)) in [("knee", "rad"), ("hip", "rad"), ("current", "A")]
        .into_iter()
        .enumerate()
    {
        let md: BTreeMap<String, String> = [
            ("subsystem", "leg"),
            ("state", name),
            ("index", &i.to_string()),
            ("units", units),
            ("writable", "true"),
            ("rate_hz", "100"),
            ("min", "-3"),
            ("max", "3"),
            ("device", ""),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
        channels.push(
            w.add_channel(schema, &format!("/leg/{name}"), r::MESSAGE_ENCODING, &md)
                .unwrap(),
        );
    }
    for k in 0..1000u64 {
        let t_s = k as f64 / 100.0;
        let t = 1_000_000_000 + k * 10_000_000;
        let samples = [
            (
                (t_s * 2.0).sin(),
                if (2.0..4.0).contains(&t_s) {
                    status::CLAMPED
                } else {
                    0
                },
            ),
            (
                (t_s * 1.3).cos() * 0.8,
                if (6.0..8.0).contains(&t_s) {
                    status::REJECTED | status::TRIPPED
                } else {
                    0
                },
            ),
            (
                0.2 * t_s - 1.0,
                if (5.0..5.5).contains(&t_s) {
                    status::STALE
                } else {
                    0
                },
            ),
        ];
        for (ch, (v, flags)) in channels.iter().zip(samples) {
            let mut body = Vec::new();
            let s = conductor_bus::StateSample {
                seq: k,
                tick: k,
                t_sample_ns: t,
                t_publish_ns: t,
                value: v,
                status: flags | status::SIMULATED,
                reserved: 0,
            };
            r::write_message(&mut body, &r::message_of(&s));
            w.write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id: *ch,
                    sequence: k as u32,
                    log_time: t,
                    publish_time: t,
                },
                &body,
            )
            .unwrap();
        }
    }
    w.finish().unwrap();
}

/// The image as (width, height, RGB pixels).
fn open_png(path: &Path) -> (u32, u32, Vec<[u8; 3]>) {
    let decoder = png::Decoder::new(std::fs::File::open(path).unwrap());
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.bit_depth, png::BitDepth::Eight);
    let channels = match info.color_type {
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        c => panic!("colour type {c:?}"),
    };
    let px = buf[..info.buffer_size()]
        .chunks(channels)
        .map(|p| [p[0], p[1], p[2]])
        .collect();
    (info.width, info.height, px)
}

#[test]
fn plot_flags_draws_states_and_their_flags_into_a_png() {
    let dir = tempdir("plotflags");
    let file = dir.join("leg.mcap");
    recording(&file);
    let png_path = dir.join("leg.png");
    let d = Domain::unique("plotflags").unwrap();
    let out = conductor(&d)
        .arg("plot")
        .arg(&file)
        .args([
            "leg/*", "--flags", "--width", "1000", "--height", "700", "-o",
        ])
        .arg(&png_path)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    // knee: clamped; hip: rejected, tripped; current: stale (simulated is provenance).
    assert!(
        stderr.contains("plotted 3 state(s) and 4 flag row(s)"),
        "{stderr}"
    );

    let (w, h, px) = open_png(&png_path);
    assert_eq!((w, h), (1000, 700));
    assert_eq!(px.len(), 1000 * 700);
    // Not blank: a good share of the pixels is drawn, in many colours.
    let white = px.iter().filter(|p| **p == [255, 255, 255]).count();
    assert!(white < px.len() * 97 / 100, "{white} of {} white", px.len());
    let distinct: std::collections::BTreeSet<[u8; 3]> = px.iter().copied().collect();
    assert!(distinct.len() > 20, "{} colours", distinct.len());
    // The flags panel: each state's bars are solid in its line colour (the lines are 2 px
    // wide, so only bars hold 4x4 blocks of one colour). knee's clamped span is 2 s of 10, hip's
    // two rows 2 s each, current's stale 0.5 s.
    let tab10 = [[31, 119, 180], [255, 127, 14], [44, 160, 44]];
    let at = |x: usize, y: usize| px[y * w as usize + x];
    let solid = |c: [u8; 3]| {
        let mut n = 0;
        for y in 0..h as usize - 4 {
            for x in 0..w as usize - 4 {
                n += usize::from((0..4).all(|dy| (0..4).all(|dx| at(x + dx, y + dy) == c)));
            }
        }
        n
    };
    let (knee, hip, current) = (solid(tab10[0]), solid(tab10[1]), solid(tab10[2]));
    assert!(knee > 1000, "knee's bar: {knee} px");
    assert!(hip > 2000, "hip's two bars: {hip} px");
    assert!(current > 200, "current's bar: {current} px");
    // Two rows of 2 s against one of 2 s, one of 0.5 s: the areas say so (bars share a height).
    let ratio = hip as f64 / knee as f64;
    assert!((1.8..2.2).contains(&ratio), "hip/knee {ratio}");
    let ratio = knee as f64 / current as f64;
    // (4 for the spans; a little more, as a 4x4 block fits 3 fewer times across each bar)
    assert!((3.5..5.2).contains(&ratio), "knee/current {ratio}");
    let upper = &px[..(h as usize / 2) * w as usize];
    let count = |area: &[[u8; 3]], c: [u8; 3]| area.iter().filter(|p| **p == c).count();
    // And the lines are in the upper panel.
    for c in tab10 {
        assert!(count(upper, c) > 300, "{c:?}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn echo_plot_draws_a_live_chart_with_values_and_flags() {
    let (d, _leg) = domain_with_leg("echoplot", 200.0, leg);
    // One frame beyond knee's limit (2): the simulator clamps it and flags knee CLAMPED until
    // the next frame (`conductor set` would refuse it, or clamp it itself with --clamp).
    let bus = conductor_bus::Bus::open(&d, "test-controller").unwrap();
    let mut ctl = conductor_bus::Controller::new(&bus);
    ctl.add_ctrl("leg/hip", 0.5).unwrap();
    ctl.add_ctrl("leg/knee", 3.0).unwrap();
    ctl.send_ctrl_checked().unwrap();
    let out = ok(conductor(&d).args([
        "echo",
        "leg/*",
        "--plot",
        "--window",
        "2",
        "--duration",
        "2.5",
    ]));
    // Piped: a frame a second and one at the end.
    let frames: Vec<&str> = out.split("3 state(s), last 2 s").skip(1).collect();
    assert!((2..=4).contains(&frames.len()), "{out}");
    let last = frames.last().unwrap();
    // The chart: braille cells with dots in them (U+2801..U+28FF), no colour escapes.
    let dots = last
        .chars()
        .filter(|c| ('\u{2801}'..='\u{28ff}').contains(c))
        .count();
    assert!(dots > 50, "{last}");
    assert!(!last.contains('\x1b'), "{last}");
    // The legend: newest value, flags now, and flag counts over the window.
    assert!(
        last.contains("[1] leg/knee  2 rad  flags: clamped,simulated  (in window: clamped "),
        "{last}"
    );
    assert!(
        last.contains("[2] leg/hip  0.5 rad  flags: simulated"),
        "{last}"
    );
    assert!(
        last.contains("[3] leg/current  0 A  flags: simulated"),
        "{last}"
    );
    // The y range covers both joints (0 to 2, padded): the labels say so.
    assert!(
        last.contains(" 2.100") && last.contains(" -0.100"),
        "{last}"
    );
}
