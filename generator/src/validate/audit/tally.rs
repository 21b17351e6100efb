//! What the audit counts, per sample, per category and overall: accumulators that merge, and the
//! worst pixels with where they are.

use serde::{Deserialize, Serialize};

/// Tolerance of the strict comparison (px): ray-cast and rendered disparity agree within it.
pub const TIGHT_PX: f64 = 0.01;
/// Tolerance of the loose comparison (px).
pub const LOOSE_PX: f64 = 0.5;
/// Left–right consistency tolerances (px): bilinear sampling of the other view's map on a curved
/// surface alone errs by a few hundredths of a pixel.
pub const LR_TIGHT_PX: f64 = 0.1;
pub const LR_LOOSE_PX: f64 = 1.0;
/// `error_decades[k]` counts errors in [1e(k-8), 1e(k-7)) px; the first bin also holds exact
/// zeros, the last everything from 10 px up.
pub const ERROR_DECADES: usize = 10;
/// Lower edge of the second decade bin (px).
pub const FIRST_DECADE_PX: f64 = 1e-7;

/// Counts of one group of audited pixels (both views).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Tally {
    /// Pixels audited.
    pub pixels: u64,
    /// Pixels at a silhouette or on a grazing surface: rays around the centre meet different
    /// surfaces (or none), or the disparity changes too fast there. Counted apart.
    pub silhouette: u64,
    /// Silhouette pixels whose value matches none of the surfaces the rays around the centre meet.
    pub silhouette_disagree: u64,
    /// Non-silhouette pixels: the ones the bars apply to.
    pub interior: u64,
    /// Interior pixels whose validity and value agree with ray casting within 0.01 px.
    pub interior_within_0_01: u64,
    /// ... within 0.5 px.
    pub interior_within_0_5: u64,
    /// Interior pixels where the map says valid and ray casting sees background, or the reverse.
    pub validity_mismatch: u64,
    /// Pixels whose value lies between surfaces seen around them, on none of them.
    pub flying: u64,
    /// Largest interior error (px), validity mismatches counted by the value of the valid side.
    pub max_error: f64,
    /// Interior |error| by decade (see [`ERROR_DECADES`]).
    pub error_decades: Vec<u64>,
    /// Left pixels (interior, valid, visible from the right camera, same surface at both right
    /// neighbours) checked against the right map at x − d.
    pub lr_checked: u64,
    pub lr_within_0_1: u64,
    pub lr_within_1: u64,
    pub lr_max: f64,
}

impl Default for Tally {
    fn default() -> Self {
        Self {
            pixels: 0,
            silhouette: 0,
            silhouette_disagree: 0,
            interior: 0,
            interior_within_0_01: 0,
            interior_within_0_5: 0,
            validity_mismatch: 0,
            flying: 0,
            max_error: 0.0,
            error_decades: vec![0; ERROR_DECADES],
            lr_checked: 0,
            lr_within_0_1: 0,
            lr_within_1: 0,
            lr_max: 0.0,
        }
    }
}

fn share(a: u64, b: u64) -> Option<f64> {
    (b > 0).then(|| a as f64 / b as f64)
}

impl Tally {
    pub fn merge(&mut self, o: &Tally) {
        self.pixels += o.pixels;
        self.silhouette += o.silhouette;
        self.silhouette_disagree += o.silhouette_disagree;
        self.interior += o.interior;
        self.interior_within_0_01 += o.interior_within_0_01;
        self.interior_within_0_5 += o.interior_within_0_5;
        self.validity_mismatch += o.validity_mismatch;
        self.flying += o.flying;
        self.max_error = self.max_error.max(o.max_error);
        for (a, b) in self.error_decades.iter_mut().zip(&o.error_decades) {
            *a += b;
        }
        self.lr_checked += o.lr_checked;
        self.lr_within_0_1 += o.lr_within_0_1;
        self.lr_within_1 += o.lr_within_1;
        self.lr_max = self.lr_max.max(o.lr_max);
    }

    /// Counts one interior pixel's error.
    pub fn add_interior(&mut self, error: f64, validity_mismatch: bool) {
        self.interior += 1;
        self.interior_within_0_01 += u64::from(!validity_mismatch && error <= TIGHT_PX);
        self.interior_within_0_5 += u64::from(!validity_mismatch && error <= LOOSE_PX);
        self.validity_mismatch += u64::from(validity_mismatch);
        self.max_error = self.max_error.max(error);
        let bin = if error < FIRST_DECADE_PX {
            0
        } else {
            ((error / FIRST_DECADE_PX).log10().floor() as usize + 1).min(ERROR_DECADES - 1)
        };
        self.error_decades[bin] += 1;
    }

    pub fn add_lr(&mut self, error: f64) {
        self.lr_checked += 1;
        self.lr_within_0_1 += u64::from(error <= LR_TIGHT_PX);
        self.lr_within_1 += u64::from(error <= LR_LOOSE_PX);
        self.lr_max = self.lr_max.max(error);
    }

    /// Share of interior pixels within 0.01 px (`None` without interior pixels).
    pub fn share_within_0_01(&self) -> Option<f64> {
        share(self.interior_within_0_01, self.interior)
    }

    pub fn share_within_0_5(&self) -> Option<f64> {
        share(self.interior_within_0_5, self.interior)
    }

    pub fn silhouette_share(&self) -> Option<f64> {
        share(self.silhouette, self.pixels)
    }

    pub fn lr_share_within_0_1(&self) -> Option<f64> {
        share(self.lr_within_0_1, self.lr_checked)
    }
}

