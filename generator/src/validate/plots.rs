//! PNG plots of a stats report with `plotters` (bitmap backend, no system font libraries).
//!
//! Text is drawn with `ab_glyph` from DejaVu Sans, bundled in `fonts/` (Bitstream Vera licence,
//! `fonts/DejaVuSans.LICENSE`): a fresh machine needs no fontconfig, freetype or font package.
//!
//! - `stats_objects.png`: object-level target disparities (all categories) vs the law's density.
//! - `stats_pixels.png`: pixel-level disparity of both views inside the law's range vs the law,
//!   empty gap bins shaded red.
//! - `stats_categories.png`: one panel per category: pixel and object histograms, law, gaps.
//! - `stats_coverage.png`: disparity of content pixels (p5–p95 band, median, mean) by image row
//!   and column, and the fraction of content (and valid) pixels per row and column.
//! - `stats_maps.png`, where the dataset has maps beside the disparity: their distributions
//!   ([`super::map_plots`]).

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::Once;

use anyhow::anyhow;
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};

use super::hist::{UniformHist, law_density};
use super::stats::stats_report::{Band, CategoryStats, StatsReport, Status};
use crate::plan::Dist;

const FONT: &[u8] = include_bytes!("fonts/DejaVuSans.ttf");
const PIXEL: RGBColor = RGBColor(70, 110, 190);
const OBJECT: RGBColor = RGBColor(20, 140, 60);
const LAW: RGBColor = RGBColor(210, 40, 40);
const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
];

pub(super) type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;
pub(super) type Chart<'a, 'b> =
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;
/// `(lo, hi, density)` bars and their legend label.
type Bars = Option<(Vec<(f64, f64, f64)>, String)>;

pub(super) fn plot_err<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow!("plotting failed: {e:?}")
}

/// A panel's chart over `x` and `y`, titled, with `y_label_width` pixels for the y labels.
pub(super) fn panel_chart<'a, 'b>(
    area: &'a Area<'b>,
    title: &str,
    y_label_width: u32,
    x: Range<f64>,
    y: Range<f64>,
) -> anyhow::Result<Chart<'a, 'b>> {
    ChartBuilder::on(area)
        .caption(title, ("sans-serif", 17))
        .margin(8)
        .x_label_area_size(38)
        .y_label_area_size(y_label_width)
        .build_cartesian_2d(x, y)
        .map_err(plot_err)
}

/// Draws the axes with their descriptions and the coarse grid (the fine lines in white, so
/// unseen); `y_labels` formats the y tick labels where plotters' own format does not suit.
fn draw_axes(
    chart: &mut Chart,
    x_desc: &str,
    y_desc: &str,
    y_labels: Option<&dyn Fn(&f64) -> String>,
) -> anyhow::Result<()> {
    let mut mesh = chart.configure_mesh();
    mesh.x_desc(x_desc)
        .y_desc(y_desc)
        .label_style(("sans-serif", 13))
        .axis_desc_style(("sans-serif", 14))
        .light_line_style(WHITE);
    if let Some(format) = y_labels {
        mesh.y_label_formatter(format);
    }
    mesh.draw().map_err(plot_err)
}

/// A legend key: a short line in the series' style.
fn line_key(style: ShapeStyle) -> impl Fn((i32, i32)) -> PathElement<(i32, i32)> {
    move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], style)
}

/// Draws `points` joined by a line in `style`, with its legend entry: `label` by a line key.
fn draw_line(
    chart: &mut Chart,
    points: impl IntoIterator<Item = (f64, f64)>,
    style: ShapeStyle,
    label: impl Into<String>,
) -> anyhow::Result<()> {
    chart
        .draw_series(LineSeries::new(points, style))
        .map_err(plot_err)?
        .label(label)
        .legend(line_key(style));
    Ok(())
}

/// A legend key: a small filled box in the series' style.
pub(super) fn box_key(style: ShapeStyle) -> impl Fn((i32, i32)) -> Rectangle<(i32, i32)> {
    move |(x, y)| Rectangle::new([(x, y - 5), (x + 18, y + 5)], style)
}

/// Draws the legend of every labelled series on a light box with a black border.
pub(super) fn draw_legend<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    position: SeriesLabelPosition,
    font_size: u32,
) -> anyhow::Result<()> {
    chart
        .configure_series_labels()
        .position(position)
        .label_font(("sans-serif", font_size))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(plot_err)
}

