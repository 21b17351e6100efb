//! The paper's robustness test ("Disturbed ETH3D", §4): an evaluation pair's right view is
//! disturbed the way a second camera module disturbs it (blur, a colour transform, chromatic
//! noise, a perspective transform, a vertical shift, lens distortion) and the error is measured
//! against the undisturbed ground truth. Only the right view changes, as in the paper's training
//! augmentation for the same camera faults: the left view and its disparity stay what the dataset
//! holds, so every change in error comes from the disturbance.
//!
//! Each disturbance is a pure function of (kind, level, seed, sample id): the random parts
//! (colour gains, noise, the perspective's corner directions) come from a ChaCha stream keyed by
//! those, so a run repeats exactly. Level 0 returns the image unchanged, bit for bit.

mod report;

pub use report::{DisturbedResult, disturbance_csv, disturbance_table, headline, headline_pixels};

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::Serialize;

use crate::augment::{BgrImage, SampleStreams, remap};

/// What disturbs the right view.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum DisturbKind {
    /// Gaussian blur; level: σ in pixels.
    Blur,
    /// Per-channel gain and a gamma, as white balance and tone curves differ between modules;
    /// level: strength s (gains in [1 − s, 1 + s], gamma in [1/(1 + s), 1 + s]).
    Colour,
    /// Independent Gaussian noise per pixel and channel; level: σ in 8-bit grey levels.
    Noise,
    /// A homography moving each corner by `level` pixels in a random direction.
    Perspective,
    /// The content moves down by `level` pixels (bilinear for fractions).
    Vshift,
    /// Radial lens distortion about the centre that moves the corners by `level` pixels.
    Distortion,
}

impl DisturbKind {
    pub const ALL: [Self; 6] = [
        Self::Blur,
        Self::Colour,
        Self::Noise,
        Self::Perspective,
        Self::Vshift,
        Self::Distortion,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Self::Blur => "blur",
            Self::Colour => "colour",
            Self::Noise => "noise",
            Self::Perspective => "perspective",
            Self::Vshift => "vshift",
            Self::Distortion => "distortion",
        }
    }

    /// What a level measures.
    pub fn unit(self) -> &'static str {
        match self {
            Self::Blur => "sigma px",
            Self::Colour => "strength",
            Self::Noise => "sigma of 255",
            Self::Perspective => "px at the corners",
            Self::Vshift => "px",
            Self::Distortion => "px at the corners",
        }
    }

    /// The levels `--disturb KIND` runs without a list (level 0 is the plain evaluation).
    pub fn default_levels(self) -> &'static [f64] {
        match self {
            Self::Blur => &[1.0, 2.0, 4.0],
            Self::Colour => &[0.1, 0.2, 0.4],
            Self::Noise => &[5.0, 10.0, 20.0],
            Self::Perspective => &[2.0, 4.0, 8.0],
            Self::Vshift => &[1.0, 2.0, 4.0],
            Self::Distortion => &[2.0, 4.0, 8.0],
        }
    }

    fn parse(name: &str) -> Option<Self> {
        let name = name.trim().to_ascii_lowercase();
        match name.as_str() {
            "color" => Some(Self::Colour),
            "vertical-shift" => Some(Self::Vshift),
            _ => Self::ALL.into_iter().find(|k| k.name() == name),
        }
    }
}

/// One kind at one level, with the seed of its random parts.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Disturbance {
    pub kind: DisturbKind,
    pub level: f64,
    pub seed: u64,
}

