//! PNG plots of a suite run (plotters, the DejaVu font embedded so no system font is needed):
//! lateness histograms beside cyclictest's, the thesis error against time (Fig. 3.1), and the
//! scaling curves (measured points with their least-squares line).

use std::path::Path;

use conductor_bus::histogram::bucket_range;
use conductor_bus::Histogram;
use plotters::prelude::*;

use super::fit::LineFit;

/// Image width (px).
pub const WIDTH: u32 = 1200;
/// Image height (px).
pub const HEIGHT: u32 = 700;

/// Why a plot could not be drawn.
#[derive(Debug, thiserror::Error)]
#[error("plotting {path}: {detail}")]
pub struct PlotError {
    /// The image.
    pub path: String,
    /// What went wrong.
    pub detail: String,
}

/// Distinct colours that read well on white (the "tab10" set).
const PALETTE: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
];

fn register_font() -> bool {
    use std::sync::OnceLock;
    static DONE: OnceLock<bool> = OnceLock::new();
    *DONE.get_or_init(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, dejavu::sans::regular())
            .is_ok()
    })
}

/// Bins per octave of the common histogram layout.
const PER_OCTAVE: f64 = 4.0;

/// A latency distribution rebinned to 4 bins per octave from 1 µs (bin 0: below 1 µs), so that
/// the executor's log-linear buckets and cyclictest's 1 µs buckets share one x axis.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Distribution {
    /// Legend label.
    pub label: String,
    /// Count per bin.
    pub bins: Vec<u64>,
    /// Values counted.
    pub total: u64,
}

fn bin_of(ns: u64) -> usize {
    if ns < 1000 {
        0
    } else {
        (PER_OCTAVE * (ns as f64 / 1000.0).log2()).floor() as usize + 1
    }
}

/// The centre of bin `b` in µs (on a log axis).
fn bin_centre_us(b: usize) -> f64 {
    if b == 0 {
        0.7
    } else {
        2f64.powf((b as f64 - 0.5) / PER_OCTAVE)
    }
}

impl Distribution {
    fn add(&mut self, ns: u64, count: u64) {
        let b = bin_of(ns);
        if self.bins.len() <= b {
            self.bins.resize(b + 1, 0);
        }
        self.bins[b] += count;
        self.total += count;
    }

    /// From the executor's histogram (each bucket counted at its lower bound).
    pub fn from_histogram(label: &str, h: &Histogram) -> Self {
        let mut d = Self {
            label: label.into(),
            ..Self::default()
        };
        for (i, &c) in h.counts().iter().enumerate().filter(|(_, c)| **c > 0) {
            d.add(bucket_range(i).0, c);
        }
        d
    }

    /// From `(µs, count)` buckets (cyclictest's).
    pub fn from_us_buckets(label: &str, buckets: &[(u64, u64)]) -> Self {
        let mut d = Self {
            label: label.into(),
            ..Self::default()
        };
        for &(us, c) in buckets {
            d.add(us * 1000, c);
        }
        d
    }

    /// `(bin centre µs, fraction of all values)` of every non-empty bin.
    fn points(&self) -> Vec<(f64, f64)> {
        self.bins
            .iter()
            .enumerate()
            .filter(|(_, c)| **c > 0)
            .map(|(b, &c)| (bin_centre_us(b), c as f64 / self.total.max(1) as f64))
            .collect()
    }
}

type DrawResult = Result<(), Box<dyn std::error::Error>>;

/// A white canvas of the plots' size at `path`.
fn canvas(
    path: &Path,
) -> Result<DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>, Box<dyn std::error::Error>> {
    let root = BitMapBackend::new(path, (WIDTH, HEIGHT)).into_drawing_area();
    root.fill(&WHITE)?;
    Ok(root)
}

/// A chart on `root` with `title` and the margins every plot here has (`y_labels` px for the
/// y axis' labels).
fn titled<'a, 'b>(
    root: &'a DrawingArea<BitMapBackend<'b>, plotters::coord::Shift>,
    title: &str,
    y_labels: u32,
) -> ChartBuilder<'a, 'b, BitMapBackend<'b>> {
    let mut b = ChartBuilder::on(root);
    b.caption(title, ("sans-serif", 26))
        .margin(20)
        .x_label_area_size(50)
        .y_label_area_size(y_labels);
    b
}

