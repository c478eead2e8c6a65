//! A transcript as printed: the banner, then `$>` commands each followed by their output.

use std::path::Path;

/// One line as a comparison sees it: the print's typographic minus (`−`) and quotes (`’`, `‘`)
/// as typed (`-`, `'`), runs of white space as one space, none at the ends.
pub fn normalize(s: &str) -> String {
    s.replace('\u{2212}', "-")
        .replace(['\u{2019}', '\u{2018}'], "'")
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
}

/// A normalized `printvars` line, `NAME - 1.234567` (six decimals), as name and value.
pub fn var_line(s: &str) -> Option<(String, f64)> {
    let (name, value) = s.split_once(" - ")?;
    let (_, decimals) = value.split_once('.')?;
    (decimals.len() == 6 && !name.contains(' ')).then_some(())?;
    Some((name.to_string(), value.parse().ok()?))
}

/// One command typed at the `$>` prompt and the lines printed under it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Step {
    /// The command, normalized, without the prompt.
    pub command: String,
    /// The output lines, normalized, without blank lines and the author's notes.
    pub expected: Vec<String>,
}

/// A parsed transcript.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Transcript {
    /// Where it came from (file name), for messages.
    pub name: String,
    /// The lines before the first prompt (the start-up banner), normalized.
    pub banner: Vec<String>,
    /// The commands in order.
    pub steps: Vec<Step>,
}

impl Transcript {
    /// Parses `text`. A line is a command if it starts with `$>`; a line in parentheses on its
    /// own (`(Image A)`) is the author's note about a picture, not output.
    pub fn parse(name: &str, text: &str) -> Self {
        let mut banner = Vec::new();
        let mut steps: Vec<Step> = Vec::new();
        for raw in text.lines() {
            let line = normalize(raw);
            if let Some(cmd) = line.strip_prefix("$>") {
                steps.push(Step {
                    command: cmd.trim().to_string(),
                    expected: Vec::new(),
                });
            } else if line.is_empty() {
                continue;
            } else if let Some(step) = steps.last_mut() {
                if !(line.starts_with('(') && line.ends_with(')')) {
                    step.expected.push(line);
                }
            } else {
                banner.push(line);
            }
        }
        Self {
            name: name.to_string(),
            banner,
            steps,
        }
    }

    /// Reads and parses `file` of the thesis corpus ([`crate::thesis_dir`]).
    pub fn load(file: &str) -> std::io::Result<Self> {
        Self::read(&crate::thesis_dir().join(file))
    }

    /// Reads and parses a transcript file; its name is the file name.
    pub fn read(path: &Path) -> std::io::Result<Self> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| std::io::Error::new(e.kind(), format!("{}: {e}", path.display())))?;
        let name = path.file_name().unwrap_or(path.as_os_str());
        Ok(Self::parse(&name.to_string_lossy(), &text))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn typography_and_spacing_fold() {
        assert_eq!(normalize("  ADCA \u{2212}  530.0\t"), "ADCA - 530.0");
        assert_eq!(normalize("Type \u{2019}help\u{2018}"), "Type 'help'");
        assert_eq!(normalize(" \t "), "");
    }

    #[test]
    fn variable_lines_need_a_name_and_six_decimals() {
        assert_eq!(
            var_line("pw2 - -51.906158"),
            Some(("pw2".into(), -51.906158))
        );
        assert_eq!(var_line("pw2 - 51.90615"), None);
        assert_eq!(var_line("p w2 - 51.906158"), None);
        assert_eq!(var_line("pw2 - 5x.906158"), None);
        assert_eq!(var_line("adc 0 100"), None);
    }

    #[test]
    fn banner_steps_and_notes() {
        let t = Transcript::parse(
            "t",
            "Welcome to SEEPS (v0.1)\n\n$>  pwm A 1000  50\n(Image A)\n\n  $> printvars\n\
             ADCA \u{2212} 530.000000\n",
        );
        assert_eq!(t.banner, ["Welcome to SEEPS (v0.1)"]);
        assert_eq!(
            t.steps,
            [
                Step {
                    command: "pwm A 1000 50".into(),
                    expected: vec![],
                },
                Step {
                    command: "printvars".into(),
                    expected: vec!["ADCA - 530.000000".into()],
                },
            ]
        );
    }

    #[test]
    fn the_corpus_is_found() {
        let t = Transcript::load("fig5_6.transcript").unwrap();
        assert_eq!(t.name, "fig5_6.transcript");
        assert_eq!(t.steps[0].command, "adc A 1000");
        let err = Transcript::load("no-such.transcript").unwrap_err();
        assert!(err.to_string().contains("no-such.transcript"), "{err}");
    }
}
