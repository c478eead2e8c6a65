//! Text formatting shared by the commands: values, ages, flags, limits and aligned tables.

use conductor_bus::status;

/// The value as the shortest decimal that parses back to the same `f64`.
pub fn value(v: f64) -> String {
    format!("{v}")
}

/// A duration in seconds with a readable unit: `850 ns`, `3.1 µs`, `12.0 ms`, `2.35 s`.
pub fn age(secs: f64) -> String {
    if !secs.is_finite() {
        return "-".into();
    }
    let a = secs.abs();
    if a < 1e-6 {
        format!("{:.0} ns", secs * 1e9)
    } else if a < 1e-3 {
        format!("{:.1} µs", secs * 1e6)
    } else if a < 1.0 {
        format!("{:.1} ms", secs * 1e3)
    } else {
        format!("{secs:.2} s")
    }
}

/// The names of the flags set in `status`, comma-separated, or `-`.
pub fn flags(s: u32) -> String {
    let v: Vec<&str> = status::names(s).collect();
    if v.is_empty() {
        "-".into()
    } else {
        v.join(",")
    }
}

/// `[min,max]` (no space, so columns split on whitespace), with `-inf`/`inf` for unbounded sides.
pub fn limits(min: f64, max: f64) -> String {
    format!("[{min},{max}]")
}

/// Formats rows as left-aligned columns separated by two spaces; the first row is the header.
pub fn table(rows: &[Vec<String>]) -> String {
    let cols = rows.iter().map(Vec::len).max().unwrap_or(0);
    let mut width = vec![0; cols];
    for r in rows {
        for (i, c) in r.iter().enumerate() {
            width[i] = width[i].max(c.chars().count());
        }
    }
    let mut s = String::new();
    for r in rows {
        let mut line = String::new();
        for (i, c) in r.iter().enumerate() {
            if i + 1 == r.len() {
                line += c;
            } else {
                line += c;
                line.extend(std::iter::repeat_n(' ', width[i] - c.chars().count() + 2));
            }
        }
        s += line.trim_end();
        s.push('\n');
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_round_trip() {
        for v in [0.1, -2.5e-300, 1.0 / 3.0, 123456789.125] {
            assert_eq!(value(v).parse::<f64>().unwrap(), v);
        }
    }

    #[test]
    fn ages_pick_units() {
        assert_eq!(age(850e-9), "850 ns");
        assert_eq!(age(3.14e-6), "3.1 µs");
        assert_eq!(age(0.012), "12.0 ms");
        assert_eq!(age(2.345), "2.35 s");
        assert_eq!(age(f64::INFINITY), "-");
    }

    #[test]
    fn flags_and_limits() {
        assert_eq!(flags(0), "-");
        assert_eq!(
            flags(status::CLAMPED | status::SIMULATED),
            "clamped,simulated"
        );
        // ABI v2: a refused setpoint of a tripped device reads as such.
        assert_eq!(
            flags(status::REJECTED | status::WATCHDOG | status::DISABLED | status::TRIPPED),
            "rejected,watchdog,disabled,tripped"
        );
        assert_eq!(limits(f64::NEG_INFINITY, 1.5), "[-inf,1.5]");
    }

    #[test]
    fn table_aligns_columns() {
        let t = table(&[
            vec!["A".into(), "BB".into(), "C".into()],
            vec!["xxx".into(), "y".into(), "z".into()],
        ]);
        assert_eq!(t, "A    BB  C\nxxx  y   z\n");
    }
}
