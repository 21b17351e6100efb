//! `stats_maps.png` (`stats --plot`, where the dataset has maps beside the disparity): one panel
//! per map the dataset has — depth of the surface pixels (log scale), the angle between normal
//! and the direction back to the camera, instances visible per sample, and each semantic class's
//! share of the pixels in its palette colour (`stereo_io::colormap::categorical`).

use std::path::{Path, PathBuf};

use plotters::prelude::*;

use super::hist::UniformHist;
use super::plots::{Area, box_key, draw_legend, panel_chart, plot_err, render};
use super::stats::maps::{DepthStats, InstanceStats, MapStats, NormalStats, SemanticStats};

const BAR: RGBColor = RGBColor(70, 110, 190);

/// A histogram's bars, each (left edge, right edge, height), as filled rectangles.
fn bar_rects(bars: &[(f64, f64, f64)]) -> impl Iterator<Item = Rectangle<(f64, f64)>> + '_ {
    bars.iter()
        .map(|&(a, b, y)| Rectangle::new([(a, 0.0), (b, y)], BAR.mix(0.6).filled()))
}
const MARK: RGBColor = RGBColor(210, 40, 40);

/// Axes with descriptions; `x_labels` formats the x tick labels.
fn axes(
    chart: &mut super::plots::Chart,
    x_desc: &str,
    y_desc: &str,
    x_labels: &dyn Fn(&f64) -> String,
    x_count: usize,
) -> anyhow::Result<()> {
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .x_labels(x_count)
        .x_label_formatter(x_labels)
        .y_label_formatter(&|v| format!("{:.0}%", 100.0 * v))
        .label_style(("sans-serif", 13))
        .axis_desc_style(("sans-serif", 14))
        .light_line_style(WHITE)
        .draw()
        .map_err(plot_err)
}

/// `(lo, hi, share)` of the non-empty span of `h` (shares of all its counts).
fn shares(h: &UniformHist) -> Vec<(f64, f64, f64)> {
    let total = h.counts.iter().sum::<u64>().max(1) as f64;
    let edges = h.edges();
    let first = h.counts.iter().position(|&c| c > 0).unwrap_or(0);
    let last = h.counts.iter().rposition(|&c| c > 0).unwrap_or(0);
    (first..=last)
        .map(|i| (edges[i], edges[i + 1], h.counts[i] as f64 / total))
        .collect()
}

fn y_top(bars: &[(f64, f64, f64)]) -> f64 {
    bars.iter().map(|b| b.2).fold(0.0, f64::max).max(1e-6) * 1.15
}

fn depth_panel(area: &Area, d: &DepthStats) -> anyhow::Result<()> {
    let bars = shares(&d.histogram_log10_m);
    let (x0, x1) = match (bars.first(), bars.last()) {
        (Some(a), Some(b)) => (a.0 - 0.05, b.1 + 0.05),
        _ => (-1.0, 1.0),
    };
    let title = format!(
        "Depth of surface pixels - median {} m, valid {:.1}%",
        d.median.map_or("-".into(), |m| format!("{m:.3}")),
        100.0 * d.valid_fraction
    );
    let mut chart = panel_chart(area, &title, 55, x0..x1, 0.0..y_top(&bars))?;
    let metres = |v: &f64| format!("{:.3}", 10f64.powf(*v));
    axes(
        &mut chart,
        "depth (m, log scale)",
        "share of surface pixels",
        &metres,
        8,
    )?;
    chart.draw_series(bar_rects(&bars)).map_err(plot_err)?;
    Ok(())
}