fn register() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        if register_font("sans-serif", FontStyle::Normal, FONT).is_err() {
            panic!("the bundled DejaVu Sans font does not parse");
        }
    });
}

/// Draws into an RGB buffer and writes it as a PNG, atomically.
pub(super) fn render(
    path: &Path,
    (w, h): (u32, u32),
    draw: impl FnOnce(&Area) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    register();
    let mut buf = vec![255u8; w as usize * h as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err)?;
        draw(&root)?;
        root.present().map_err(plot_err)?;
    }
    stereo_io::write_png(path, &stereo_io::Image::rgb8(w as usize, h as usize, buf))?;
    Ok(())
}

/// `(lo, hi, density)` per bin; `norm` is the count that integrates to 1.
fn density_bars(h: &UniformHist, norm: u64) -> Vec<(f64, f64, f64)> {
    let w = h.bin_width();
    let edges = h.edges();
    h.counts
        .iter()
        .enumerate()
        .map(|(i, &c)| {
            (
                edges[i],
                edges[i + 1],
                if norm == 0 {
                    0.0
                } else {
                    c as f64 / (norm as f64 * w)
                },
            )
        })
        .collect()
}

fn step_line(bars: &[(f64, f64, f64)]) -> Vec<(f64, f64)> {
    let mut pts = vec![(bars[0].0, 0.0)];
    for &(a, b, y) in bars {
        pts.push((a, y));
        pts.push((b, y));
    }
    pts.push((bars[bars.len() - 1].1, 0.0));
    pts
}

/// What one histogram panel shows.
struct Panel<'a> {
    title: String,
    x: (f64, f64),
    /// Filled bars (pixel level) and their legend label.
    bars: Bars,
    /// Outline histogram (object level) and its legend label.
    outline: Bars,
    /// Law density curve and its scale (fraction of the plotted mass inside the support).
    law: Option<(&'a Dist, f64)>,
    empty: Vec<[f64; 2]>,
    /// Edges of the gap-check bins, drawn as faint vertical lines.
    gap_edges: Vec<f64>,
}

fn draw_panel(area: &Area, p: &Panel) -> anyhow::Result<()> {
    let (x0, x1) = p.x;
    let law_pts = p
        .law
        .map(|(law, scale)| {
            law_density(law, x0, x1, 600)
                .into_iter()
                .map(|(x, y)| (x, y * scale))
                .collect::<Vec<_>>()
        })
        .unwrap_or_default();
    let y_max = [
        p.bars.as_ref().map(|b| &b.0),
        p.outline.as_ref().map(|b| &b.0),
    ]
    .into_iter()
    .flatten()
    .flat_map(|v| v.iter().map(|b| b.2))
    .chain(law_pts.iter().map(|p| p.1))
    .fold(0.0, f64::max)
    .max(1e-9)
        * 1.15;
    let mut chart = panel_chart(area, &p.title, 62, x0..x1, 0.0..y_max)?;
    draw_axes(
        &mut chart,
        "disparity (px)",
        "density (1/px)",
        Some(&|v| format!("{v:.3}")),
    )?;
    if !p.empty.is_empty() {
        chart
            .draw_series(
                p.empty
                    .iter()
                    .map(|[a, b]| Rectangle::new([(*a, 0.0), (*b, y_max)], LAW.mix(0.18).filled())),
            )
            .map_err(plot_err)?
            .label(format!("empty gap bin ({})", p.empty.len()))
            .legend(box_key(LAW.mix(0.18).filled()));
    }
    if !p.gap_edges.is_empty() {
        let grey = RGBColor(150, 60, 170).mix(0.75);
        chart
            .draw_series(
                p.gap_edges
                    .iter()
                    .map(|&x| PathElement::new(vec![(x, 0.0), (x, y_max)], grey.stroke_width(1))),
            )
            .map_err(plot_err)?
            .label(format!(
                "gap-check bins ({})",
                p.gap_edges.len().saturating_sub(1)
            ))
            .legend(move |(x, y)| {
                PathElement::new(vec![(x + 9, y - 6), (x + 9, y + 6)], grey.stroke_width(1))
            });
    }
    if let Some((bars, label)) = &p.bars {
        chart
            .draw_series(
                bars.iter()
                    .map(|&(a, b, y)| Rectangle::new([(a, 0.0), (b, y)], PIXEL.mix(0.55).filled())),
            )
            .map_err(plot_err)?
            .label(label.as_str())
            .legend(box_key(PIXEL.mix(0.55).filled()));
    }
    if let Some((bars, label)) = &p.outline {
        draw_line(
            &mut chart,
            step_line(bars),
            OBJECT.stroke_width(2),
            label.as_str(),
        )?;
    }
    if !law_pts.is_empty() {
        draw_line(
            &mut chart,
            law_pts,
            LAW.stroke_width(2),
            "recipe law (density)",
        )?;
    }
    draw_legend(&mut chart, SeriesLabelPosition::UpperRight, 13)
}

