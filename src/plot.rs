//! Multi-panel line-chart PNGs (states against references, learning curves, scaling fits) for the
//! CLI's reports, drawn with plotters and the bundled DejaVu Sans font (no system fonts needed).

use std::path::Path;
use std::sync::Once;

use anyhow::{bail, Context};
use plotters::prelude::*;
use plotters::style::FontStyle;

/// The font bundled in the repository (`assets/fonts/`, licence beside it).
static FONT: &[u8] = include_bytes!("../assets/fonts/DejaVuSans.ttf");
static REGISTER: Once = Once::new();

fn register_font() {
    REGISTER.call_once(|| {
        // The bytes are a valid TrueType font checked in with the code; a failure here would
        // only make text disappear, so it is ignored rather than aborting the plot.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// One curve: points `(t, y)`, a legend label, and how it is drawn.
#[derive(Clone, Debug)]
pub struct Series {
    /// Legend text (no legend entry when empty).
    pub label: String,
    /// The points, in time order.
    pub points: Vec<(f64, f64)>,
    /// Dashed line (used for references and bounds).
    pub dashed: bool,
    /// Unconnected markers instead of a line (used for measurements a fit is drawn through).
    pub markers: bool,
    /// Palette index of the colour (default: the series' position in its panel), so that a fit
    /// and its measurements can share one colour.
    pub color: Option<usize>,
}

impl Series {
    /// A solid curve from parallel time and value slices.
    pub fn new(label: impl Into<String>, t: &[f64], y: &[f64]) -> Self {
        Series {
            label: label.into(),
            points: t.iter().copied().zip(y.iter().copied()).collect(),
            dashed: false,
            markers: false,
            color: None,
        }
    }

    /// The same curve in palette colour `index`.
    pub fn colored(mut self, index: usize) -> Self {
        self.color = Some(index);
        self
    }

    /// The same points drawn as unconnected markers.
    pub fn markers(mut self) -> Self {
        self.markers = true;
        self
    }

    /// The same curve drawn dashed.
    pub fn dashed(mut self) -> Self {
        self.dashed = true;
        self
    }
}

/// One panel (sub-plot) stacked vertically with the others, sharing the time axis.
#[derive(Clone, Debug)]
pub struct Panel {
    /// Panel caption.
    pub title: String,
    /// Label of the y axis.
    pub y_label: String,
    /// Its curves.
    pub series: Vec<Series>,
}

const COLORS: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
];

/// Draws `panels` stacked vertically, sharing an x axis labelled `x_label`, into a PNG at `path`
/// (written to a temporary name in the same directory, then renamed). `width` is in pixels; each
/// panel is 260 px high.
pub fn time_series_png(
    path: &Path,
    title: &str,
    x_label: &str,
    panels: &[Panel],
    width: u32,
) -> anyhow::Result<()> {
    if panels.is_empty() {
        bail!("nothing to plot: no panels");
    }
    register_font();
    let name = path
        .file_name()
        .and_then(|n| n.to_str())
        .context("plot path has no file name")?;
    // The renderer picks the format from the extension: the unique temporary name keeps `.png`.
    let tmp = koopman::fsutil::temp_path(path)?.with_extension("tmp.png");
    let result = draw(&tmp, title, x_label, panels, width);
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    koopman::fsutil::commit(&tmp, path).with_context(|| format!("writing {name}"))
}

fn draw(
    path: &Path,
    title: &str,
    x_label: &str,
    panels: &[Panel],
    width: u32,
) -> anyhow::Result<()> {
    let height = 60 + 260 * panels.len() as u32;
    let root = BitMapBackend::new(path, (width, height)).into_drawing_area();
    root.fill(&WHITE)
        .map_err(|e| anyhow::anyhow!("plot: {e}"))?;
    let root = root
        .titled(title, ("sans-serif", 24))
        .map_err(|e| anyhow::anyhow!("plot title: {e}"))?;
    let areas = root.split_evenly((panels.len(), 1));
    for (panel, area) in panels.iter().zip(&areas) {
        let (x0, x1, y0, y1, legend_corner) = layout(panel);
        // Whole-number data (rounds, counts) get no fractional tick labels (no "round 0.5").
        let whole_x = panel
            .series
            .iter()
            .flat_map(|s| s.points.iter())
            .all(|p| !p.0.is_finite() || p.0.fract() == 0.0);
        let mut chart = ChartBuilder::on(area)
            .caption(&panel.title, ("sans-serif", 18))
            .margin(8)
            .x_label_area_size(36)
            .y_label_area_size(64)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(|e| anyhow::anyhow!("plot axes: {e}"))?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc(&panel.y_label)
            .x_label_formatter(&|x| x_tick_label(*x, whole_x))
            .y_label_formatter(&|y| tick_label(*y))
            .label_style(("sans-serif", 14))
            .draw()
            .map_err(|e| anyhow::anyhow!("plot mesh: {e}"))?;
        for (i, s) in panel.series.iter().enumerate() {
            let color = COLORS[s.color.unwrap_or(i) % COLORS.len()];
            let pts: Vec<(f64, f64)> = s
                .points
                .iter()
                .copied()
                .filter(|p| p.0.is_finite() && p.1.is_finite())
                .collect();
            let style = color.stroke_width(2);
            let drawn = if s.markers {
                chart.draw_series(pts.into_iter().map(|p| Circle::new(p, 4, color.filled())))
            } else if s.dashed {
                chart.draw_series(DashedLineSeries::new(pts, 8, 5, style))
            } else {
                chart.draw_series(LineSeries::new(pts, style))
            };
            let drawn = drawn.map_err(|e| anyhow::anyhow!("plot series: {e}"))?;
            if !s.label.is_empty() {
                drawn.label(s.label.clone()).legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2))
                });
            }
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 14))
            .position(legend_corner)
            .draw()
            .map_err(|e| anyhow::anyhow!("plot legend: {e}"))?;
    }
    root.present()
        .map_err(|e| anyhow::anyhow!("writing {}: {e}", path.display()))?;
    Ok(())
}