/// The legend box of every plot: upper right, on a light background.
fn draw_legend<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 15))
        .draw()?;
    Ok(())
}

/// Registers the font, draws, and names the image in any error.
fn plot(path: &Path, draw: impl FnOnce() -> DrawResult) -> Result<(), PlotError> {
    let r = if register_font() {
        draw()
    } else {
        Err("the embedded font did not load".into())
    };
    r.map_err(|e| PlotError {
        path: path.display().to_string(),
        detail: e.to_string(),
    })
}

/// Lateness histograms (log–log: fraction of wake-ups per bin against lateness) of `series`.
pub fn lateness_png(path: &Path, title: &str, series: &[Distribution]) -> Result<(), PlotError> {
    plot(path, || draw_lateness(path, title, series))
}

fn draw_lateness(path: &Path, title: &str, series: &[Distribution]) -> DrawResult {
    let pts: Vec<Vec<(f64, f64)>> = series.iter().map(Distribution::points).collect();
    let x_max = pts.iter().flatten().map(|p| p.0).fold(10.0f64, f64::max) * 1.5;
    let y_min = pts
        .iter()
        .flatten()
        .map(|p| p.1)
        .fold(1.0f64, f64::min)
        .max(1e-9)
        / 2.0;
    let root = canvas(path)?;
    let mut chart = titled(&root, title, 80)
        .build_cartesian_2d((0.5f64..x_max).log_scale(), (y_min..1.5f64).log_scale())?;
    chart
        .configure_mesh()
        .x_desc("Wake-up lateness (µs), 4 bins per octave")
        .y_desc("Fraction of wake-ups")
        .label_style(("sans-serif", 15))
        .axis_desc_style(("sans-serif", 17))
        .draw()?;
    for (i, (d, p)) in series.iter().zip(&pts).enumerate() {
        let c = PALETTE[i % PALETTE.len()];
        chart
            .draw_series(LineSeries::new(p.iter().copied(), c.stroke_width(2)))?
            .label(format!("{} (n={})", d.label, d.total))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
        chart.draw_series(p.iter().map(|&xy| Circle::new(xy, 3, c.filled())))?;
    }
    draw_legend(&mut chart)?;
    root.present()?;
    Ok(())
}

/// One curve of an error plot: `(seconds, sin(t_L) − value)`.
#[derive(Debug, Clone, Copy)]
pub struct Curve<'a> {
    /// Legend label.
    pub label: &'a str,
    /// The points.
    pub points: &'a [(f64, f64)],
}

/// The thesis' Fig. 3.1: the error sin(t_L) − value against time, one curve per series.
pub fn error_png(path: &Path, title: &str, curves: &[Curve<'_>]) -> Result<(), PlotError> {
    plot(path, || draw_error(path, title, curves))
}

fn draw_error(path: &Path, title: &str, curves: &[Curve<'_>]) -> DrawResult {
    let t_max = curves
        .iter()
        .flat_map(|c| c.points.iter().map(|p| p.0))
        .fold(1e-3f64, f64::max);
    let y_abs = curves
        .iter()
        .flat_map(|c| c.points.iter().map(|p| p.1.abs()))
        .filter(|v| v.is_finite())
        .fold(1e-9f64, f64::max)
        * 1.1;
    let root = canvas(path)?;
    let mut chart = titled(&root, title, 90).build_cartesian_2d(0f64..t_max, -y_abs..y_abs)?;
    chart
        .configure_mesh()
        .x_desc("Time (s)")
        .y_desc("Error (sin(t) − StateValue(t))")
        .y_label_formatter(&|v| format!("{v:.1e}"))
        .label_style(("sans-serif", 15))
        .axis_desc_style(("sans-serif", 17))
        .draw()?;
    for (i, c) in curves.iter().enumerate() {
        let col = PALETTE[i % PALETTE.len()];
        chart
            .draw_series(LineSeries::new(
                c.points.iter().copied().filter(|p| p.1.is_finite()),
                col.stroke_width(1),
            ))?
            .label(c.label)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], col.stroke_width(2)));
    }
    draw_legend(&mut chart)?;
    root.present()?;
    Ok(())
}

