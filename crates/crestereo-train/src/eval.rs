//! Evaluation of a model on any dataset stereo-io reads: per-image metrics on all valid pixels
//! and on non-occluded ones, foreground mxIoU where masks are given, means over images, and the
//! JSON / CSV / table outputs of `crestereo eval`.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use burn::prelude::*;
use crestereo::BgrImage;
use crestereo::{CREStereo, InferenceOptions, infer_disparity};
use serde::Serialize;
use stereo_io::{StereoDataset, StereoSample};

use crate::disturb::{Disturbance, DisturbedResult};
use crate::metrics::{
    CSV_METRICS, DisparityMetrics, boundary_band, disparity_metrics, max_iou, metric_values,
};

#[derive(Debug, Clone, Serialize)]
pub struct EvalOptions {
    /// Refinement iterations per pass (reference test: 20).
    pub iters: usize,
    /// Stacked cascades (reference test: 2).
    pub stages: usize,
    /// At most this many samples (0 = all).
    pub limit: usize,
    /// Foreground masks `<dir>/<sample id>.png` (non-zero = foreground) for mxIoU / mxIoUbd.
    pub fg_masks: Option<PathBuf>,
    /// Boundary band half-width of mxIoUbd (the paper: p = 4).
    pub boundary_px: usize,
    /// Left-right consistency tolerance (px) that defines non-occluded pixels on datasets that
    /// ship both disparity maps but no occlusion mask (ours, CREStereo's release, SceneFlow).
    pub lr_tolerance_px: f32,
    /// A disturbance of the right view (`crestereo eval --disturb`); none for a plain evaluation.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub disturbance: Option<Disturbance>,
}

impl EvalOptions {
    /// How many samples of a dataset of `len` are evaluated (`limit`, 0 = all).
    pub fn count(&self, len: usize) -> usize {
        if self.limit > 0 {
            len.min(self.limit)
        } else {
            len
        }
    }
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            iters: 20,
            stages: 2,
            limit: 0,
            fg_masks: None,
            boundary_px: 4,
            lr_tolerance_px: stereo_io::LEFT_RIGHT_TOLERANCE_PX,
            disturbance: None,
        }
    }
}

/// Where the non-occluded mask of an image came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum NonOccSource {
    /// The dataset's own mask (Middlebury/ETH3D `mask0nocc`, KITTI `disp_noc`, Sintel).
    Dataset,
    /// Left-right consistency of the two ground-truth maps.
    LeftRightCheck,
}

#[derive(Debug, Clone, Serialize)]
pub struct ImageResult {
    pub id: String,
    pub width: usize,
    pub height: usize,
    pub seconds: f64,
    pub all: Option<DisparityMetrics>,
    pub nonocc: Option<DisparityMetrics>,
    pub nonocc_source: Option<NonOccSource>,
    pub mxiou: Option<f64>,
    pub mxiou_bd: Option<f64>,
}

#[derive(Debug, Clone, Serialize)]
pub struct FailedImage {
    pub id: String,
    pub error: String,
}

/// Means over images (each image weighs the same, as the benchmarks average).
#[derive(Debug, Clone, Serialize)]
pub struct EvalReport {
    pub dataset: String,
    pub format: String,
    pub weights: String,
    pub options: EvalOptions,
    pub images: usize,
    pub mean_all: Option<DisparityMetrics>,
    pub mean_nonocc: Option<DisparityMetrics>,
    pub mean_mxiou: Option<f64>,
    pub mean_mxiou_bd: Option<f64>,
    pub seconds_per_image: f64,
    pub failed: Vec<FailedImage>,
    pub per_image: Vec<ImageResult>,
    /// `--disturb`: the same evaluation with the right view disturbed, per kind and level.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub disturbed: Vec<DisturbedResult>,
}

/// The non-occluded pixels of a sample's left view and where that mask came from.
#[derive(Debug, Clone, PartialEq)]
pub struct NonOccMask {
    pub mask: Vec<bool>,
    pub source: NonOccSource,
}

/// Non-occluded pixels: the dataset's mask, else the left-right check when a right-view map
/// exists, else `None`.
pub fn nonocc_mask(sample: &StereoSample, tolerance: f32) -> Option<NonOccMask> {
    if let Some(m) = &sample.valid_left {
        return Some(NonOccMask {
            mask: m.clone(),
            source: NonOccSource::Dataset,
        });
    }
    let right = sample.disp_right.as_ref()?;
    let mask = sample.disp_left.left_right_consistent(right, tolerance);
    Some(NonOccMask {
        mask,
        source: NonOccSource::LeftRightCheck,
    })
}

