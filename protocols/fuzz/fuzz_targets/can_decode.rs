//! CAN payload decoders: MIT-mode replies and commands, ODrive messages, SLCAN lines.
#![no_main]
use conductor_protocols::mit_can::{self, Model, Reply};
use conductor_protocols::odrive_can::{CmdId, Message};
use conductor_protocols::slcan::{Command, Dialect, Line, Response, BEL, CR};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|input: &[u8]| {
    let l = Model::Ak80_9.limits();
    if let Ok(r) = Reply::decode(input, &l) {
        assert!(r.p.is_finite() && r.v.is_finite() && r.t.is_finite());
    }
    let _ = mit_can::decode_command(input, &l);
    if let Some((&code, rest)) = input.split_first() {
        if let Some(cmd) = CmdId::from_code(code & 0x1F) {
            if let Ok(m) = Message::decode(cmd, rest) {
                let _ = m.encode();
            }
        }
    }
    for term in [CR, BEL] {
        if let Ok(r) = Response::decode(Line { body: input, terminator: term }) {
            let mut buf = [0u8; 128];
            let _ = r.encode(&mut buf);
        }
    }
    let _ = Command::decode(input, &Dialect::default());
});
