//! `conductor plot`: recorded states against time in one chart, like the thesis' Fig. 2.6
//! ("Robot Joint State": every joint of a leg over a walking run, one legend entry per state);
//! with `--flags`, a second panel below on the same time axis shows when each state's status
//! flags were set (one row per state and flag that was ever set).

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use conductor_bus::status;

use crate::cli::PlotArgs;
use crate::error::{CliError, Result};
use crate::recording::{Recording, RecordingError};
use crate::select::Selector;

/// One line of the chart.
#[derive(Debug, Clone)]
pub struct Series {
    /// Legend label.
    pub label: String,
    /// Units of the state.
    pub units: String,
    /// `(seconds since the first plotted sample, value)`; NaN values are left out.
    pub points: Vec<(f64, f64)>,
    /// `(seconds since the first plotted sample, status flags)` of every sample.
    pub flags: Vec<(f64, u32)>,
}

/// Flags that say where a sample comes from rather than what happened to it: not drawn.
pub const PROVENANCE: u32 = status::SIMULATED | status::REPLAYED;

/// One row of the flags panel: a state's flag and the spans (s) during which it was set.
#[derive(Debug, Clone, PartialEq)]
pub struct FlagRow {
    /// `<state>: <flag>`.
    pub label: String,
    /// Index of the series (its colour).
    pub series: usize,
    /// `(from, to)` seconds: from the first sample with the flag to the first without it (or
    /// one sample period past the last).
    pub spans: Vec<(f64, f64)>,
}

/// The rows of the flags panel: for each series, each flag bit (provenance flags aside) set in
/// at least one of its samples, in bit order.
pub fn flag_rows(series: &[Series]) -> Vec<FlagRow> {
    let mut rows = Vec::new();
    for (k, s) in series.iter().enumerate() {
        let ever = s.flags.iter().fold(0, |a, f| a | f.1) & !PROVENANCE;
        // The last span ends one mean sample period after the last sample.
        let period = match (s.flags.first(), s.flags.last()) {
            (Some(a), Some(b)) if s.flags.len() > 1 => (b.0 - a.0) / (s.flags.len() - 1) as f64,
            _ => 0.0,
        };
        for bit in (0..32).map(|b| 1u32 << b).filter(|b| ever & b != 0) {
            let mut spans = Vec::new();
            let mut open: Option<f64> = None;
            for &(t, f) in &s.flags {
                match (f & bit != 0, open) {
                    (true, None) => open = Some(t),
                    (false, Some(from)) => {
                        spans.push((from, t));
                        open = None;
                    }
                    _ => {}
                }
            }
            if let (Some(from), Some(last)) = (open, s.flags.last()) {
                spans.push((from, last.0 + period));
            }
            let name = status::names(bit).next().unwrap_or("unknown");
            rows.push(FlagRow {
                label: format!("{}: {name}", s.label.trim_end_matches("(value)")),
                series: k,
                spans,
            });
        }
    }
    rows
}

/// Picks the series of `patterns` from a recording.
pub fn series(rec: &Recording, patterns: &[String], path: &Path) -> Result<Vec<Series>> {
    let sels = patterns
        .iter()
        .map(|p| Selector::new(p))
        .collect::<Result<Vec<_>>>()?;
    let chosen: Vec<usize> = (0..rec.channels.len())
        .filter(|&i| {
            let c = &rec.channels[i];
            sels.iter().any(|s| s.matches(&c.subsystem, &c.state))
        })
        .collect();
    if chosen.is_empty() {
        let have: Vec<String> = rec.channels.iter().map(|c| c.qualified_name()).collect();
        return Err(RecordingError::Bad {
            path: path.into(),
            detail: format!(
                "no recorded state matches {}; the file has: {}",
                patterns.join(" "),
                have.join(", ")
            ),
        }
        .into());
    }
    // Short labels (the state name) unless two subsystems share a name.
    let unique = |name: &str| {
        chosen
            .iter()
            .filter(|&&i| rec.channels[i].state == name)
            .count()
            == 1
    };
    let t0 = rec
        .samples
        .iter()
        .find(|s| chosen.contains(&(s.channel as usize)))
        .map_or(0, |s| s.t_ns);
    let mut out: Vec<Series> = chosen
        .iter()
        .map(|&i| {
            let c = &rec.channels[i];
            let name = if unique(&c.state) {
                c.state.clone()
            } else {
                c.qualified_name()
            };
            Series {
                label: format!("{name}(value)"),
                units: c.meta.units.clone(),
                points: Vec::new(),
                flags: Vec::new(),
            }
        })
        .collect();
    for s in &rec.samples {
        if let Some(k) = chosen.iter().position(|&i| i == s.channel as usize) {
            let t = s.t_ns.saturating_sub(t0) as f64 * 1e-9;
            if s.value.is_finite() {
                out[k].points.push((t, s.value));
            }
            out[k].flags.push((t, s.status));
        }
    }
    Ok(out)
}