/// The kinds and levels of `--disturb` values: `KIND`, `KIND:L1,L2,...` or `all`, each value once
/// per kind (a later value for the same kind replaces its levels).
pub fn parse_specs(specs: &[String]) -> Result<Vec<(DisturbKind, Vec<f64>)>, String> {
    let mut out: Vec<(DisturbKind, Vec<f64>)> = Vec::new();
    let kinds = DisturbKind::ALL.map(DisturbKind::name).join(", ");
    for spec in specs {
        let (name, levels) = match spec.split_once(':') {
            Some((n, l)) => (n, Some(l)),
            None => (spec.as_str(), None),
        };
        let chosen: Vec<DisturbKind> = if name.trim().eq_ignore_ascii_case("all") {
            DisturbKind::ALL.to_vec()
        } else {
            vec![DisturbKind::parse(name).ok_or_else(|| {
                format!("--disturb {spec}: `{name}` is not a disturbance (one of {kinds}, or all)")
            })?]
        };
        for kind in chosen {
            let levels = match levels {
                None => kind.default_levels().to_vec(),
                Some(list) => list
                    .split(',')
                    .map(|v| match v.trim().parse::<f64>() {
                        Ok(x) if x.is_finite() && x >= 0.0 => Ok(x),
                        _ => Err(format!(
                            "--disturb {spec}: level `{v}` is not a number >= 0 ({})",
                            kind.unit()
                        )),
                    })
                    .collect::<Result<Vec<_>, _>>()?,
            };
            match out.iter_mut().find(|(k, _)| *k == kind) {
                Some(entry) => entry.1 = levels,
                None => out.push((kind, levels)),
            }
        }
    }
    Ok(out)
}

impl Disturbance {
    /// The disturbed copy of a (right) view; `sample_id` keys the random parts per sample.
    pub fn apply(&self, img: &BgrImage, sample_id: &str) -> BgrImage {
        if self.level == 0.0 {
            return img.clone();
        }
        // The augmentation's named streams: one per (seed, kind, sample).
        let mut rng = SampleStreams::for_sample(self.seed)
            .stream(&format!("disturb/{}/{sample_id}", self.kind.name()));
        let level = self.level;
        match self.kind {
            DisturbKind::Blur => gaussian_blur(img, level),
            DisturbKind::Colour => colour_transform(img, level, &mut rng),
            DisturbKind::Noise => chromatic_noise(img, level, &mut rng),
            DisturbKind::Perspective => perspective(img, level, &mut rng),
            DisturbKind::Vshift => remap(img, |x, y| (x, y - level)),
            DisturbKind::Distortion => radial_distortion(img, level),
        }
    }
}