/// What is wrong with one pixel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum IssueKind {
    /// An interior pixel off by more than 0.01 px.
    Value,
    /// An interior pixel valid where ray casting sees background, or the reverse.
    Validity,
    /// A value between the surfaces around the pixel (a blended depth edge).
    Flying,
}

/// One bad pixel, where it is and by how much.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PixelIssue {
    pub sample: String,
    pub category: String,
    pub view: String,
    pub x: usize,
    pub y: usize,
    pub kind: IssueKind,
    /// The map's value (`None`: invalid).
    pub rendered: Option<f32>,
    /// Ray casting's disparity at the pixel centre (`None`: background).
    pub expected: Option<f64>,
    pub error: f64,
}

/// Relative depth error tolerated: |file − ray cast| ≤ 1e-4 · ray-cast depth.
pub const DEPTH_RELATIVE: f64 = 1e-4;
/// Angle (degrees) tolerated between a normal map's normal and ray casting's.
pub const NORMAL_DEGREES: f64 = 0.5;

/// Counts of one per-pixel map (depth, normals, instance or semantic) over a group of audited
/// pixels (both views). Errors: relative for depth, degrees for normals, 1 for a wrong id.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MapTally {
    /// Pixels audited.
    pub pixels: u64,
    /// Pixels at a silhouette: rays 0.02 px around the centre meet other objects (or none), or
    /// (depth and normals) the surface is grazing, as for the disparity. Counted apart.
    pub silhouette: u64,
    /// Normals only: checked pixels on one object whose rays around the centre see normals
    /// more than 0.5° apart (a flat-shaded edge, or a surface curving that fast); they are
    /// compared with the nearest of those normals.
    #[serde(default)]
    pub crease: u64,
    /// Silhouette pixels whose value matches none of the surfaces the rays around the centre
    /// meet.
    pub edge_disagree: u64,
    /// The other pixels: the ones the bar applies to.
    pub checked: u64,
    /// Checked pixels whose validity agrees with ray casting and whose value is within bounds.
    pub in_bounds: u64,
    /// Checked pixels with a surface in the map where ray casting sees none, or the reverse.
    pub validity_mismatch: u64,
    /// Largest error over the checked pixels of equal validity.
    pub max_error: f64,
}

impl MapTally {
    pub fn merge(&mut self, o: &MapTally) {
        self.pixels += o.pixels;
        self.silhouette += o.silhouette;
        self.crease += o.crease;
        self.edge_disagree += o.edge_disagree;
        self.checked += o.checked;
        self.in_bounds += o.in_bounds;
        self.validity_mismatch += o.validity_mismatch;
        self.max_error = self.max_error.max(o.max_error);
    }

    /// Share of checked pixels within bounds (`None` without checked pixels).
    pub fn share_in_bounds(&self) -> Option<f64> {
        share(self.in_bounds, self.checked)
    }
}

/// One pixel of a map out of bounds (or the worst of a sound sample), and where it is.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MapIssue {
    pub map: String,
    pub sample: String,
    pub category: String,
    pub view: String,
    pub x: usize,
    pub y: usize,
    /// The map's value (depth; normal x, y, z; id), empty where the map says no surface.
    pub rendered: Vec<f64>,
    /// Ray casting's value at the pixel centre, empty for background.
    pub expected: Vec<f64>,
    /// Relative depth error, angle in degrees, 1 for a wrong id or a validity mismatch.
    pub error: f64,
    /// Whether the pixel is out of bounds (worst lists also keep the largest sound errors).
    pub out_of_bounds: bool,
}

/// Keeps the `n` most telling issues of each map: out of bounds first, then by error.
pub fn keep_worst_maps(issues: &mut Vec<MapIssue>, n: usize) {
    issues.sort_by(|a, b| {
        b.out_of_bounds
            .cmp(&a.out_of_bounds)
            .then(b.error.total_cmp(&a.error))
            .then_with(|| {
                (&a.map, &a.sample, &a.view, a.y, a.x).cmp(&(&b.map, &b.sample, &b.view, b.y, b.x))
            })
    });
    let mut kept: Vec<(String, usize)> = Vec::new();
    issues.retain(|i| match kept.iter_mut().find(|(m, _)| *m == i.map) {
        Some((_, k)) => {
            *k += 1;
            *k <= n
        }
        None => {
            kept.push((i.map.clone(), 1));
            n > 0
        }
    });
}

/// Keeps the `n` largest issues (by error; ties by position so the choice is deterministic).
pub fn keep_worst(issues: &mut Vec<PixelIssue>, n: usize) {
    issues.sort_by(|a, b| {
        b.error
            .total_cmp(&a.error)
            .then_with(|| (&a.sample, &a.view, a.y, a.x).cmp(&(&b.sample, &b.view, b.y, b.x)))
    });
    issues.truncate(n);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interior_errors_fall_in_their_bins_and_merge() {
        let mut t = Tally::default();
        t.add_interior(0.0, false);
        t.add_interior(5e-6, false);
        t.add_interior(0.02, false);
        t.add_interior(3.0, true);
        assert_eq!(
            (
                t.interior,
                t.interior_within_0_01,
                t.interior_within_0_5,
                t.validity_mismatch
            ),
            (4, 2, 3, 1)
        );
        assert_eq!(t.error_decades, vec![1, 0, 1, 0, 0, 0, 1, 0, 1, 0]);
        assert_eq!(t.max_error, 3.0);
        let mut twice = t.clone();
        twice.merge(&t);
        assert_eq!(twice.interior, 8);
        assert_eq!(twice.share_within_0_01(), Some(0.5));
    }
}
