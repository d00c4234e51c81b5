//! Draws the curves of pushgrasp training runs (grasp success, learner loss, mean Q against
//! Q*, the share of relabelled transitions) as the panels of one PNG or SVG figure.
//!
//! The caller supplies the data; this crate only lays it out. Several series in a panel overlay
//! several runs, and series `i` has the same colour in every panel, so one run reads the same
//! across the figure.
//!
//! Its tests take it past 400 lines; the code itself is under 400.

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use thiserror::Error;

/// One curve, e.g. one run's loss against learner updates.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Series {
    /// Legend entry, e.g. the run's name.
    pub label: String,
    /// `(x, y)` in drawing order. Points with a non-finite coordinate are left out, so a
    /// diverged loss does not take the axes with it.
    pub points: Vec<(f64, f64)>,
}

/// One panel of a figure.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Chart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
    /// Horizontal reference lines, e.g. `(1.8, "Q*")`.
    pub references: Vec<(f64, String)>,
    /// Fixed y range (e.g. `(0.0, 100.0)` for a percentage), used when it is finite and
    /// increasing; otherwise the range fits the data and the reference lines.
    pub y_range: Option<(f64, f64)>,
}

#[derive(Debug, Error)]
pub enum PlotError {
    #[error("{}: unknown plot format, the file name must end in .png or .svg", path.display())]
    UnknownFormat { path: PathBuf },
    #[error("{}: no charts to draw", path.display())]
    NoCharts { path: PathBuf },
    #[error("{}: drawing failed: {message}", path.display())]
    Draw { path: PathBuf, message: String },
    #[error("{}: could not write the SVG", path.display())]
    WriteSvg {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: could not write the PNG", path.display())]
    WritePng {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
}

/// Pixels of one panel; the figure is a grid of them.
const PANEL_SIZE: (u32, u32) = (640, 420);

/// Series colours by index (matplotlib's "tab10"), so run `i` is the same colour in every panel.
const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

/// Reference lines are dark grey and dashed, so they never pass for a run.
const REFERENCE_COLOUR: RGBColor = RGBColor(60, 60, 60);

/// The font family every text uses; `register_font` binds it to the bundled font.
const FONT: &str = "sans-serif";

/// Draws `charts` as the panels of one figure, a grid `columns` wide (clamped to 1 and to the
/// number of charts), and writes it to `path` as PNG or SVG, chosen by the file's extension.
pub fn draw(charts: &[Chart], columns: usize, path: &Path) -> Result<(), PlotError> {
    let extension = path.extension().and_then(|e| e.to_str()).unwrap_or("");
    let svg = if extension.eq_ignore_ascii_case("svg") {
        true
    } else if extension.eq_ignore_ascii_case("png") {
        false
    } else {
        return Err(PlotError::UnknownFormat { path: path.into() });
    };
    if charts.is_empty() {
        return Err(PlotError::NoCharts { path: path.into() });
    }
    let draw_error = |message: String| PlotError::Draw {
        path: path.into(),
        message,
    };
    register_font().map_err(draw_error)?;

    let columns = columns.clamp(1, charts.len());
    let rows = charts.len().div_ceil(columns);
    let size = (PANEL_SIZE.0 * columns as u32, PANEL_SIZE.1 * rows as u32);
    if svg {
        let mut text = String::new();
        draw_figure(
            SVGBackend::with_string(&mut text, size).into_drawing_area(),
            charts,
            columns,
        )
        .map_err(|e| draw_error(e.to_string()))?;
        std::fs::write(path, text).map_err(|source| PlotError::WriteSvg {
            path: path.into(),
            source,
        })
    } else {
        // Drawn into memory and encoded with the workspace's `image`: plotters' own PNG
        // encoder would bring in a second, older `image`.
        let mut pixels = vec![0; size.0 as usize * size.1 as usize * 3];
        draw_figure(
            BitMapBackend::with_buffer(&mut pixels, size).into_drawing_area(),
            charts,
            columns,
        )
        .map_err(|e| draw_error(e.to_string()))?;
        image::save_buffer_with_format(
            path,
            &pixels,
            size.0,
            size.1,
            image::ExtendedColorType::Rgb8,
            image::ImageFormat::Png,
        )
        .map_err(|source| PlotError::WritePng {
            path: path.into(),
            source,
        })
    }
}

/// plotters' `ab_glyph` text engine knows only the fonts registered with it, and both backends
/// need one: the bitmap to rasterise text, the SVG to size label areas and legends. DejaVu
/// Sans comes from the `dejavu` crate, so no system font library or font file is needed.
fn register_font() -> Result<(), String> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let registered = *REGISTERED.get_or_init(|| {
        plotters::style::register_font(FONT, FontStyle::Normal, dejavu::sans::regular()).is_ok()
    });
    if registered {
        Ok(())
    } else {
        Err("the bundled font could not be loaded".into())
    }
}

fn draw_figure<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    charts: &[Chart],
    columns: usize,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    root.fill(&WHITE)?;
    let rows = charts.len().div_ceil(columns);
    for (area, chart) in root.split_evenly((rows, columns)).iter().zip(charts) {
        draw_panel(area, chart)?;
    }
    root.present()
}