fn foreground(dir: &Path, id: &str, width: usize, height: usize) -> Result<Vec<bool>> {
    let path = dir.join(format!("{id}.png"));
    let img = stereo_io::read_image(&path)?;
    if (img.width, img.height) != (width, height) {
        bail!(
            "foreground mask {} is {}x{}, the image {}x{}",
            path.display(),
            img.width,
            img.height,
            width,
            height
        );
    }
    // Non-zero in the first channel = foreground.
    let c = img.channels;
    Ok(match &img.samples {
        stereo_io::Samples::U8(v) => v.chunks(c).map(|px| px[0] > 0).collect(),
        stereo_io::Samples::U16(v) => v.chunks(c).map(|px| px[0] > 0).collect(),
    })
}

/// Evaluates one decoded sample.
pub fn evaluate_sample<B: Backend>(
    model: &CREStereo<B>,
    sample: &StereoSample,
    id: &str,
    opts: &EvalOptions,
    device: &B::Device,
) -> Result<ImageResult> {
    let t0 = Instant::now();
    let mut right = BgrImage::from_rgb(&sample.right);
    if let Some(d) = &opts.disturbance {
        right = d.apply(&right, id);
    }
    let pred = infer_disparity(
        model,
        &BgrImage::from_rgb(&sample.left),
        &right,
        InferenceOptions {
            iters: opts.iters,
            stages: opts.stages,
        },
        device,
    )?;
    let seconds = t0.elapsed().as_secs_f64();
    let truth = &sample.disp_left;
    let all = disparity_metrics(&pred.data, &truth.data, &truth.valid);
    let nonocc_mask = nonocc_mask(sample, opts.lr_tolerance_px);
    let nonocc = nonocc_mask.as_ref().and_then(|n| {
        let m: Vec<bool> = n
            .mask
            .iter()
            .zip(&truth.valid)
            .map(|(a, b)| *a && *b)
            .collect();
        disparity_metrics(&pred.data, &truth.data, &m)
    });
    let nonocc_source = nonocc_mask.map(|n| n.source);
    let (mut mxiou, mut mxiou_bd) = (None, None);
    if let Some(dir) = &opts.fg_masks {
        let fg = foreground(dir, id, truth.width, truth.height)?;
        mxiou = max_iou(&pred.data, &fg, &vec![true; fg.len()]);
        let band = boundary_band(&fg, truth.width, truth.height, opts.boundary_px);
        mxiou_bd = max_iou(&pred.data, &fg, &band);
    }
    Ok(ImageResult {
        id: id.to_string(),
        width: truth.width,
        height: truth.height,
        seconds,
        all,
        nonocc,
        nonocc_source,
        mxiou,
        mxiou_bd,
    })
}

/// The mean of each metric over images; `count` is the total of pixels.
pub fn mean_metrics(ms: &[DisparityMetrics]) -> Option<DisparityMetrics> {
    if ms.is_empty() {
        return None;
    }
    let n = ms.len() as f64;
    let avg = |f: fn(&DisparityMetrics) -> f64| ms.iter().map(f).sum::<f64>() / n;
    Some(DisparityMetrics {
        count: ms.iter().map(|m| m.count).sum(),
        epe: avg(|m| m.epe),
        rms: avg(|m| m.rms),
        bad_0_5: avg(|m| m.bad_0_5),
        bad_1: avg(|m| m.bad_1),
        bad_2: avg(|m| m.bad_2),
        bad_3: avg(|m| m.bad_3),
        d1: avg(|m| m.d1),
        a50: avg(|m| m.a50),
        a90: avg(|m| m.a90),
        a95: avg(|m| m.a95),
        a99: avg(|m| m.a99),
    })
}