fn object_bars(c: &CategoryStats) -> Bars {
    c.objects.histogram.as_ref().map(|h| {
        (
            density_bars(h, c.objects.count as u64),
            format!("object targets (n={})", c.objects.count),
        )
    })
}

fn ks_text(c: &CategoryStats) -> String {
    match (c.objects.ks_distance, c.objects.ks_critical) {
        (Some(d), Some(k)) => format!("KS {d:.3} (crit {k:.3})"),
        _ => "no objects".to_string(),
    }
}

fn status_text(c: &CategoryStats) -> &'static str {
    match c.status {
        Status::Ok => "OK",
        Status::Fail => "FAIL",
        Status::Skip => "SKIP",
    }
}

/// The x range of the law panels: the law's support with 8% padding.
fn law_range(report: &StatsReport) -> (f64, f64) {
    let (lo, hi) = (report.law_support[0], report.law_support[1]);
    let pad = ((hi - lo) * 0.08).max(0.5);
    ((lo - pad).max(0.0), hi + pad)
}

/// A panel of one category's pixel-level histogram inside the law's support, normalised over
/// the pixels inside it (so it compares with the law's density), optionally with its object
/// histogram.
fn pixel_panel<'a>(
    c: &CategoryStats,
    report: &'a StatsReport,
    title: String,
    with_objects: bool,
) -> Panel<'a> {
    let (bars, empty, gap_edges) = match &c.pixels {
        Some(p) => {
            let inside: u64 = p.histogram.counts.iter().sum();
            let share = 100.0 * inside as f64 / p.valid.max(1) as f64;
            (
                Some((
                    density_bars(&p.histogram, inside),
                    format!(
                        "pixels in the law's range ({share:.1}% of {:.2e} valid)",
                        p.valid as f64
                    ),
                )),
                p.gap_check
                    .as_ref()
                    .map(|g| g.empty.clone())
                    .unwrap_or_default(),
                p.gap_check
                    .as_ref()
                    .map(|g| g.edges.clone())
                    .unwrap_or_default(),
            )
        }
        None => (None, Vec::new(), Vec::new()),
    };
    Panel {
        title,
        x: law_range(report),
        bars,
        outline: if with_objects { object_bars(c) } else { None },
        law: Some((&report.law, 1.0)),
        empty,
        gap_edges,
    }
}

fn coverage_panel(
    area: &Area,
    title: &str,
    x_desc: &str,
    bands: &[Band],
    y_max: f64,
) -> anyhow::Result<()> {
    let mut chart = panel_chart(area, title, 55, 0.0..1.0, 0.0..y_max)?;
    draw_axes(&mut chart, x_desc, "disparity (px)", None)?;
    let mid = |b: &Band| 0.5 * (b.from + b.to);
    let have: Vec<&Band> = bands.iter().filter(|b| b.p5.is_some()).collect();
    if have.is_empty() {
        return Ok(());
    }
    let mut poly: Vec<(f64, f64)> = have.iter().map(|b| (mid(b), b.p95.unwrap())).collect();
    poly.extend(have.iter().rev().map(|b| (mid(b), b.p5.unwrap())));
    chart
        .draw_series(std::iter::once(Polygon::new(poly, PIXEL.mix(0.3).filled())))
        .map_err(plot_err)?
        .label("p5-p95")
        .legend(box_key(PIXEL.mix(0.3).filled()));
    let median = have.iter().map(|b| (mid(b), b.p50.unwrap()));
    draw_line(&mut chart, median, PIXEL.stroke_width(2), "median")?;
    let mean = have.iter().filter_map(|b| b.mean.map(|m| (mid(b), m)));
    draw_line(&mut chart, mean, BLACK.stroke_width(1), "mean")?;
    draw_legend(&mut chart, SeriesLabelPosition::UpperRight, 13)
}