/// Distinct colours that read well on white (the "tab10" set of many plotting tools); also
/// the line colours of `conductor echo --plot`.
pub(crate) const PALETTE: [(u8, u8, u8); 10] = [
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
];

fn bounds(series: &[Series]) -> ((f64, f64), (f64, f64)) {
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for (x, y) in series.iter().flat_map(|s| &s.points) {
        x0 = x0.min(*x);
        x1 = x1.max(*x);
        y0 = y0.min(*y);
        y1 = y1.max(*y);
    }
    // The time axis spans every sample, NaN ones too (their flags are drawn).
    for (x, _) in series.iter().flat_map(|s| &s.flags) {
        x0 = x0.min(*x);
        x1 = x1.max(*x);
    }
    if y0 > y1 {
        (y0, y1) = (-1.0, 1.0);
    }
    if x0 > x1 {
        return ((0.0, 1.0), (-1.0, 1.0));
    }
    if x1 - x0 < 1e-9 {
        x1 = x0 + 1.0;
    }
    let pad = ((y1 - y0) * 0.05).max(1e-9);
    ((x0, x1), (y0 - pad, y1 + pad))
}

fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    title: &str,
    ylabel: &str,
    series: &[Series],
    flags: Option<&[FlagRow]>,
) -> std::result::Result<(), String>
where
    DB::ErrorType: 'static,
{
    let e = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    root.fill(&WHITE).map_err(e)?;
    let ((x0, x1), (y0, y1)) = bounds(series);
    // Both panels share the time axis: the same left label area keeps them aligned.
    let label_area = flags
        .into_iter()
        .flatten()
        .map(|r| 9 * r.label.chars().count() as u32 + 16)
        .fold(70, u32::max);
    let (upper, lower) = match flags {
        Some(rows) => {
            let h = root.dim_in_pixel().1;
            // The flags panel: 28 px per row plus its axis, at most half the image.
            let want = 28 * rows.len().max(1) as u32 + 90;
            let (a, b) = root.split_vertically(h - want.min(h / 2));
            (a, Some(b))
        }
        None => (root.clone(), None),
    };
    let mut chart = ChartBuilder::on(&upper)
        .caption(title, ("sans-serif", 28))
        .margin(20)
        .x_label_area_size(50)
        .y_label_area_size(label_area)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_desc("Time (s)")
        .y_desc(ylabel)
        .label_style(("sans-serif", 16))
        .axis_desc_style(("sans-serif", 18))
        .draw()
        .map_err(e)?;
    for (i, s) in series.iter().enumerate() {
        let (r, g, b) = PALETTE[i % PALETTE.len()];
        let color = RGBColor(r, g, b).stroke_width(2);
        chart
            .draw_series(LineSeries::new(s.points.iter().copied(), color))
            .map_err(e)?
            .label(s.label.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 16))
        .draw()
        .map_err(e)?;
    if let (Some(area), Some(rows)) = (lower, flags) {
        draw_flags(&area, (x0, x1), rows, label_area).map_err(e)?;
    }
    root.present().map_err(e)?;
    Ok(())
}