fn normals_panel(area: &Area, n: &NormalStats) -> anyhow::Result<()> {
    let h = &n.angle_histogram_deg;
    let total = h.counts.iter().sum::<u64>().max(1) as f64;
    let edges = h.edges();
    let bars: Vec<(f64, f64, f64)> = (0..h.bins())
        .map(|i| (edges[i], edges[i + 1], h.counts[i] as f64 / total))
        .collect();
    let title = format!(
        "Normal vs direction to the camera - within 30/60/90 deg: {:.1}/{:.1}/{:.1}%",
        100.0 * n.facing[0],
        100.0 * n.facing[1],
        100.0 * n.facing[2]
    );
    let top = y_top(&bars);
    let mut chart = panel_chart(area, &title, 55, 0.0..180.0, 0.0..top)?;
    axes(
        &mut chart,
        "angle (deg)",
        "share of surface pixels",
        &|v| format!("{v:.0}"),
        10,
    )?;
    chart
        .draw_series(bar_rects(&bars))
        .map_err(plot_err)?
        .label("surface pixels")
        .legend(box_key(BAR.mix(0.6).filled()));
    chart
        .draw_series(
            n.facing_deg
                .iter()
                .map(|&x| PathElement::new(vec![(x, 0.0), (x, top)], MARK.stroke_width(1))),
        )
        .map_err(plot_err)?
        .label("30, 60, 90 deg")
        .legend(|(x, y)| PathElement::new(vec![(x + 9, y - 6), (x + 9, y + 6)], MARK));
    draw_legend(&mut chart, SeriesLabelPosition::UpperRight, 13)
}

fn instance_panel(area: &Area, i: &InstanceStats) -> anyhow::Result<()> {
    let total = i.visible_counts.iter().sum::<u64>().max(1) as f64;
    let bars: Vec<(f64, f64, f64)> = i
        .visible_counts
        .iter()
        .enumerate()
        .map(|(k, &c)| (k as f64 - 0.4, k as f64 + 0.4, c as f64 / total))
        .collect();
    let title = format!(
        "Instances visible per sample - min/mean/max {:.0}/{:.2}/{:.0}",
        i.visible[0], i.visible[1], i.visible[2]
    );
    let x1 = i.visible_counts.len() as f64 - 0.5;
    let mut chart = panel_chart(area, &title, 55, -0.5..x1.max(0.5), 0.0..y_top(&bars))?;
    let ticks = i.visible_counts.len().clamp(2, 20);
    axes(
        &mut chart,
        "instances visible",
        "share of samples",
        &|v| format!("{v:.0}"),
        ticks,
    )?;
    chart.draw_series(bar_rects(&bars)).map_err(plot_err)?;
    Ok(())
}

fn semantic_panel(area: &Area, s: &SemanticStats) -> anyhow::Result<()> {
    let classes: Vec<_> = s.classes.iter().filter(|c| c.pixels > 0).collect();
    let top = classes
        .iter()
        .map(|c| c.share)
        .fold(0.0, f64::max)
        .max(1e-6)
        * 1.15;
    let n = classes.len().max(1) as f64;
    let mut chart = panel_chart(
        area,
        "Semantic classes - share of all pixels",
        55,
        -0.5..n - 0.5,
        0.0..top,
    )?;
    let names = |v: &f64| {
        let k = v.round();
        match classes.get(k as usize) {
            Some(c) if (v - k).abs() < 1e-6 && k >= 0.0 => c.name.clone(),
            _ => String::new(),
        }
    };
    axes(
        &mut chart,
        "class",
        "share of pixels",
        &names,
        classes.len() + 1,
    )?;
    chart
        .draw_series(classes.iter().enumerate().map(|(k, c)| {
            let [r, g, b] = stereo_io::colormap::categorical(c.id);
            let colour = RGBColor(r, g, b).filled();
            Rectangle::new([(k as f64 - 0.4, 0.0), (k as f64 + 0.4, c.share)], colour)
        }))
        .map_err(plot_err)?;
    Ok(())
}

/// Writes `stats_maps.png` into `dir` and returns its path.
pub fn write_map_plot(maps: &MapStats, dir: &Path) -> anyhow::Result<PathBuf> {
    let path = dir.join("stats_maps.png");
    render(&path, (1400, 900), |root| {
        let panels = root.split_evenly((2, 2));
        if let Some(d) = &maps.depth {
            depth_panel(&panels[0], d)?;
        }
        if let Some(n) = &maps.normals {
            normals_panel(&panels[1], n)?;
        }
        if let Some(i) = &maps.instance {
            instance_panel(&panels[2], i)?;
        }
        if let Some(s) = &maps.semantic {
            semantic_panel(&panels[3], s)?;
        }
        Ok(())
    })?;
    Ok(path)
}