/// The axis ranges of `panel` (its finite points, padded; scattered markers get room at the
/// ends and a legend band above the data) and the corner for its legend.
fn layout(panel: &Panel) -> (f64, f64, f64, f64, SeriesLabelPosition) {
    let pts = panel
        .series
        .iter()
        .flat_map(|s| s.points.iter())
        .filter(|p| p.0.is_finite() && p.1.is_finite());
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for &(x, y) in pts {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if !x0.is_finite() {
        (x0, x1, y0, y1) = (0.0, 1.0, -1.0, 1.0);
    }
    if x1 <= x0 {
        x1 = x0 + 1.0;
    }
    let scatter = panel.series.iter().any(|s| s.markers);
    if scatter {
        // Markers at the ends of the range would be cut in half.
        let pad = (x1 - x0) * 0.03;
        (x0, x1) = (x0 - pad, x1 + pad);
    }
    let pad = ((y1 - y0) * 0.08).max(1e-3);
    let (y0, mut y1) = (y0 - pad, y1 + pad);
    let legend_corner = if scatter {
        // Scattered measurements: the legend gets a band of its own above the data.
        let entries = panel.series.iter().filter(|s| !s.label.is_empty()).count();
        let band = ((entries as f64 * 19.0 + 14.0) / 178.0).min(0.6);
        y1 += (y1 - y0) * band / (1.0 - band);
        SeriesLabelPosition::UpperRight
    } else {
        emptiest_corner(panel, (x0, x1), (y0, y1))
    };
    (x0, x1, y0, y1, legend_corner)
}

/// The corner of the plot area whose box (45% of the width, 40% of the height) holds the fewest
/// points of `panel`, so that the legend hides as little as possible (upper right on a tie).
fn emptiest_corner(panel: &Panel, x: (f64, f64), y: (f64, f64)) -> SeriesLabelPosition {
    let corners = [
        (SeriesLabelPosition::UpperRight, true, true),
        (SeriesLabelPosition::UpperLeft, false, true),
        (SeriesLabelPosition::LowerRight, true, false),
        (SeriesLabelPosition::LowerLeft, false, false),
    ];
    let count = |right: bool, upper: bool| {
        panel
            .series
            .iter()
            .flat_map(|s| s.points.iter())
            .filter(|p| p.0.is_finite() && p.1.is_finite())
            .filter(|p| {
                let fx = (p.0 - x.0) / (x.1 - x.0);
                let fy = (p.1 - y.0) / (y.1 - y.0);
                let in_x = if right { fx >= 0.55 } else { fx <= 0.45 };
                let in_y = if upper { fy >= 0.6 } else { fy <= 0.4 };
                in_x && in_y
            })
            .count()
    };
    let mut best = (SeriesLabelPosition::UpperRight, usize::MAX);
    for (corner, right, upper) in corners {
        let n = count(right, upper);
        if n < best.1 {
            best = (corner, n);
        }
    }
    best.0
}

/// An axis tick: whole numbers from 100 up (iterations, sample counts), otherwise at most three
/// decimals without trailing zeros.
/// An x tick's label: none for a fractional tick on an axis of whole-number data.
fn x_tick_label(v: f64, whole: bool) -> String {
    if whole && (v - v.round()).abs() > 1e-9 {
        String::new()
    } else {
        tick_label(v)
    }
}

fn tick_label(v: f64) -> String {
    if v.abs() >= 100.0 {
        return format!("{v:.0}");
    }
    let s = format!("{v:.3}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".into()
    } else {
        s.into()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_legend_goes_where_the_curves_are_not() {
        let t: Vec<f64> = (0..=10).map(f64::from).collect();
        let falling: Vec<f64> = t.iter().map(|v| 10.0 - v).collect();
        let panel = |y: &[f64]| Panel {
            title: String::new(),
            y_label: String::new(),
            series: vec![Series::new("y", &t, y)],
        };
        // A falling line crosses the upper-left and lower-right corners only.
        let corner = emptiest_corner(&panel(&falling), (0.0, 10.0), (0.0, 10.0));
        assert!(matches!(corner, SeriesLabelPosition::UpperRight));
        let rising: Vec<f64> = t.clone();
        let corner = emptiest_corner(&panel(&rising), (0.0, 10.0), (0.0, 10.0));
        assert!(matches!(corner, SeriesLabelPosition::UpperLeft));
        // Points along the top: the legend goes below them.
        let top = vec![9.5; t.len()];
        let corner = emptiest_corner(&panel(&top), (0.0, 10.0), (-0.5, 10.0));
        assert!(matches!(corner, SeriesLabelPosition::LowerRight));
    }

    #[test]
    fn tick_labels_drop_float_noise() {
        assert_eq!(tick_label(10000.0), "10000");
        assert_eq!(tick_label(0.30000000000000004), "0.3");
        assert_eq!(tick_label(-1.25), "-1.25");
        assert_eq!(tick_label(2.0), "2");
        assert_eq!(tick_label(-0.0001), "0");
        assert_eq!(x_tick_label(1.5, true), "");
        assert_eq!(x_tick_label(2.0, true), "2");
        assert_eq!(x_tick_label(1.5, false), "1.5");
    }

    #[test]
    fn draws_a_png_atomically() {
        let dir = std::env::temp_dir().join(format!("koopbridge-plot-{}", std::process::id()));
        let path = dir.join("p.png");
        let t: Vec<f64> = (0..50).map(|k| k as f64 * 0.1).collect();
        let y: Vec<f64> = t.iter().map(|v| v.sin()).collect();
        let panels = vec![Panel {
            title: "states".into(),
            y_label: "θ [rad]".into(),
            series: vec![
                Series::new("θ", &t, &y),
                Series::new("θ ref", &t, &vec![0.0; 50]).dashed(),
            ],
        }];
        time_series_png(&path, "test", "t [s]", &panels, 600).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
        // No temporary file is left behind.
        let left: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .filter_map(|e| e.ok())
            .map(|e| e.file_name())
            .collect();
        assert_eq!(left.len(), 1, "{left:?}");
        assert!(time_series_png(&path, "empty", "t [s]", &[], 600).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
