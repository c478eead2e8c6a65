//! Typing a transcript into a terminal and holding the output to the printed one.

use crate::parse::{normalize, var_line, Transcript};

/// The variables of one `printvars`, as our terminal printed them, in order.
pub type Listing = Vec<(String, f64)>;

/// How our terminal's output differed from the transcript.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Mismatch {
    /// A banner line of the thesis is not in ours.
    #[error("{transcript}: banner line {line:?} missing from {ours:?}")]
    Banner {
        /// Transcript name.
        transcript: String,
        /// The thesis' line.
        line: String,
        /// Our banner's lines.
        ours: Vec<String>,
    },
    /// The transcript has no command at all (a parse of the wrong file).
    #[error("{transcript}: no `$>` command")]
    NoCommands {
        /// Transcript name.
        transcript: String,
    },
    /// A `printvars` listed other variables, or in another order.
    #[error("{transcript}: {command}: variables {got:?}, expected {expected:?}")]
    Variables {
        /// Transcript name.
        transcript: String,
        /// The command typed.
        command: String,
        /// The thesis' names, in order.
        expected: Vec<String>,
        /// Ours.
        got: Vec<String>,
    },
    /// A `printvars` printed something besides variable lines.
    #[error("{transcript}: {command}: only variable lines expected: {actual:?}")]
    NotOnlyVariables {
        /// Transcript name.
        transcript: String,
        /// The command typed.
        command: String,
        /// Our output lines.
        actual: Vec<String>,
    },
    /// A printed line is missing from our output (or out of order).
    #[error("{transcript}: after {command:?} expected {line:?} in {actual:?}")]
    Missing {
        /// Transcript name.
        transcript: String,
        /// The command typed.
        command: String,
        /// The thesis' line not found.
        line: String,
        /// Our output lines.
        actual: Vec<String>,
    },
    /// Our terminal refused a command the thesis' accepted.
    #[error("{transcript}: {command} failed: {actual:?}")]
    Refused {
        /// Transcript name.
        transcript: String,
        /// The command typed.
        command: String,
        /// Our output lines.
        actual: Vec<String>,
    },
}

