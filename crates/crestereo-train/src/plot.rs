//! The loss curve of a run as a PNG (`crestereo plot`): training loss per step with a moving
//! average on a log axis, and the training / validation EPE beside it; and the error of
//! `crestereo eval --disturb` against each disturbance's level.

use std::path::Path;
use std::sync::Once;

use anyhow::{Context, Result, anyhow, bail};
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};

// The generator's bundled DejaVu Sans (Bitstream Vera licence): no system font libraries needed.
const FONT: &[u8] = include_bytes!("../../../generator/src/validate/fonts/DejaVuSans.ttf");

fn register() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        if register_font("sans-serif", FontStyle::Normal, FONT).is_err() {
            panic!("the bundled DejaVu Sans font does not parse");
        }
    });
}

fn err<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow!("plotting failed: {e:?}")
}

/// Columns of a CSV by header name: `(step, value)` pairs of finite values.
fn read_columns(path: &Path, want: &[&str]) -> Result<Vec<Vec<(f64, f64)>>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap_or_default().split(',').collect();
    let idx: Vec<usize> = want
        .iter()
        .map(|w| {
            header
                .iter()
                .position(|h| h == w)
                .ok_or_else(|| anyhow!("{}: no column `{w}`", path.display()))
        })
        .collect::<Result<_>>()?;
    let mut out = vec![Vec::new(); want.len()];
    for line in lines {
        let cells: Vec<&str> = line.split(',').collect();
        let Some(step) = cells.first().and_then(|s| s.parse::<f64>().ok()) else {
            continue;
        };
        for (k, &i) in idx.iter().enumerate() {
            if let Some(v) = cells
                .get(i)
                .and_then(|s| s.parse::<f64>().ok())
                .filter(|v| v.is_finite())
            {
                out[k].push((step, v));
            }
        }
    }
    Ok(out)
}

/// Trailing moving average over `window` points.
pub fn moving_average(points: &[(f64, f64)], window: usize) -> Vec<(f64, f64)> {
    let window = window.max(1);
    let mut sum = 0.0;
    let mut out = Vec::with_capacity(points.len());
    for (i, &(x, y)) in points.iter().enumerate() {
        sum += y;
        if i >= window {
            sum -= points[i - window].1;
        }
        out.push((x, sum / (i + 1).min(window) as f64));
    }
    out
}

/// The curves of a run's logs: per-step training loss and EPE, validation EPE.
struct RunCurves {
    loss: Vec<(f64, f64)>,
    epe: Vec<(f64, f64)>,
    val: Vec<(f64, f64)>,
}

impl RunCurves {
    fn read(run: &Path) -> Result<Self> {
        let train_log = run.join("train_log.csv");
        let mut cols = read_columns(&train_log, &["loss", "epe"])?.into_iter();
        let (loss, epe) = (
            cols.next().unwrap_or_default(),
            cols.next().unwrap_or_default(),
        );
        if loss.is_empty() {
            bail!("{} has no finite loss rows yet", train_log.display());
        }
        let val = match run.join("val_log.csv") {
            p if p.is_file() => read_columns(&p, &["epe"])?.remove(0),
            _ => Vec::new(),
        };
        Ok(Self { loss, epe, val })
    }

    /// The last logged step (at least 1): the x range of both charts.
    fn last_step(&self) -> f64 {
        self.loss.last().map_or(1.0, |p| p.0).max(1.0)
    }
}

type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;

/// A line's legend entry: a short stroke in its colour.
fn legend_mark(colour: RGBColor) -> impl Fn((i32, i32)) -> PathElement<(i32, i32)> {
    move |(x, y)| PathElement::new([(x, y), (x + 18, y)], colour)
}

/// The chart's legend: its series' labels in a framed box.
fn draw_legend<'a, 'b: 'a, CT: plotters::coord::CoordTranslate>(
    chart: &mut ChartContext<'a, BitMapBackend<'b>, CT>,
) -> Result<()> {
    chart
        .configure_series_labels()
        .border_style(BLACK)
        .background_style(WHITE.mix(0.8))
        .draw()
        .map_err(err)
}

/// The training loss per step and its moving average, on a log axis.
fn draw_loss(area: &Area, curves: &RunCurves, smooth: usize) -> Result<()> {
    let loss = &curves.loss;
    let (lo, hi) = loss
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
    let mut chart = ChartBuilder::on(area)
        .caption("training loss", ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(
            0.0..curves.last_step(),
            (lo.max(1e-6) * 0.9..hi * 1.1).log_scale(),
        )
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("step")
        .y_desc("sequence loss")
        .draw()
        .map_err(err)?;
    let (raw, averaged) = (RGBColor(170, 190, 230), RGBColor(31, 119, 180));
    chart
        .draw_series(LineSeries::new(loss.iter().copied(), raw.stroke_width(1)))
        .map_err(err)?
        .label("per step")
        .legend(legend_mark(raw));
    chart
        .draw_series(LineSeries::new(
            moving_average(loss, smooth),
            averaged.stroke_width(2),
        ))
        .map_err(err)?
        .label(format!("moving average ({smooth})"))
        .legend(legend_mark(averaged));
    draw_legend(&mut chart)
}

/// The training EPE (moving average) and the validation EPE.
fn draw_epe(area: &Area, curves: &RunCurves, smooth: usize) -> Result<()> {
    let (epe, val) = (&curves.epe, &curves.val);
    let e_hi = epe
        .iter()
        .chain(val)
        .fold(0.0f64, |a, p| a.max(p.1))
        .max(1e-3);
    let mut chart = ChartBuilder::on(area)
        .caption("end-point error (px)", ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..curves.last_step(), 0.0..e_hi * 1.05)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("step")
        .y_desc("EPE")
        .draw()
        .map_err(err)?;
    let (training, validation) = (RGBColor(255, 127, 14), RGBColor(44, 160, 44));
    chart
        .draw_series(LineSeries::new(
            moving_average(epe, smooth),
            training.stroke_width(2),
        ))
        .map_err(err)?
        .label("training crops (moving average)")
        .legend(legend_mark(training));
    if !val.is_empty() {
        chart
            .draw_series(LineSeries::new(
                val.iter().copied(),
                validation.stroke_width(2),
            ))
            .map_err(err)?
            .label("validation (full images)")
            .legend(legend_mark(validation));
        chart
            .draw_series(val.iter().map(|&p| Circle::new(p, 4, validation.filled())))
            .map_err(err)?;
    }
    draw_legend(&mut chart)
}

/// Writes a drawn RGB buffer as a PNG.
fn write_rgb_png(out: &Path, buf: Vec<u8>, w: u32, h: u32) -> Result<()> {
    stereo_io::write_png(out, &stereo_io::Image::rgb8(w as usize, h as usize, buf))?;
    Ok(())
}

/// Draws a run's loss and EPE curves side by side into a PNG.
pub fn plot_run(run: &Path, out: &Path, smooth: usize) -> Result<()> {
    let curves = RunCurves::read(run)?;
    register();
    let (w, h) = (1200u32, 480u32);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let (left, right) = root.split_horizontally(w / 2);
        draw_loss(&left, &curves, smooth)?;
        draw_epe(&right, &curves, smooth)?;
        root.present().map_err(err)?;
    }
    write_rgb_png(out, buf, w, h)
}