fn mean(xs: impl Iterator<Item = f64>) -> Option<f64> {
    let v: Vec<f64> = xs.collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// Evaluates a dataset. An unreadable sample is reported in `failed` and the rest continue.
pub fn evaluate<B: Backend>(
    model: &CREStereo<B>,
    dataset: &dyn StereoDataset,
    weights: &str,
    opts: &EvalOptions,
    device: &B::Device,
    mut progress: impl FnMut(usize, usize, &ImageResult),
) -> Result<EvalReport> {
    let n = opts.count(dataset.len());
    let mut per_image = Vec::new();
    let mut failed = Vec::new();
    for i in 0..n {
        let id = dataset.id(i).unwrap_or("?").to_string();
        let result = dataset
            .sample(i)
            .map_err(anyhow::Error::from)
            .and_then(|s| evaluate_sample(model, &s, &id, opts, device));
        match result {
            Ok(r) => {
                progress(i + 1, n, &r);
                per_image.push(r);
            }
            Err(e) => {
                tracing::warn!("evaluation skips {id}: {e:#}");
                failed.push(FailedImage {
                    id,
                    error: format!("{e:#}"),
                });
            }
        }
    }
    Ok(EvalReport::summarise(
        dataset, weights, opts, per_image, failed,
    ))
}

fn opt(v: Option<f64>) -> String {
    v.map(|x| format!("{x:.6}")).unwrap_or_default()
}

impl EvalReport {
    /// The report of `per_image` results: means over images.
    fn summarise(
        dataset: &dyn StereoDataset,
        weights: &str,
        opts: &EvalOptions,
        per_image: Vec<ImageResult>,
        failed: Vec<FailedImage>,
    ) -> Self {
        let alls: Vec<_> = per_image.iter().filter_map(|r| r.all).collect();
        let noccs: Vec<_> = per_image.iter().filter_map(|r| r.nonocc).collect();
        Self {
            dataset: dataset.root().display().to_string(),
            format: dataset.format().to_string(),
            weights: weights.to_string(),
            options: opts.clone(),
            images: per_image.len(),
            mean_all: mean_metrics(&alls),
            mean_nonocc: mean_metrics(&noccs),
            mean_mxiou: mean(per_image.iter().filter_map(|r| r.mxiou)),
            mean_mxiou_bd: mean(per_image.iter().filter_map(|r| r.mxiou_bd)),
            seconds_per_image: mean(per_image.iter().map(|r| r.seconds)).unwrap_or(0.0),
            failed,
            per_image,
            disturbed: Vec::new(),
        }
    }

    /// This (disturbed) evaluation as one row of a robustness report.
    pub fn disturbed_row(&self) -> Option<DisturbedResult> {
        let d = self.options.disturbance?;
        Some(DisturbedResult {
            kind: d.kind,
            level: d.level,
            unit: d.kind.unit(),
            seed: d.seed,
            images: self.images,
            failed: self.failed.len(),
            mean_all: self.mean_all,
            mean_nonocc: self.mean_nonocc,
            seconds_per_image: self.seconds_per_image,
        })
    }

    /// One row per image: id, size, seconds, the metrics on all pixels, on non-occluded pixels
    /// (empty where unavailable), mxIoU and mxIoUbd.
    pub fn per_image_csv(&self) -> String {
        let mut s = String::from("id,width,height,seconds,valid_px");
        for m in CSV_METRICS {
            write!(s, ",{m}").unwrap();
        }
        s.push_str(",nonocc_px");
        for m in CSV_METRICS {
            write!(s, ",nonocc_{m}").unwrap();
        }
        s.push_str(",mxiou,mxiou_bd\n");
        for r in &self.per_image {
            write!(
                s,
                "{},{},{},{:.3}",
                csv_field(&r.id),
                r.width,
                r.height,
                r.seconds
            )
            .unwrap();
            for m in [&r.all, &r.nonocc] {
                match m {
                    Some(m) => {
                        write!(s, ",{}", m.count).unwrap();
                        for v in metric_values(m) {
                            write!(s, ",{v:.6}").unwrap();
                        }
                    }
                    None => s.push_str(&",".repeat(1 + CSV_METRICS.len())),
                }
            }
            writeln!(s, ",{},{}", opt(r.mxiou), opt(r.mxiou_bd)).unwrap();
        }
        s
    }

    /// The human-readable summary `crestereo eval` prints.
    pub fn table(&self) -> String {
        let mut s = String::new();
        writeln!(
            s,
            "{} ({}), {} images, weights {}",
            self.dataset, self.format, self.images, self.weights
        )
        .unwrap();
        if !self.failed.is_empty() {
            writeln!(
                s,
                "{} images could not be evaluated (see the JSON)",
                self.failed.len()
            )
            .unwrap();
        }
        self.write_metric_rows(&mut s);
        if let Some(v) = self.mean_mxiou {
            writeln!(s, "{:<14}{v:>12.4}", "mxIoU").unwrap();
        }
        if let Some(v) = self.mean_mxiou_bd {
            writeln!(
                s,
                "{:<14}{v:>12.4}",
                format!("mxIoUbd (p={})", self.options.boundary_px)
            )
            .unwrap();
        }
        writeln!(s, "{:<14}{:>12.3}", "s / image", self.seconds_per_image).unwrap();
        s
    }

    /// The disparity metrics as rows, one column for all pixels and one for non-occluded ones
    /// where available.
    fn write_metric_rows(&self, s: &mut String) {
        let cols = [("all", &self.mean_all), ("non-occ", &self.mean_nonocc)];
        write!(s, "{:<14}", "metric").unwrap();
        for (name, m) in cols {
            if m.is_some() {
                write!(s, "{name:>12}").unwrap();
            }
        }
        s.push('\n');
        let labels = [
            "EPE (AvgErr)",
            "RMS",
            "Bad-0.5 %",
            "Bad-1 %",
            "Bad-2 %",
            "Bad-3 %",
            "D1 %",
            "A50",
            "A90",
            "A95",
            "A99",
        ];
        for (k, label) in labels.iter().enumerate() {
            write!(s, "{label:<14}").unwrap();
            for (_, m) in cols {
                if let Some(m) = m {
                    write!(s, "{:>12.4}", metric_values(m)[k]).unwrap();
                }
            }
            s.push('\n');
        }
    }

    /// Writes `<out>.json` style outputs: the full report as JSON and the per-image CSV.
    pub fn write(&self, json: &Path, csv: &Path) -> Result<()> {
        let text = serde_json::to_vec_pretty(self)?;
        stereo_io::write_bytes_atomically(json, &text)
            .with_context(|| format!("cannot write {}", json.display()))?;
        stereo_io::write_bytes_atomically(csv, self.per_image_csv().as_bytes())
            .with_context(|| format!("cannot write {}", csv.display()))?;
        Ok(())
    }
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereo_io::{DisparityMap, RgbImage, SampleMeta};

    fn sample(left: &[f32], right: Option<&[f32]>, w: usize) -> StereoSample {
        let map = |d: &[f32]| DisparityMap {
            width: w,
            height: 1,
            data: d.to_vec(),
            valid: d.iter().map(|v| *v > 0.0).collect(),
        };
        let img = RgbImage {
            width: w,
            height: 1,
            data: vec![0; 3 * w],
        };
        StereoSample {
            left: img.clone(),
            right: img,
            disp_left: map(left),
            disp_right: right.map(map),
            valid_left: None,
            meta: SampleMeta::default(),
        }
    }

    #[test]
    fn left_right_check_marks_occlusions() {
        // A foreground strip (d = 2) at x = 4..6 in front of a background at d = 1. In the right
        // view the strip moves to 2..4 and hides the background seen by left pixels 3 and 4.
        let left = [0.0, 1.0, 1.0, 1.0, 2.0, 2.0, 1.0, 1.0];
        let right = [1.0, 1.0, 2.0, 2.0, 1.0, 1.0, 1.0, 1.0];
        let NonOccMask { mask, source } =
            nonocc_mask(&sample(&left, Some(&right), 8), 0.5).unwrap();
        assert_eq!(source, NonOccSource::LeftRightCheck);
        // x=0 invalid; x=1 → 0 ok; x=2 → 1 ok; x=3 → 2 (d 2 ≠ 1) occluded; x=4,5 → 2,3 ok;
        // x=6 → 5 ok; x=7 → 6 ok.
        assert_eq!(mask, [false, true, true, false, true, true, true, true]);
        assert!(nonocc_mask(&sample(&left, None, 8), 0.5).is_none());
        let mut s = sample(&left, Some(&right), 8);
        s.valid_left = Some(vec![true; 8]);
        assert_eq!(nonocc_mask(&s, 0.5).unwrap().source, NonOccSource::Dataset);
    }

    #[test]
    fn means_are_per_image_and_csv_has_a_row_each() {
        let a = disparity_metrics(&[1.0, 2.0], &[1.0, 1.0], &[true, true]).unwrap();
        let b = disparity_metrics(&[3.0], &[1.0], &[true]).unwrap();
        let m = mean_metrics(&[a, b]).unwrap();
        assert_eq!(m.count, 3);
        assert!((m.epe - (0.5 + 2.0) / 2.0).abs() < 1e-12);
        assert!((m.bad_1 - (0.0 + 100.0) / 2.0).abs() < 1e-12);
        let r = |id: &str, m| ImageResult {
            id: id.into(),
            width: 2,
            height: 1,
            seconds: 0.1,
            all: Some(m),
            nonocc: None,
            nonocc_source: None,
            mxiou: Some(0.5),
            mxiou_bd: None,
        };
        let report = EvalReport {
            dataset: "d".into(),
            format: "f".into(),
            weights: "w".into(),
            options: EvalOptions::default(),
            images: 2,
            mean_all: Some(m),
            mean_nonocc: None,
            mean_mxiou: Some(0.5),
            mean_mxiou_bd: None,
            seconds_per_image: 0.1,
            failed: vec![],
            per_image: vec![r("a,1", a), r("b", b)],
            disturbed: vec![],
        };
        let csv = report.per_image_csv();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 3);
        let cols = lines[0].split(',').count();
        assert_eq!(lines[2].split(',').count(), cols);
        assert!(lines[1].starts_with("\"a,1\",2,1,"));
        let table = report.table();
        assert!(
            table.contains("EPE (AvgErr)") && table.contains("mxIoU") && !table.contains("non-occ"),
            "{table}"
        );
    }
}