impl Transcript {
    /// Holds a terminal to this transcript. `banner` is what the terminal printed on start;
    /// `type_line` types one command and returns what it printed (without the echo), after
    /// letting the time a person takes to type pass, so periodic variables move.
    ///
    /// Checked: every banner line (but the thesis' program name and author lines) is in ours;
    /// a step whose printed output is all variable lines (`printvars`) prints exactly the
    /// same variables in the same order and nothing else; any other step prints every printed
    /// line in order (ours may print more, e.g. longer menus) and no `error:` line. Returns
    /// the variable listings, in order, for the caller's checks of the values.
    pub fn check(
        &self,
        banner: &str,
        mut type_line: impl FnMut(&str) -> String,
    ) -> Result<Vec<Listing>, Mismatch> {
        let transcript = || self.name.clone();
        let ours: Vec<String> = banner.lines().map(normalize).collect();
        // The thesis' program was called SEEPS, by Bob Sherbert: those lines differ on purpose.
        for line in self
            .banner
            .iter()
            .filter(|l| !l.contains("SEEPS") && !l.contains("Sherbert"))
        {
            if !ours.contains(line) {
                return Err(Mismatch::Banner {
                    transcript: transcript(),
                    line: line.clone(),
                    ours,
                });
            }
        }
        if self.steps.is_empty() {
            return Err(Mismatch::NoCommands {
                transcript: transcript(),
            });
        }
        let mut listings = Vec::new();
        for step in &self.steps {
            let actual: Vec<String> = type_line(&step.command)
                .lines()
                .map(normalize)
                .filter(|l| !l.is_empty())
                .collect();
            let expected_vars: Listing = step.expected.iter().filter_map(|l| var_line(l)).collect();
            if !expected_vars.is_empty() && expected_vars.len() == step.expected.len() {
                let got: Listing = actual.iter().filter_map(|l| var_line(l)).collect();
                let names = |v: &Listing| v.iter().map(|(n, _)| n.clone()).collect::<Vec<_>>();
                if names(&got) != names(&expected_vars) {
                    return Err(Mismatch::Variables {
                        transcript: transcript(),
                        command: step.command.clone(),
                        expected: names(&expected_vars),
                        got: names(&got),
                    });
                }
                if got.len() != actual.len() {
                    return Err(Mismatch::NotOnlyVariables {
                        transcript: transcript(),
                        command: step.command.clone(),
                        actual,
                    });
                }
                listings.push(got);
            } else {
                let mut at = 0;
                for e in &step.expected {
                    let Some(i) = actual[at..].iter().position(|a| a == e) else {
                        return Err(Mismatch::Missing {
                            transcript: transcript(),
                            command: step.command.clone(),
                            line: e.clone(),
                            actual,
                        });
                    };
                    at += i + 1;
                }
                if actual.iter().any(|l| l.starts_with("error:")) {
                    return Err(Mismatch::Refused {
                        transcript: transcript(),
                        command: step.command.clone(),
                        actual,
                    });
                }
            }
        }
        Ok(listings)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TEXT: &str = "Welcome to SEEPS (v0.1)\n\
        (Systems Engineering Embedded Prototyping System)\n\
        $> var\n\
        Variables menu\n\
        printvars\n\
        $> adc A 1000\n\
        $> printvars\n\
        ADCA \u{2212} 530.000000\n\
        adca \u{2212} 0.057185\n";

    const BANNER: &str =
        "Welcome to Score (v9)\r\n(Systems Engineering Embedded Prototyping System)\r\n";

    /// A terminal that answers each command from a table.
    fn terminal<'a>(answers: &'a [(&'a str, &'a str)]) -> impl FnMut(&str) -> String + 'a {
        move |cmd| {
            answers.iter().find(|(c, _)| *c == cmd).map_or_else(
                || panic!("unexpected command {cmd}"),
                |(_, a)| a.to_string(),
            )
        }
    }

    fn transcript() -> Transcript {
        Transcript::parse("t", TEXT)
    }

    #[test]
    fn a_matching_terminal_passes_and_its_values_are_returned() {
        let listings = transcript()
            .check(
                BANNER,
                terminal(&[
                    ("var", "Variables menu\n  (more)\nprintvars\ndefexp\n"),
                    ("adc A 1000", ""),
                    ("printvars", "ADCA - 600.000000\r\n\r\nadca -  0.250000\r\n"),
                ]),
            )
            .unwrap();
        assert_eq!(
            listings,
            [vec![
                ("ADCA".to_string(), 600.0),
                ("adca".to_string(), 0.25)
            ]]
        );
    }

    #[test]
    fn each_difference_is_named() {
        let t = transcript();
        let banner = t
            .check("Welcome to Score (v9)\n", terminal(&[]))
            .unwrap_err();
        assert!(
            matches!(&banner, Mismatch::Banner { line, .. } if line.starts_with("(Systems")),
            "{banner}"
        );
        // (output of `var`, output of `printvars`, the mismatch expected)
        type Case = (&'static str, &'static str, fn(&Mismatch) -> bool);
        let cases: [Case; 5] = [
            (
                "printvars\nVariables menu",
                "ADCA - 1.000000\nadca - 2.000000",
                |m| matches!(m, Mismatch::Missing { line, .. } if line == "printvars"),
            ),
            (
                "Variables menu\nerror: x\nprintvars",
                "",
                |m| matches!(m, Mismatch::Refused { command, .. } if command == "var"),
            ),
            (
                "Variables menu\nprintvars",
                "adca - 2.000000\nADCA - 1.000000",
                |m| matches!(m, Mismatch::Variables { got, .. } if got == &["adca", "ADCA"]),
            ),
            (
                "Variables menu\nprintvars",
                "ADCA - 1.000000\nadca - 2.00",
                |m| matches!(m, Mismatch::Variables { got, .. } if got == &["ADCA"]),
            ),
            (
                "Variables menu\nprintvars",
                "ADCA - 1.000000\nadca - 2.000000\nnote: x",
                |m| matches!(m, Mismatch::NotOnlyVariables { .. }),
            ),
        ];
        for (var_out, printvars_out, is) in cases {
            let m = t
                .check(
                    BANNER,
                    terminal(&[
                        ("var", var_out),
                        ("adc A 1000", ""),
                        ("printvars", printvars_out),
                    ]),
                )
                .unwrap_err();
            assert!(is(&m), "{m}");
            assert!(m.to_string().starts_with("t: "), "{m}");
        }
        let empty = Transcript::parse("e", "Welcome\n").check("Welcome", terminal(&[]));
        assert!(matches!(empty, Err(Mismatch::NoCommands { .. })));
    }
}
