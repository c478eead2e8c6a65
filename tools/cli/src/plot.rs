//! `conductor plot`: recorded states against time in one chart, like the thesis' Fig. 2.6
//! ("Robot Joint State": every joint of a leg over a walking run, one legend entry per state).

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::cli::PlotArgs;
use crate::error::{CliError, Result};
use crate::recording::Recording;
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
        return Err(CliError::BadRecording {
            path: path.into(),
            detail: format!(
                "no recorded state matches {}; the file has: {}",
                patterns.join(" "),
                have.join(", ")
            ),
        });
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
            }
        })
        .collect();
    for s in &rec.samples {
        if let Some(k) = chosen.iter().position(|&i| i == s.channel as usize) {
            if s.value.is_finite() {
                out[k]
                    .points
                    .push((s.t_ns.saturating_sub(t0) as f64 * 1e-9, s.value));
            }
        }
    }
    Ok(out)
}

/// Distinct colours that read well on white (the "tab10" set of many plotting tools).
const PALETTE: [(u8, u8, u8); 10] = [
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
) -> std::result::Result<(), String>
where
    DB::ErrorType: 'static,
{
    let e = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    root.fill(&WHITE).map_err(e)?;
    let ((x0, x1), (y0, y1)) = bounds(series);
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 28))
        .margin(20)
        .x_label_area_size(50)
        .y_label_area_size(70)
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
    root.present().map_err(e)?;
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
        )
    } else {
        draw(
            BitMapBackend::new(&args.output, size).into_drawing_area(),
            &title,
            &ylabel,
            &series,
        )
    };
    r.map_err(CliError::Plot)?;
    eprintln!(
        "plotted {} state(s) to {}",
        series.len(),
        args.output.display()
    );
    Ok(series.len())
}