/// Separable Gaussian of standard deviation `sigma` (radius 3σ), edges clamped.
fn gaussian_blur(img: &BgrImage, sigma: f64) -> BgrImage {
    let radius = (3.0 * sigma).ceil() as isize;
    let weights: Vec<f64> = (-radius..=radius)
        .map(|d| (-(d * d) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let total: f64 = weights.iter().sum();
    let kernel: Vec<f32> = weights.iter().map(|w| (w / total) as f32).collect();
    let (w, h) = (img.width, img.height);
    let mut out = BgrImage::zeros(w, h);
    let mut row_pass = vec![0.0f32; w * h];
    for (src, dst) in img.data.chunks(w * h).zip(out.data.chunks_mut(w * h)) {
        // Along each row (neighbours 1 apart), then along each column (w apart).
        convolve_1d(src, &mut row_pass, &kernel, (w, h), (1, w));
        convolve_1d(&row_pass, dst, &kernel, (w, h), (w, 1));
    }
    out
}

/// One pass of a centred 1-D kernel over a `size.0 × size.1` plane along the axis whose
/// neighbours are `strides.0` apart (`strides.1` between lines), positions clamped to the plane.
fn convolve_1d(
    src: &[f32],
    dst: &mut [f32],
    kernel: &[f32],
    (w, h): (usize, usize),
    (step, line): (usize, usize),
) {
    let radius = (kernel.len() / 2) as isize;
    let (len, lines) = if step == 1 { (w, h) } else { (h, w) };
    for l in 0..lines {
        for i in 0..len as isize {
            let at = |j: isize| src[l * line + j.clamp(0, len as isize - 1) as usize * step];
            dst[l * line + i as usize * step] = kernel
                .iter()
                .enumerate()
                .map(|(k, kw)| at(i + k as isize - radius) * kw)
                .sum();
        }
    }
}

/// Per-channel gains in [1 − s, 1 + s] and one gamma in [1/(1 + s), 1 + s], clamped to 0..255.
fn colour_transform(img: &BgrImage, s: f64, rng: &mut ChaCha8Rng) -> BgrImage {
    let gains: [f32; 3] = std::array::from_fn(|_| (1.0 + s * rng.random_range(-1.0..=1.0)) as f32);
    let gamma = (1.0 + s).powf(rng.random_range(-1.0..=1.0)) as f32;
    let plane = img.width * img.height;
    let mut out = img.clone();
    for (c, gain) in gains.iter().enumerate() {
        for v in &mut out.data[c * plane..(c + 1) * plane] {
            *v = 255.0 * ((*v * gain).clamp(0.0, 255.0) / 255.0).powf(gamma);
        }
    }
    out
}

/// Gaussian noise of standard deviation `sigma` drawn for every pixel and channel.
fn chromatic_noise(img: &BgrImage, sigma: f64, rng: &mut ChaCha8Rng) -> BgrImage {
    let normal = Normal::new(0.0f32, sigma as f32).expect("sigma is finite and positive");
    let mut out = img.clone();
    for v in &mut out.data {
        *v = (*v + normal.sample(rng)).clamp(0.0, 255.0);
    }
    out
}

/// The homography taking the four image corners to themselves moved by `shift` pixels each, in
/// random directions; each output pixel shows the input where the inverse map sends it.
fn perspective(img: &BgrImage, shift: f64, rng: &mut ChaCha8Rng) -> BgrImage {
    let (w, h) = ((img.width - 1) as f64, (img.height - 1) as f64);
    let corners = [(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)];
    let moved = corners.map(|(x, y)| {
        let angle = rng.random_range(0.0..std::f64::consts::TAU);
        (x + shift * angle.cos(), y + shift * angle.sin())
    });
    // Output → input: the map sending the moved corners back to the originals.
    match homography(&moved, &corners) {
        Some(m) => remap(img, |x, y| {
            let d = m[6] * x + m[7] * y + 1.0;
            (
                (m[0] * x + m[1] * y + m[2]) / d,
                (m[3] * x + m[4] * y + m[5]) / d,
            )
        }),
        None => img.clone(),
    }
}

/// The 3×3 homography (h33 = 1, row-major, 8 values) with `to[i] ~ H · from[i]`, by Gaussian
/// elimination with partial pivoting; `None` for degenerate corners.
fn homography(from: &[(f64, f64); 4], to: &[(f64, f64); 4]) -> Option<[f64; 8]> {
    let mut a = [[0.0f64; 9]; 8];
    for i in 0..4 {
        let ((x, y), (u, v)) = (from[i], to[i]);
        a[2 * i] = [x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y, u];
        a[2 * i + 1] = [0.0, 0.0, 0.0, x, y, 1.0, -v * x, -v * y, v];
    }
    for col in 0..8 {
        let pivot = (col..8).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[pivot][col].abs() < 1e-12 {
            return None;
        }
        a.swap(col, pivot);
        let pivot_row = a[col];
        for (row, line) in a.iter_mut().enumerate() {
            if row != col {
                let f = line[col] / pivot_row[col];
                for (v, p) in line[col..].iter_mut().zip(&pivot_row[col..]) {
                    *v -= f * p;
                }
            }
        }
    }
    Some(std::array::from_fn(|i| a[i][8] / a[i][i]))
}

/// Radial distortion about the centre, `p_in = c + (p − c)(1 + k r²)` with r = 1 at the corners
/// and k chosen so that the corners move by `shift` pixels.
fn radial_distortion(img: &BgrImage, shift: f64) -> BgrImage {
    remap(img, radial_map(img.width, img.height, shift))
}

/// The output → input map of [`radial_distortion`].
fn radial_map(width: usize, height: usize, shift: f64) -> impl Fn(f64, f64) -> (f64, f64) {
    let (cx, cy) = ((width - 1) as f64 / 2.0, (height - 1) as f64 / 2.0);
    let half_diagonal = (cx * cx + cy * cy).sqrt().max(1.0);
    let k = shift / half_diagonal;
    move |x, y| {
        let (dx, dy) = (x - cx, y - cy);
        let r2 = (dx * dx + dy * dy) / (half_diagonal * half_diagonal);
        (cx + dx * (1.0 + k * r2), cy + dy * (1.0 + k * r2))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(width: usize, height: usize) -> BgrImage {
        let mut img = BgrImage::zeros(width, height);
        let plane = width * height;
        for c in 0..3 {
            for y in 0..height {
                for x in 0..width {
                    let v = ((x * 37 + y * 91 + c * 53) % 200) as f32 + 20.0;
                    img.data[c * plane + y * width + x] = v;
                }
            }
        }
        img
    }

    #[test]
    fn level_zero_is_the_identity_and_other_levels_change_the_image() {
        let img = image(40, 24);
        for kind in DisturbKind::ALL {
            let at = |level| {
                Disturbance {
                    kind,
                    level,
                    seed: 3,
                }
                .apply(&img, "sample-7")
            };
            assert_eq!(at(0.0), img, "{kind:?} at level 0");
            let moved = at(kind.default_levels()[1]);
            assert_ne!(moved, img, "{kind:?} at its second level");
            assert_eq!(moved, at(kind.default_levels()[1]), "{kind:?} repeats");
        }
    }

    #[test]
    fn random_parts_depend_on_seed_and_sample() {
        let img = image(32, 16);
        let d = |seed| Disturbance {
            kind: DisturbKind::Noise,
            level: 5.0,
            seed,
        };
        assert_ne!(d(0).apply(&img, "a"), d(1).apply(&img, "a"));
        assert_ne!(d(0).apply(&img, "a"), d(0).apply(&img, "b"));
    }

    #[test]
    fn vertical_shift_moves_rows_down() {
        let img = image(16, 12);
        let out = Disturbance {
            kind: DisturbKind::Vshift,
            level: 2.0,
            seed: 0,
        }
        .apply(&img, "x");
        let plane = 16 * 12;
        for c in 0..3 {
            for x in 0..16 {
                assert_eq!(out.data[c * plane + x], 0.0);
                for y in 2..12 {
                    assert_eq!(
                        out.data[c * plane + y * 16 + x],
                        img.data[c * plane + (y - 2) * 16 + x]
                    );
                }
            }
        }
    }

    #[test]
    fn blur_keeps_a_constant_image_and_spreads_an_impulse_as_a_gaussian() {
        let mut flat = BgrImage::zeros(20, 10);
        flat.data.iter_mut().for_each(|v| *v = 100.0);
        let out = gaussian_blur(&flat, 2.0);
        assert!(out.data.iter().all(|v| (v - 100.0).abs() < 1e-3));
        // An impulse far from the edges: its mass is kept, it spreads symmetrically along both
        // axes, and the ratio one pixel off the centre is exp(-1/(2σ²)).
        let (w, h, sigma) = (31, 25, 1.5);
        let mut impulse = BgrImage::zeros(w, h);
        let (x0, y0) = (15, 12);
        impulse.data[w * h + y0 * w + x0] = 1000.0;
        let out = gaussian_blur(&impulse, sigma);
        let g = &out.data[w * h..2 * w * h];
        let at = |x: usize, y: usize| f64::from(g[y * w + x]);
        assert!((g.iter().map(|&v| f64::from(v)).sum::<f64>() - 1000.0).abs() < 1e-2);
        assert!(
            out.data[..w * h].iter().all(|&v| v == 0.0),
            "channels stay apart"
        );
        for d in 1..4 {
            assert!((at(x0 + d, y0) - at(x0 - d, y0)).abs() < 1e-4);
            assert!((at(x0, y0 + d) - at(x0, y0 - d)).abs() < 1e-4);
            assert!((at(x0 + d, y0) - at(x0, y0 + d)).abs() < 1e-4);
        }
        let ratio = at(x0 + 1, y0) / at(x0, y0);
        assert!(
            (ratio - (-1.0 / (2.0 * sigma * sigma)).exp()).abs() < 1e-5,
            "{ratio}"
        );
    }

    #[test]
    fn the_homography_sends_the_corners_where_asked() {
        let from = [(0.0, 0.0), (9.0, 0.0), (9.0, 5.0), (0.0, 5.0)];
        let to = [(0.5, -1.0), (10.0, 0.3), (8.2, 6.0), (-0.4, 4.1)];
        let m = homography(&from, &to).unwrap();
        for ((x, y), (u, v)) in from.iter().zip(&to) {
            let d = m[6] * x + m[7] * y + 1.0;
            assert!(((m[0] * x + m[1] * y + m[2]) / d - u).abs() < 1e-9);
            assert!(((m[3] * x + m[4] * y + m[5]) / d - v).abs() < 1e-9);
        }
    }

    #[test]
    fn distortion_moves_the_corners_by_the_level_and_keeps_the_centre() {
        let (w, h) = (33, 21);
        let map = radial_map(w, h, 3.0);
        // Each corner samples the point 3 px further out along its diagonal.
        let (cx, cy) = (16.0, 10.0);
        for (x, y) in [(0.0, 0.0), (32.0, 0.0), (32.0, 20.0), (0.0, 20.0)] {
            let (sx, sy) = map(x, y);
            let moved = f64::hypot(sx - cx, sy - cy) - f64::hypot(x - cx, y - cy);
            assert!(
                (moved - 3.0).abs() < 1e-9,
                "corner ({x}, {y}) moved {moved}"
            );
            assert!(
                ((sx - cx) * (y - cy) - (sy - cy) * (x - cx)).abs() < 1e-9,
                "radially"
            );
        }
        assert_eq!(map(cx, cy), (cx, cy));
        // The image goes through that map: a linear ramp is sampled exactly by bilinear taps.
        let ramp = |x: f64, y: f64| 10.0 + 2.0 * x + 3.0 * y;
        let mut img = BgrImage::zeros(w, h);
        for y in 0..h {
            for x in 0..w {
                img.data[y * w + x] = ramp(x as f64, y as f64) as f32;
            }
        }
        let out = radial_distortion(&img, 3.0);
        for (x, y) in [(16, 10), (10, 5), (25, 14), (4, 17)] {
            let (sx, sy) = map(x as f64, y as f64);
            let got = f64::from(out.data[y * w + x]);
            assert!((got - ramp(sx, sy)).abs() < 1e-3, "({x}, {y}): {got}");
        }
    }

    #[test]
    fn specs_parse_with_defaults_aliases_and_errors() {
        let s = |v: &[&str]| parse_specs(&v.iter().map(|x| x.to_string()).collect::<Vec<_>>());
        assert_eq!(
            s(&["blur:0,1.5"]).unwrap(),
            vec![(DisturbKind::Blur, vec![0.0, 1.5])]
        );
        assert_eq!(
            s(&["color"]).unwrap(),
            vec![(DisturbKind::Colour, vec![0.1, 0.2, 0.4])]
        );
        assert_eq!(s(&["all"]).unwrap().len(), 6);
        assert!(s(&["fog"]).unwrap_err().contains("not a disturbance"));
        assert!(s(&["noise:-1"]).unwrap_err().contains("not a number >= 0"));
    }
}