/// EPE against the disturbance level, one panel per kind (`crestereo eval --disturb`); level 0
/// is the undisturbed evaluation, `baseline_epe`.
pub fn plot_disturbance(
    rows: &[crate::disturb::DisturbedResult],
    baseline_epe: Option<f64>,
    out: &Path,
) -> Result<()> {
    let mut kinds: Vec<crate::disturb::DisturbKind> = Vec::new();
    for r in rows {
        if !kinds.contains(&r.kind) {
            kinds.push(r.kind);
        }
    }
    if kinds.is_empty() {
        bail!("no disturbance was evaluated");
    }
    register();
    let columns = kinds.len().min(3);
    let lines = kinds.len().div_ceil(columns);
    let (w, h) = (420 * columns as u32, 340 * lines as u32);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let panels = root.split_evenly((lines, columns));
        let pixels = crate::disturb::headline_pixels(rows);
        for (kind, area) in kinds.iter().zip(&panels) {
            let mut points: Vec<(f64, f64)> = baseline_epe.map(|e| (0.0, e)).into_iter().collect();
            points.extend(
                rows.iter()
                    .filter(|r| r.kind == *kind && (r.level > 0.0 || baseline_epe.is_none()))
                    .filter_map(|r| r.headline().map(|(_, m)| (r.level, m.epe))),
            );
            points.sort_by(|a, b| a.0.total_cmp(&b.0));
            let x_hi = points.iter().fold(0.0f64, |a, p| a.max(p.0)).max(1e-3);
            let y_hi = points.iter().fold(0.0f64, |a, p| a.max(p.1)).max(1e-3);
            let unit = rows.iter().find(|r| r.kind == *kind).map_or("", |r| r.unit);
            let mut chart = ChartBuilder::on(area)
                .caption(kind.name(), ("sans-serif", 20))
                .margin(10)
                .x_label_area_size(36)
                .y_label_area_size(50)
                .build_cartesian_2d(0.0..x_hi * 1.05, 0.0..y_hi * 1.1)
                .map_err(err)?;
            chart
                .configure_mesh()
                .x_desc(format!("level ({unit})"))
                .y_desc(format!("EPE, {pixels} (px)"))
                .draw()
                .map_err(err)?;
            let colour = RGBColor(31, 119, 180);
            chart
                .draw_series(LineSeries::new(
                    points.iter().copied(),
                    colour.stroke_width(2),
                ))
                .map_err(err)?;
            chart
                .draw_series(points.iter().map(|&p| Circle::new(p, 4, colour.filled())))
                .map_err(err)?;
        }
        root.present().map_err(err)?;
    }
    write_rgb_png(out, buf, w, h)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moving_average_is_trailing() {
        let p: Vec<(f64, f64)> = (0..5).map(|i| (i as f64, i as f64)).collect();
        let m = moving_average(&p, 2);
        assert_eq!(
            m.iter().map(|p| p.1).collect::<Vec<_>>(),
            [0.0, 0.5, 1.5, 2.5, 3.5]
        );
    }

    #[test]
    fn plots_a_log() {
        let dir = tempfile::tempdir().unwrap();
        let mut csv =
            String::from("step,samples,lr,loss,epe,samples_per_s,elapsed_s,skipped_steps\n");
        for s in 1..=50 {
            csv.push_str(&format!(
                "{s},{},{},{},{},1,1,0\n",
                2 * s,
                4e-4,
                10.0 / s as f64,
                5.0 / s as f64
            ));
        }
        csv.push_str("51,102,4e-4,NaN,NaN,1,1,1\n");
        std::fs::write(dir.path().join("train_log.csv"), csv).unwrap();
        std::fs::write(
            dir.path().join("val_log.csv"),
            "step,images,epe\n25,4,2.0\n50,4,1.0\n",
        )
        .unwrap();
        let out = dir.path().join("loss.png");
        plot_run(dir.path(), &out, 5).unwrap();
        let img = stereo_io::read_image(&out).unwrap();
        assert_eq!((img.width, img.height), (1200, 480));
        assert!(plot_run(tempfile::tempdir().unwrap().path(), &out, 5).is_err());
    }
}