fn valid_panel(
    area: &Area,
    title: &str,
    x_desc: &str,
    report: &StatsReport,
    rows: bool,
) -> anyhow::Result<()> {
    let mut chart = panel_chart(area, title, 55, 0.0..1.0, 0.0..1.05)?;
    draw_axes(&mut chart, x_desc, "fraction of pixels", None)?;
    let groups = report
        .categories
        .iter()
        .filter(|c| c.pixels.is_some())
        .enumerate()
        .map(|(i, c)| (c, PALETTE[i % PALETTE.len()], 1))
        .chain([(&report.overall, BLACK, 3)]);
    for (c, color, width) in groups {
        let p = c.pixels.as_ref().expect("filtered");
        let bands = if rows { &p.rows } else { &p.cols };
        let content = bands
            .iter()
            .map(|b| (0.5 * (b.from + b.to), b.content_fraction));
        let label = format!("{} content", c.name);
        draw_line(&mut chart, content, color.stroke_width(width), label)?;
    }
    if let Some(p) = &report.overall.pixels {
        let grey = RGBColor(150, 150, 150);
        let bands = if rows { &p.rows } else { &p.cols };
        let valid = bands
            .iter()
            .map(|b| (0.5 * (b.from + b.to), b.valid_fraction));
        draw_line(&mut chart, valid, grey.stroke_width(2), "all valid")?;
    }
    draw_legend(&mut chart, SeriesLabelPosition::MiddleRight, 12)
}

/// Writes the four PNGs into `dir` and returns their paths.
pub fn write_plots(report: &StatsReport, dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir)?;
    let mut written = Vec::new();
    let all = &report.overall;

    let path = dir.join("stats_objects.png");
    render(&path, (1000, 600), |root| {
        let title = format!(
            "Object-level target disparity vs recipe law - {}, {}",
            ks_text(all),
            status_text(all)
        );
        let panel = Panel {
            title,
            x: law_range(report),
            bars: None,
            outline: object_bars(all),
            law: Some((&report.law, 1.0)),
            empty: Vec::new(),
            gap_edges: Vec::new(),
        };
        draw_panel(root, &panel)
    })?;
    written.push(path);

    let path = dir.join("stats_pixels.png");
    render(&path, (1000, 600), |root| {
        let gaps = all
            .pixels
            .as_ref()
            .and_then(|p| p.gap_check.as_ref())
            .map_or("no gap check".to_string(), |g| {
                format!("{}/{} gap bins empty", g.empty.len(), g.bins)
            });
        let title = format!(
            "Pixel-level disparity inside the law's range (both views) - {} samples, {gaps}",
            report.samples
        );
        draw_panel(root, &pixel_panel(all, report, title, false))
    })?;
    written.push(path);

    let path = dir.join("stats_categories.png");
    let n = report.categories.len().max(1);
    let rows = n.div_ceil(2);
    render(&path, (1400, 420 * rows as u32), |root| {
        for (area, c) in root.split_evenly((rows, 2)).iter().zip(&report.categories) {
            let title = format!(
                "{} - {} scenes, {}, {}",
                c.name,
                c.samples,
                ks_text(c),
                status_text(c)
            );
            draw_panel(area, &pixel_panel(c, report, title, true))?;
        }
        Ok(())
    })?;
    written.push(path);

    let path = dir.join("stats_coverage.png");
    render(&path, (1400, 900), |root| {
        let panels = root.split_evenly((2, 2));
        let Some(p) = &all.pixels else { return Ok(()) };
        let y_max = p
            .rows
            .iter()
            .chain(&p.cols)
            .filter_map(|b| b.p95)
            .fold(0.0, f64::max)
            .max(1e-3)
            * 1.15;
        coverage_panel(
            &panels[0],
            "Content disparity by image row (pixels at or above the law's min)",
            "row (0 = top, 1 = bottom)",
            &p.rows,
            y_max,
        )?;
        coverage_panel(
            &panels[1],
            "Content disparity by image column",
            "column (0 = left, 1 = right)",
            &p.cols,
            y_max,
        )?;
        valid_panel(
            &panels[2],
            "Content-pixel fraction by row",
            "row (0 = top, 1 = bottom)",
            report,
            true,
        )?;
        valid_panel(
            &panels[3],
            "Content-pixel fraction by column",
            "column (0 = left, 1 = right)",
            report,
            false,
        )?;
        Ok(())
    })?;
    written.push(path);
    if let Some(maps) = &report.maps {
        written.push(super::map_plots::write_map_plot(maps, dir)?);
    }
    Ok(written)
}
