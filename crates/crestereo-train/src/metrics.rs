//! Stereo error metrics on one image: EPE (AvgErr), RMS, Bad-τ, KITTI D1, error quantiles, and the
//! paper's mxIoU / mxIoUbd for foreground masks (§4.5).
//!
//! Errors are |predicted − true| disparity over the pixels a mask selects (valid, or valid and
//! non-occluded). Percentages are in 0..100.

use serde::Serialize;

/// The metrics of one prediction over one mask.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DisparityMetrics {
    /// Pixels measured.
    pub count: usize,
    /// Mean absolute error (EPE, Middlebury's AvgErr).
    pub epe: f64,
    /// Root mean squared error.
    pub rms: f64,
    /// Percentage of pixels with error above 0.5, 1, 2 and 3 px.
    pub bad_0_5: f64,
    pub bad_1: f64,
    pub bad_2: f64,
    pub bad_3: f64,
    /// KITTI D1: error above 3 px and above 5% of the true disparity.
    pub d1: f64,
    /// Error quantiles (Middlebury's A50 … A99), linear interpolation between ranks.
    pub a50: f64,
    pub a90: f64,
    pub a95: f64,
    pub a99: f64,
}

/// The metric columns of the CSVs (`eval`'s per-image report, `eval --disturb`'s rows), in the
/// order of [`metric_values`].
pub const CSV_METRICS: [&str; 11] = [
    "epe", "rms", "bad_0_5", "bad_1", "bad_2", "bad_3", "d1", "a50", "a90", "a95", "a99",
];

pub fn metric_values(m: &DisparityMetrics) -> [f64; 11] {
    [
        m.epe, m.rms, m.bad_0_5, m.bad_1, m.bad_2, m.bad_3, m.d1, m.a50, m.a90, m.a95, m.a99,
    ]
}

/// The q-quantile of sorted values, interpolating linearly between the closest ranks.
pub fn quantile(sorted: &[f64], q: f64) -> f64 {
    let pos = q.clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let (i, f) = (pos.floor() as usize, pos.fract());
    if i + 1 < sorted.len() {
        sorted[i] * (1.0 - f) + sorted[i + 1] * f
    } else {
        sorted[i]
    }
}

/// Metrics over the pixels where `mask` is true; `None` when it selects none.
/// Panics when the buffers differ in length (a caller bug, not bad data).
pub fn disparity_metrics(pred: &[f32], truth: &[f32], mask: &[bool]) -> Option<DisparityMetrics> {
    assert!(
        pred.len() == truth.len() && truth.len() == mask.len(),
        "prediction, truth and mask differ in size"
    );
    let mut errors = Vec::new();
    let (mut sum, mut sq) = (0.0, 0.0);
    let mut bad = [0usize; 4];
    let mut d1 = 0usize;
    for ((&p, &t), &m) in pred.iter().zip(truth).zip(mask) {
        if !m {
            continue;
        }
        let e = (f64::from(p) - f64::from(t)).abs();
        sum += e;
        sq += e * e;
        for (b, tau) in bad.iter_mut().zip([0.5, 1.0, 2.0, 3.0]) {
            *b += usize::from(e > tau);
        }
        d1 += usize::from(e > 3.0 && e > 0.05 * f64::from(t).abs());
        errors.push(e);
    }
    let n = errors.len();
    if n == 0 {
        return None;
    }
    errors.sort_by(f64::total_cmp);
    let pct = |k: usize| 100.0 * k as f64 / n as f64;
    Some(DisparityMetrics {
        count: n,
        epe: sum / n as f64,
        rms: (sq / n as f64).sqrt(),
        bad_0_5: pct(bad[0]),
        bad_1: pct(bad[1]),
        bad_2: pct(bad[2]),
        bad_3: pct(bad[3]),
        d1: pct(d1),
        a50: quantile(&errors, 0.50),
        a90: quantile(&errors, 0.90),
        a95: quantile(&errors, 0.95),
        a99: quantile(&errors, 0.99),
    })
}

/// Pixels within `p` pixels (Chebyshev distance) of the foreground mask's boundary, where a
/// boundary pixel is a pixel whose 4-neighbour has the other label.
pub fn boundary_band(fg: &[bool], width: usize, height: usize, p: usize) -> Vec<bool> {
    assert_eq!(fg.len(), width * height);
    let at = |x: usize, y: usize| fg[y * width + x];
    let mut band = vec![false; fg.len()];
    for y in 0..height {
        for x in 0..width {
            let here = at(x, y);
            let edge = (x > 0 && at(x - 1, y) != here)
                || (x + 1 < width && at(x + 1, y) != here)
                || (y > 0 && at(x, y - 1) != here)
                || (y + 1 < height && at(x, y + 1) != here);
            if edge {
                for by in y.saturating_sub(p)..=(y + p).min(height - 1) {
                    for bx in x.saturating_sub(p)..=(x + p).min(width - 1) {
                        band[by * width + bx] = true;
                    }
                }
            }
        }
    }
    band
}

