//! The human terminal (thesis Fig. 5.1): banner, `$> ` prompt, echo, backspace, one command
//! per line, output with CR LF line ends.

use core::fmt::Write;

use score_core::hal::Hal;
use score_core::line::{LineBuffer, LineEvent};
use score_core::{Real, PROMPT};

use crate::board::{Board, Extra};
use crate::out::TextOut;

/// Line assembly and echo for one terminal.
#[derive(Debug, Clone, Default)]
pub struct Terminal {
    line: LineBuffer,
}

impl Terminal {
    /// A fresh terminal.
    pub const fn new() -> Self {
        Self {
            line: LineBuffer::new(),
        }
    }

    /// The start-up text: the thesis' banner, the board, then the prompt.
    pub fn banner<N: Real, H: Hal, const O: usize>(
        &self,
        board: &Board<N, H>,
        out: &mut TextOut<O>,
    ) {
        let _ = writeln!(out);
        let _ = score_core::write_banner(out);
        let _ = writeln!(
            out,
            "Board '{}', {}, numbers {}",
            board.info.board,
            board.info.firmware,
            N::NAME
        );
        let _ = writeln!(out);
        let _ = write!(out, "{PROMPT}");
    }

    /// Feeds typed bytes: echoes them, and runs each completed line (output, then a new
    /// prompt). Returns true if a line ran (the port wakes its update loop: the table or the
    /// hardware may have changed).
    pub fn feed<N: Real, H: Hal, const O: usize>(
        &mut self,
        bytes: &[u8],
        board: &mut Board<N, H>,
        now_us: u64,
        out: &mut TextOut<O>,
        extra: Extra<'_>,
    ) -> bool {
        let mut ran = false;
        for &b in bytes {
            match self.line.push(b) {
                LineEvent::None => {}
                LineEvent::Echo(c) => out.push_bytes(&[c]),
                LineEvent::Erase => out.push_bytes(b"\x08 \x08"),
                LineEvent::Full => out.push_bytes(b"\x07"),
                LineEvent::Line => {
                    let _ = writeln!(out);
                    let line = self.line.line();
                    if !line.trim().is_empty() {
                        board.run_line(line, now_us, out, &mut *extra);
                        ran = true;
                    }
                    if out.truncated() {
                        let _ = writeln!(out, "\n(output cut)");
                    }
                    let _ = write!(out, "{PROMPT}");
                }
            }
        }
        ran
    }
}