fn draw_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    chart: &Chart,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let (curves, x, y) = curves_and_ranges(chart);
    let references: Vec<&(f64, String)> = chart
        .references
        .iter()
        .filter(|(value, _)| value.is_finite() && (y.start..=y.end).contains(value))
        .collect();

    let mut ctx = ChartBuilder::on(area)
        .caption(&chart.title, (FONT, 20))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(65)
        .build_cartesian_2d(x.clone(), y.clone())?;
    let (x_tick, y_tick) = (tick_format(&x), tick_format(&y));
    ctx.configure_mesh()
        .x_label_formatter(&x_tick)
        .y_label_formatter(&y_tick)
        .x_desc(&chart.x_label)
        .y_desc(&chart.y_label)
        .label_style((FONT, 13))
        .axis_desc_style((FONT, 15))
        .bold_line_style(RGBColor(225, 225, 225))
        .max_light_lines(0)
        .draw()?;

    for (i, (series, points)) in chart.series.iter().zip(&curves).enumerate() {
        let style = PALETTE[i % PALETTE.len()].stroke_width(2);
        // A lone point makes no line; a dot shows it.
        let dot = if points.len() == 1 { 3 } else { 0 };
        ctx.draw_series(LineSeries::new(points.iter().copied(), style).point_size(dot))?
            .label(&series.label)
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 24, y)], style));
    }
    for (value, label) in &references {
        let style = REFERENCE_COLOUR.stroke_width(1);
        ctx.draw_series(DashedLineSeries::new(
            [(x.start, *value), (x.end, *value)],
            6,
            4,
            style,
        ))?
        .label(label)
        .legend(move |(x, y)| {
            plotters::element::DashedPathElement::new([(x, y), (x + 24, y)], 6, 4, style)
        });
    }

    if curves.iter().all(Vec::is_empty) {
        let style = (FONT, 18)
            .into_font()
            .color(&REFERENCE_COLOUR)
            .pos(Pos::new(HPos::Center, VPos::Center));
        let centre = ((x.start + x.end) / 2.0, (y.start + y.end) / 2.0);
        ctx.plotting_area()
            .draw(&Text::new("no data", centre, style))?;
    }
    if chart.series.len() > 1 || !references.is_empty() {
        ctx.configure_series_labels()
            .position(legend_corner(&curves, &x, &y))
            .label_font((FONT, 13))
            .background_style(WHITE.mix(0.85))
            .border_style(REFERENCE_COLOUR)
            .draw()?;
    }
    Ok(())
}

/// A series' points as drawn.
type Curve = Vec<(f64, f64)>;

/// Each series' finite points and the axes' ranges: x fits the points; y is the chart's
/// fixed range (the points clamped into it) or fits the points and the reference lines.
fn curves_and_ranges(chart: &Chart) -> (Vec<Curve>, Range<f64>, Range<f64>) {
    let fixed_y = chart
        .y_range
        .filter(|&(lo, hi)| lo.is_finite() && hi.is_finite() && lo < hi)
        .map(|(lo, hi)| lo..hi);
    let mut curves: Vec<Curve> = chart
        .series
        .iter()
        .map(|s| {
            s.points
                .iter()
                .copied()
                .filter(|(x, y)| x.is_finite() && y.is_finite())
                .collect()
        })
        .collect();
    let x = fit(curves.iter().flatten().map(|p| p.0), 0.0);
    let y = match &fixed_y {
        Some(range) => {
            // Nothing clips to the plotting area, so a curve leaving a fixed range runs
            // along its edge instead of over the axes.
            for p in curves.iter_mut().flatten() {
                p.1 = p.1.clamp(range.start, range.end);
            }
            range.clone()
        }
        // The reference lines are part of the fit, so Q* stays in view below the curves.
        None => fit(
            curves.iter().flatten().map(|p| p.1).chain(
                chart
                    .references
                    .iter()
                    .map(|r| r.0)
                    .filter(|v| v.is_finite()),
            ),
            0.05,
        ),
    };
    (curves, x, y)
}

/// The range of `values` widened by `pad` of its span on each side; a single value gets a unit
/// wide range around it and no values get `0..1`, as plotters needs a non-empty range.
fn fit(values: impl Iterator<Item = f64>, pad: f64) -> Range<f64> {
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    if lo > hi {
        0.0..1.0
    } else if lo == hi {
        lo - 0.5..hi + 0.5
    } else {
        let margin = (hi - lo) * pad;
        lo - margin..hi + margin
    }
}