/// One measured series of a scaling curve: `(x, y)` points, drawn as markers joined by a line.
#[derive(Debug, Clone, Copy)]
pub struct Series<'a> {
    /// Legend label.
    pub label: &'a str,
    /// The points.
    pub points: &'a [(f64, f64)],
}

/// A scaling curve: `series` against `x`, with the fitted line `fit` (dashed, over the series'
/// x range) labelled `fit_label`; linear axes from 0.
pub fn curve_png(
    path: &Path,
    title: &str,
    (x_desc, y_desc): (&str, &str),
    series: &[Series<'_>],
    fit: Option<(&str, LineFit)>,
) -> Result<(), PlotError> {
    plot(path, || {
        draw_curve(path, title, (x_desc, y_desc), series, fit)
    })
}

fn draw_curve(
    path: &Path,
    title: &str,
    (x_desc, y_desc): (&str, &str),
    series: &[Series<'_>],
    fit: Option<(&str, LineFit)>,
) -> DrawResult {
    let all = || {
        series
            .iter()
            .flat_map(|s| s.points.iter().copied())
            .filter(|p| p.0.is_finite() && p.1.is_finite())
    };
    let x_max = all().map(|p| p.0).fold(1.0f64, f64::max) * 1.05;
    let fit_y = |x: f64| fit.map_or(0.0, |(_, f)| f.at(x));
    let y_max = all()
        .map(|p| p.1)
        .chain([fit_y(0.0), fit_y(x_max)])
        .fold(1e-3f64, f64::max)
        * 1.15;
    let root = canvas(path)?;
    let mut chart = titled(&root, title, 80).build_cartesian_2d(0f64..x_max, 0f64..y_max)?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .label_style(("sans-serif", 15))
        .axis_desc_style(("sans-serif", 17))
        .draw()?;
    for (i, s) in series.iter().enumerate() {
        let c = PALETTE[i % PALETTE.len()];
        let pts: Vec<(f64, f64)> = s
            .points
            .iter()
            .copied()
            .filter(|p| p.0.is_finite() && p.1.is_finite())
            .collect();
        chart
            .draw_series(LineSeries::new(pts.iter().copied(), c.stroke_width(2)))?
            .label(s.label)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
        chart.draw_series(pts.iter().map(|&xy| Circle::new(xy, 5, c.filled())))?;
    }
    if let Some((label, f)) = fit {
        let (x0, x1) = all().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.0), b.max(p.0)));
        if x0 <= x1 {
            let c = BLACK.mix(0.6);
            chart
                .draw_series(DashedLineSeries::new(
                    [(x0, f.at(x0)), (x1, f.at(x1))],
                    8,
                    6,
                    c.stroke_width(2),
                ))?
                .label(label)
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2))
                });
        }
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 15))
        .draw()?;
    root.present()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rebinning_puts_both_sources_on_one_grid() {
        assert_eq!((bin_of(0), bin_of(999), bin_of(1000)), (0, 0, 1));
        // One octave above 1 µs is 4 bins further.
        assert_eq!(bin_of(2000), 5);
        let mut h = Histogram::new();
        h.record(2_000);
        h.record(500);
        let a = Distribution::from_histogram("x", &h);
        let b = Distribution::from_us_buckets("y", &[(2, 1), (0, 1)]);
        // The executor's bucket holding 2000 ns is [1920, 2047]: counted at 1920 ns, one bin
        // below cyclictest's 2 µs.
        assert_eq!(a.bins, vec![1, 0, 0, 0, 1]);
        assert_eq!(b.bins, vec![1, 0, 0, 0, 0, 1]);
        let p = b.points();
        assert_eq!(p.len(), 2);
        assert!((p.iter().map(|x| x.1).sum::<f64>() - 1.0).abs() < 1e-12);
    }
}