/// The paper's mxIoU: the best intersection-over-union between the foreground mask and the
/// predicted mask `disparity > t`, over every threshold t, counted over the pixels `region`
/// selects (all pixels for mxIoU, the boundary band for mxIoUbd). `None` when the region holds
/// no foreground pixel.
pub fn max_iou(pred: &[f32], fg: &[bool], region: &[bool]) -> Option<f64> {
    assert!(pred.len() == fg.len() && fg.len() == region.len());
    // Sweep thresholds from high to low: lowering t past a pixel's value adds it to the mask.
    let mut pixels: Vec<(f32, bool)> = pred
        .iter()
        .zip(fg)
        .zip(region)
        .filter(|(_, r)| **r)
        .map(|((d, f), _)| (*d, *f))
        .collect();
    let fg_total = pixels.iter().filter(|(_, f)| *f).count();
    if fg_total == 0 {
        return None;
    }
    pixels.sort_by(|a, b| b.0.total_cmp(&a.0));
    let (mut inter, mut predicted, mut best) = (0usize, 0usize, 0.0f64);
    let mut i = 0;
    while i < pixels.len() {
        // Pixels with equal disparity enter the mask together.
        let d = pixels[i].0;
        while i < pixels.len() && pixels[i].0 == d {
            predicted += 1;
            inter += usize::from(pixels[i].1);
            i += 1;
        }
        let union = fg_total + predicted - inter;
        best = best.max(inter as f64 / union as f64);
    }
    Some(best)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-12
    }

    #[test]
    fn metrics_match_hand_computation() {
        // Errors over the masked pixels: 0.2, 0.6, 1.5, 2.5, 4.0 (the sixth pixel is masked out).
        let truth = [10.0, 10.0, 10.0, 100.0, 50.0, 7.0];
        let pred = [10.2, 9.4, 11.5, 102.5, 54.0, 0.0];
        let mask = [true, true, true, true, true, false];
        let m = disparity_metrics(&pred, &truth, &mask).unwrap();
        assert_eq!(m.count, 5);
        assert!((m.epe - 8.8 / 5.0).abs() < 1e-6);
        let sq = 0.04 + 0.36 + 2.25 + 6.25 + 16.0;
        assert!((m.rms - (sq / 5.0f64).sqrt()).abs() < 1e-6);
        assert!(
            close(m.bad_0_5, 80.0)
                && close(m.bad_1, 60.0)
                && close(m.bad_2, 40.0)
                && close(m.bad_3, 20.0)
        );
        // 4.0 > 3 and > 5% of 50 = 2.5: one D1 outlier; 2.5 on a truth of 100 is neither.
        assert!(close(m.d1, 20.0));
        // Sorted errors 0.2 0.6 1.5 2.5 4.0: the median is 1.5, A90 at rank 3.6 = 2.5 + 0.6·1.5.
        assert!((m.a50 - 1.5).abs() < 1e-6);
        assert!((m.a90 - 3.4).abs() < 1e-6);
        assert!((m.a99 - (2.5 + 0.96 * 1.5)).abs() < 1e-6);
    }

    #[test]
    fn d1_needs_both_conditions() {
        // Error 4 on truth 100 (4%): not D1. Error 4 on truth 60 (6.7%): D1.
        let m = disparity_metrics(&[104.0, 64.0], &[100.0, 60.0], &[true, true]).unwrap();
        assert!(close(m.d1, 50.0));
        assert!(disparity_metrics(&[1.0], &[1.0], &[false]).is_none());
    }

    #[test]
    fn max_iou_finds_the_best_threshold() {
        // 1×6 image; foreground pixels 1..=3 (10, 12, 9.5), but background pixel 0 (11) sits
        // among them. Sweeping t down: 12 → 1/3, 11 → 1/4, 10 → 2/4, 9.5 → 3/4, 2 → 3/5.
        let pred = [11.0, 10.0, 12.0, 9.5, 2.0, 1.0];
        let fg = [false, true, true, true, false, false];
        let all = [true; 6];
        assert!(close(max_iou(&pred, &fg, &all).unwrap(), 0.75));
        // A perfect prediction reaches 1.
        let pred = [1.0, 10.0, 12.0, 11.0, 2.0, 1.0];
        assert!(close(max_iou(&pred, &fg, &all).unwrap(), 1.0));
        assert!(max_iou(&pred, &[false; 6], &all).is_none());
    }

    #[test]
    fn boundary_band_covers_p_pixels_each_side() {
        // 12×1 image, foreground at x = 6..12: boundary pixels are x = 5 and 6.
        let fg: Vec<bool> = (0..12).map(|x| x >= 6).collect();
        let band = boundary_band(&fg, 12, 1, 2);
        let expected: Vec<bool> = (0..12).map(|x| (3..=8).contains(&x)).collect();
        assert_eq!(band, expected);
    }
}