/// Tick labels with as many decimals as the roughly ten ticks of `range` need: plotters'
/// default writes episode 250 as "250.0".
fn tick_format(range: &Range<f64>) -> impl Fn(&f64) -> String {
    let step = (range.end - range.start) / 10.0;
    // The nudge keeps a step of 0.1 whose logarithm rounds below -1 at one decimal.
    let decimals = (-(step.log10() + 1e-9).floor()).clamp(0.0, 12.0) as usize;
    move |v| format!("{v:.decimals$}")
}

/// The corner whose quarter of the plot holds the fewest points, so the legend hides as
/// little as it can: a falling loss leaves the upper right free, a rising success rate the
/// upper left, a plateau near the top the lower corners.
fn legend_corner(curves: &[Curve], x: &Range<f64>, y: &Range<f64>) -> SeriesLabelPosition {
    let x_mid = (x.start + x.end) / 2.0;
    let y_mid = (y.start + y.end) / 2.0;
    // Indexed by (right, upper) as 2 * right + upper.
    let mut counts = [0usize; 4];
    for &(px, py) in curves.iter().flatten() {
        counts[2 * usize::from(px >= x_mid) + usize::from(py >= y_mid)] += 1;
    }
    // On ties the earlier corner wins: upper right is where legends are looked for first.
    [
        (3, SeriesLabelPosition::UpperRight),
        (1, SeriesLabelPosition::UpperLeft),
        (2, SeriesLabelPosition::LowerRight),
        (0, SeriesLabelPosition::LowerLeft),
    ]
    .into_iter()
    .min_by_key(|&(quadrant, _)| counts[quadrant])
    .map_or(SeriesLabelPosition::UpperRight, |(_, corner)| corner)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn corner(points: &[(f64, f64)]) -> SeriesLabelPosition {
        legend_corner(&[points.to_vec()], &(0.0..10.0), &(0.0..1.0))
    }

    #[test]
    fn legend_avoids_the_curve() {
        let falling: Vec<_> = (0..10)
            .map(|i| (i as f64, 0.95 - i as f64 / 10.0))
            .collect();
        assert!(matches!(corner(&falling), SeriesLabelPosition::UpperRight));
        let rising: Vec<_> = (0..10)
            .map(|i| (i as f64, 0.05 + i as f64 / 10.0))
            .collect();
        assert!(matches!(corner(&rising), SeriesLabelPosition::UpperLeft));
        let high: Vec<_> = (0..10).map(|i| (i as f64, 0.9)).collect();
        assert!(matches!(corner(&high), SeriesLabelPosition::LowerRight));
    }

    #[test]
    fn ticks_have_the_decimals_the_range_needs() {
        assert_eq!(tick_format(&(0.0..300.0))(&250.0), "250");
        assert_eq!(tick_format(&(0.0..100.0))(&50.0), "50");
        assert_eq!(tick_format(&(-0.1..2.1))(&0.4), "0.4");
        assert_eq!(tick_format(&(0.0..0.05))(&0.015), "0.015");
        assert_eq!(tick_format(&(0.0..1.0))(&0.3), "0.3");
    }

    #[test]
    fn fit_pads_and_never_collapses() {
        assert_eq!(fit([0.0, 10.0].into_iter(), 0.1), -1.0..11.0);
        assert_eq!(fit([2.0].into_iter(), 0.1), 1.5..2.5);
        assert_eq!(fit(std::iter::empty(), 0.1), 0.0..1.0);
    }

    /// Each overlaid series strokes its polyline in its own palette colour.
    #[test]
    fn overlaid_series_get_distinct_palette_colours() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("overlay.svg");
        let series = (0..3)
            .map(|run| Series {
                label: format!("run {run}"),
                points: (0..20)
                    .map(|i| (i as f64, (i * (run + 1)) as f64))
                    .collect(),
            })
            .collect();
        let chart = Chart {
            series,
            ..Chart::default()
        };
        draw(&[chart], 1, &path).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        let strokes: Vec<String> = PALETTE[..3]
            .iter()
            .map(|RGBColor(r, g, b)| format!("stroke=\"#{r:02X}{g:02X}{b:02X}\""))
            .collect();
        for stroke in &strokes {
            // The curve and its legend sample.
            assert!(
                svg.matches(stroke.as_str()).count() >= 2,
                "{stroke} missing"
            );
        }
        assert!(!svg.contains(&format!(
            "stroke=\"#{:02X}{:02X}{:02X}\"",
            PALETTE[3].0, PALETTE[3].1, PALETTE[3].2
        )));
    }
}