/// The flags panel: one row per (state, flag), a bar in the state's colour while it was set.
fn draw_flags<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    (x0, x1): (f64, f64),
    rows: &[FlagRow],
    label_area: u32,
) -> std::result::Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let n = rows.len().max(1) as i32;
    let mut chart = ChartBuilder::on(area)
        .margin(20)
        .margin_top(5)
        .x_label_area_size(50)
        .y_label_area_size(label_area)
        .build_cartesian_2d(x0..x1, (0..n).into_segmented())?;
    // Row 0 on top: the segments count from the bottom.
    let labels: Vec<String> = rows.iter().rev().map(|r| r.label.clone()).collect();
    chart
        .configure_mesh()
        .disable_y_mesh()
        .x_desc("Time (s)")
        .y_labels(n as usize)
        .y_label_formatter(&|v| match v {
            SegmentValue::CenterOf(i) => labels.get(*i as usize).cloned().unwrap_or_default(),
            _ => String::new(),
        })
        .label_style(("sans-serif", 16))
        .axis_desc_style(("sans-serif", 18))
        .draw()?;
    if rows.is_empty() {
        chart.draw_series(std::iter::once(Text::new(
            "no flags set (simulated/replayed aside)",
            (x0 + (x1 - x0) * 0.02, SegmentValue::CenterOf(0)),
            ("sans-serif", 16),
        )))?;
        return Ok(());
    }
    for (i, row) in rows.iter().enumerate() {
        let (r, g, b) = PALETTE[row.series % PALETTE.len()];
        let color = RGBColor(r, g, b).filled();
        let i = n - 1 - i as i32;
        chart.draw_series(row.spans.iter().map(|&(a, b)| {
            let mut bar = Rectangle::new(
                [(a, SegmentValue::Exact(i)), (b, SegmentValue::Exact(i + 1))],
                color,
            );
            // A gap between rows, so that adjacent flags read as two bars.
            bar.set_margin(3, 3, 0, 0);
            bar
        }))?;
    }
    Ok(())
}

/// Registers the embedded DejaVu Sans as "sans-serif" (no system fonts needed).
fn register_font() -> Result<()> {
    use std::sync::OnceLock;
    static DONE: OnceLock<bool> = OnceLock::new();
    let ok = *DONE.get_or_init(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, dejavu::sans::regular())
            .is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err(CliError::Plot("the embedded font did not load".into()))
    }
}

/// Draws the chart; returns the number of series.
pub fn run(args: &PlotArgs) -> Result<usize> {
    if args.width < 200 || args.height < 150 {
        return Err(CliError::Usage("--width/--height: at least 200x150".into()));
    }
    let rec = Recording::load(&args.file)?;
    if rec.truncated {
        eprintln!(
            "warning: {} ends early (was the recorder killed?); plotting what is readable",
            args.file.display()
        );
    }
    let series = series(&rec, &args.states, &args.file)?;
    register_font()?;
    let title = args.title.clone().unwrap_or_else(|| {
        args.file
            .file_name()
            .map_or("recording".into(), |n| n.to_string_lossy().into_owned())
    });
    let ylabel = args.ylabel.clone().unwrap_or_else(|| {
        let u = &series[0].units;
        if !u.is_empty() && series.iter().all(|s| &s.units == u) {
            format!("Value ({u})")
        } else {
            "Value".into()
        }
    });
    let flags = args.flags.then(|| flag_rows(&series));
    let size = (args.width, args.height);
    let svg = args
        .output
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("svg"));
    let r = if svg {
        draw(
            SVGBackend::new(&args.output, size).into_drawing_area(),
            &title,
            &ylabel,
            &series,
            flags.as_deref(),
        )
    } else {
        draw(
            BitMapBackend::new(&args.output, size).into_drawing_area(),
            &title,
            &ylabel,
            &series,
            flags.as_deref(),
        )
    };
    r.map_err(CliError::Plot)?;
    eprintln!(
        "plotted {} state(s){} to {}",
        series.len(),
        flags.map_or(String::new(), |f| format!(" and {} flag row(s)", f.len())),
        args.output.display()
    );
    Ok(series.len())
}
