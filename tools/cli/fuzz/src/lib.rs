//! The checks behind each fuzz target of `conductor-cli`'s readers of outside input (in
//! `conductor-cli-formats`, which the CLI re-exports), one function per target taking the raw
//! input. The libFuzzer binaries in `fuzz_targets/` call them, and
//! `tools/cli/tests/fuzz_corpus.rs` includes this file to replay the committed seed and
//! regression corpora as an ordinary test.

use std::path::Path;

use conductor_cli_formats::recording::{self, Recording};
use conductor_cli_formats::udp::{self as protocol, Malformed, Request, MAX_REQUEST};

/// A target's check: panics when the input shows a bug.
pub type Check = fn(&[u8]);

/// Every target: its name (the binary in `fuzz_targets/`, the folder under `seeds/` and
/// `regressions/`) and its check.
pub const TARGETS: &[(&str, Check)] = &[("udp_request", udp_request), ("recording", recording)];

/// One datagram of the thesis' UDP text protocol: a `SET` value is finite and prints back (in
/// exponent form) to the same request; a refusal's text (sent back to the client) is short printable ASCII.
pub fn udp_request(datagram: &[u8]) {
    match protocol::parse(datagram) {
        Ok(req) => {
            assert!(datagram.len() <= MAX_REQUEST);
            if let Request::Set(x) = req {
                assert!(x.is_finite(), "{x}");
                // In exponent form: `{x}` of 2e255 is 256 digits, over the datagram limit.
                assert_eq!(protocol::parse(format!("SET {x:e}").as_bytes()), Ok(req));
            }
        }
        Err(e) => {
            if datagram.len() > MAX_REQUEST {
                assert_eq!(e, Malformed::TooLong(datagram.len()));
            }
            let text = e.to_string();
            assert!(text.len() < 120, "{text}");
            assert!(
                text.chars().all(|c| c.is_ascii_graphic() || c == ' '),
                "{text:?}"
            );
        }
    }
}

/// Bytes as a recording file: `Recording::from_bytes` refuses or yields samples sorted by time
/// whose channels exist, and the replay's timeline over it has a positive pass length.
pub fn recording(data: &[u8]) {
    let Ok(rec) = Recording::from_bytes(Path::new("fuzz.mcap"), data) else {
        return;
    };
    assert!(rec.samples.windows(2).all(|w| w[0].t_ns <= w[1].t_ns));
    assert!(rec
        .samples
        .iter()
        .all(|s| (s.channel as usize) < rec.channels.len()));
    if !rec.samples.is_empty() {
        assert!(recording::pass_ns(&rec, rec.channels.len()) > 0);
    }
}
