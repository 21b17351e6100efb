//! A dense disparity map with its validity mask and camera facts.

/// Horizontal disparity in pixels, row-major from the top-left pixel.
///
/// Convention: `x_right = x_left - d` for the left view, `x_left = x_right + d` for the right
/// view. Pixels where no surface was hit hold `0.0` and `valid == false`.
#[derive(Debug, Clone, PartialEq)]
pub struct DisparityMap {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
    pub valid: Vec<bool>,
}

/// How far (px) a right-view disparity may differ from the left-view one at the matching pixel
/// for [`DisparityMap::left_right_consistent`] to call the pixel seen by both views: `eval`'s
/// non-occluded metrics and the KITTI export's `disp_noc` use the same value.
pub const LEFT_RIGHT_TOLERANCE_PX: f32 = 1.0;

/// Camera facts stored in the EXR header, so a file alone says what its numbers mean.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct DisparityMeta {
    /// Focal length in pixels (horizontal sensor fit).
    pub f_px: Option<f64>,
    /// Stereo baseline in metres.
    pub baseline_m: Option<f64>,
    /// "left" or "right".
    pub view: Option<String>,
}

/// Summary of the valid pixels of a map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DisparityStats {
    pub valid_pixels: usize,
    pub min: f32,
    pub max: f32,
    pub mean: f64,
}

impl DisparityMap {
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            data: vec![0.0; width * height],
            valid: vec![false; width * height],
        }
    }

    /// A map from its pixels' readings in row-major order: `Some(d)` a disparity, `None` no
    /// ground truth (stored as 0).
    pub fn from_readings(
        width: usize,
        height: usize,
        readings: impl IntoIterator<Item = Option<f32>>,
    ) -> Self {
        let (data, valid) = readings
            .into_iter()
            .map(|r| (r.unwrap_or(0.0), r.is_some()))
            .unzip();
        Self {
            width,
            height,
            data,
            valid,
        }
    }

    /// Converts planar camera depth to disparity `d = f_px * B / Z`.
    ///
    /// Depth that is not finite, not positive, or at/after `background_depth` (Cycles writes
    /// 1e10 where a ray hits nothing) becomes disparity 0 and invalid.
    pub fn from_depth(
        width: usize,
        height: usize,
        depth: &[f32],
        f_px: f64,
        baseline_m: f64,
        background_depth: f32,
    ) -> Self {
        assert_eq!(
            depth.len(),
            width * height,
            "depth buffer does not match {width}x{height}"
        );
        let fb = f_px * baseline_m;
        let mut map = Self::new(width, height);
        for (i, &z) in depth.iter().enumerate() {
            if z.is_finite() && z > 0.0 && z < background_depth {
                // f64 keeps the only rounding in the final f32 store.
                map.data[i] = (fb / f64::from(z)) as f32;
                map.valid[i] = true;
            }
        }
        map
    }

    pub fn get(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    pub fn is_valid(&self, x: usize, y: usize) -> bool {
        self.valid[y * self.width + x]
    }

    /// The left-view pixels the right view sees too (non-occluded): a valid left pixel `x`
    /// with disparity `d` whose match `round(x − d)` lies inside the right image and holds a
    /// valid right-view disparity within `tolerance` of `d`. Where the match shows another
    /// surface, the two disparities differ by that surface's depth step. `self` is the
    /// left-view map and `right` the right-view one, of the same size.
    pub fn left_right_consistent(&self, right: &DisparityMap, tolerance: f32) -> Vec<bool> {
        assert_eq!(
            (self.width, self.height),
            (right.width, right.height),
            "left and right disparity maps differ in size"
        );
        let w = self.width;
        let mut seen = vec![false; self.data.len()];
        for (i, keep) in seen.iter_mut().enumerate() {
            if !self.valid[i] {
                continue;
            }
            let d = self.data[i];
            let xr = ((i % w) as f32 - d).round();
            if xr < 0.0 || xr >= w as f32 {
                continue;
            }
            let j = i - i % w + xr as usize;
            *keep = right.valid[j] && (right.data[j] - d).abs() <= tolerance;
        }
        seen
    }

    /// Statistics of the valid pixels, `None` when there are none.
    pub fn stats(&self) -> Option<DisparityStats> {
        let mut n = 0usize;
        let (mut min, mut max, mut sum) = (f32::INFINITY, f32::NEG_INFINITY, 0f64);
        for (&d, &v) in self.data.iter().zip(&self.valid) {
            if v {
                n += 1;
                min = min.min(d);
                max = max.max(d);
                sum += f64::from(d);
            }
        }
        (n > 0).then(|| DisparityStats {
            valid_pixels: n,
            min,
            max,
            mean: sum / n as f64,
        })
    }
}

/// Refuses disparity that holds a NaN, naming the first such pixel: NaN is neither a disparity
/// nor a mark of "no ground truth", so a file holding one is corrupt. `hint` ends the message
/// (how the format marks a missing value, where it has a way).
pub(crate) fn refuse_nan(
    path: &std::path::Path,
    data: &[f32],
    width: usize,
    hint: &str,
) -> crate::error::Result<()> {
    match data.iter().position(|d| d.is_nan()) {
        None => Ok(()),
        Some(i) => Err(crate::error::Error::format(
            path,
            format!(
                "disparity is NaN at pixel ({}, {}); NaN is not accepted{hint}",
                i % width.max(1),
                i / width.max(1)
            ),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_to_disparity_marks_background_invalid() {
        let depth = [2.0f32, 1e10, f32::NAN, 4.0];
        let map = DisparityMap::from_depth(2, 2, &depth, 100.0, 0.1, 1e9);
        assert_eq!(map.data, vec![5.0, 0.0, 0.0, 2.5]);
        assert_eq!(map.valid, vec![true, false, false, true]);
        let s = map.stats().unwrap();
        assert_eq!((s.valid_pixels, s.min, s.max), (2, 2.5, 5.0));
        assert!((s.mean - 3.75).abs() < 1e-12);
    }

    fn row(data: &[f32]) -> DisparityMap {
        DisparityMap {
            width: data.len(),
            height: 1,
            data: data.to_vec(),
            valid: data.iter().map(|&d| d > 0.0).collect(),
        }
    }

    #[test]
    fn left_right_check_keeps_pixels_both_views_see() {
        // A far wall (d = 1) and, in front of it, a near box (d = 4) over left x = 5..=7, which
        // the right view sees at x = 1..=3. The wall's left pixels x = 2..=4 land there: the right
        // view sees the box instead (occluded). Left x = 0 lands outside the right image; left
        // x = 9 has no ground truth. Right x = 4..=6 show wall the left view cannot see.
        let left = row(&[1.0, 1.0, 1.0, 1.0, 1.0, 4.0, 4.0, 4.0, 1.0, 0.0]);
        let right = row(&[1.0, 4.0, 4.0, 4.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0]);
        let (f, t) = (false, true);
        assert_eq!(
            left.left_right_consistent(&right, LEFT_RIGHT_TOLERANCE_PX),
            [f, t, f, f, f, t, t, t, t, f]
        );
        // A tolerance as large as the depth step cannot tell the surfaces apart.
        assert_eq!(
            left.left_right_consistent(&right, 3.0),
            [f, t, t, t, t, t, t, t, t, f]
        );
    }
}
