//! Analytic two-layer stereo pairs (a textured fronto-parallel background and a textured
//! rectangle in front of it), rendered exactly for both views. The tests of the loader, the
//! training loop and the commands train and evaluate on these when no rendered data is needed.

use std::path::Path;

use anyhow::Result;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use stereo_io::{DisparityMap, ImageEncoding, RgbImage, SampleMeta, StereoSample, WritableFormat};

/// A smooth random colour texture: bilinear interpolation of a coarse random grid, plus a fine
/// hash pattern of the texture coordinate so every window is distinctive.
struct Texture {
    cell: f64,
    gw: usize,
    grid: Vec<[f64; 3]>,
}

impl Texture {
    fn new(rng: &mut ChaCha8Rng, width: usize, height: usize, cell: f64) -> Self {
        let gw = (width as f64 / cell) as usize + 3;
        let gh = (height as f64 / cell) as usize + 3;
        let grid = (0..gw * gh)
            .map(|_| {
                [
                    rng.random_range(20.0..235.0),
                    rng.random_range(20.0..235.0),
                    rng.random_range(20.0..235.0),
                ]
            })
            .collect();
        Self { cell, gw, grid }
    }

    fn at(&self, u: f64, v: f64) -> [f64; 3] {
        let (gx, gy) = (u / self.cell + 1.0, v / self.cell + 1.0);
        let (x0, y0) = (gx.floor().max(0.0) as usize, gy.floor().max(0.0) as usize);
        let (fx, fy) = (gx - x0 as f64, gy - y0 as f64);
        let g = |x: usize, y: usize| {
            self.grid[y.min(self.grid.len() / self.gw - 1) * self.gw + x.min(self.gw - 1)]
        };
        let mut out = [0.0; 3];
        for (c, o) in out.iter_mut().enumerate() {
            *o = g(x0, y0)[c] * (1.0 - fx) * (1.0 - fy)
                + g(x0 + 1, y0)[c] * fx * (1.0 - fy)
                + g(x0, y0 + 1)[c] * (1.0 - fx) * fy
                + g(x0 + 1, y0 + 1)[c] * fx * fy;
        }
        // Deterministic fine detail tied to the texture coordinate, not to the view.
        let h = ((u * 12.9898 + v * 78.233).sin() * 43758.5453).fract();
        out.map(|o| (o + 25.0 * h).clamp(0.0, 255.0))
    }
}

/// One analytic pair with both disparity maps.
pub struct SyntheticPair {
    pub left: RgbImage,
    pub right: RgbImage,
    pub disp_left: DisparityMap,
    pub disp_right: DisparityMap,
    /// The rectangle in the left view (the foreground of mxIoU).
    pub foreground: Vec<bool>,
}

/// A background at disparity `d_bg` and a rectangle at `d_fg` (> `d_bg`), both integer so the
/// two views sample the textures at the same points.
pub fn synthetic_pair(width: usize, height: usize, seed: u64) -> SyntheticPair {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let d_bg = rng.random_range(4..16) as f64;
    let d_fg = d_bg + rng.random_range(4..(width / 8).max(6)) as f64;
    let (rw, rh) = (
        rng.random_range(width / 4..width / 2),
        rng.random_range(height / 4..height / 2),
    );
    let x0 = rng.random_range(d_fg as usize..width - rw) as f64;
    let y0 = rng.random_range(0..height - rh);
    let (x1, y1) = (x0 + rw as f64, y0 + rh);
    let bg = Texture::new(&mut rng, width + 64, height, 9.0);
    let fg = Texture::new(&mut rng, width, height, 5.0);
    let mut left = RgbImage {
        width,
        height,
        data: vec![0; width * height * 3],
    };
    let mut right = left.clone();
    let mut disp_left = DisparityMap::new(width, height);
    let mut disp_right = DisparityMap::new(width, height);
    let mut foreground = vec![false; width * height];
    let put = |img: &mut RgbImage, x: usize, y: usize, c: [f64; 3]| {
        for (dst, v) in img.data[(y * width + x) * 3..][..3].iter_mut().zip(c) {
            *dst = v.round() as u8;
        }
    };
    for y in 0..height {
        let in_rows = (y0..y1).contains(&y);
        for x in 0..width {
            let xf = x as f64;
            // Left view: the rectangle covers [x0, x1); the background point at x is seen at
            // x − d_bg in the right view, so its texture coordinate is x + (offset) in both.
            let inside = in_rows && xf >= x0 && xf < x1;
            foreground[y * width + x] = inside;
            let (c, d) = if inside {
                (fg.at(xf - x0, y as f64), d_fg)
            } else {
                (bg.at(xf + 32.0, y as f64), d_bg)
            };
            put(&mut left, x, y, c);
            disp_left.data[y * width + x] = d as f32;
            disp_left.valid[y * width + x] = true;
            // Right view: everything moves left by its disparity.
            let (c, d) = if in_rows && xf >= x0 - d_fg && xf < x1 - d_fg {
                (fg.at(xf + d_fg - x0, y as f64), d_fg)
            } else {
                (bg.at(xf + d_bg + 32.0, y as f64), d_bg)
            };
            put(&mut right, x, y, c);
            disp_right.data[y * width + x] = d as f32;
            disp_right.valid[y * width + x] = true;
        }
    }
    SyntheticPair {
        left,
        right,
        disp_left,
        disp_right,
        foreground,
    }
}

/// Writes `count` synthetic pairs in the CREStereo release layout through stereo-io's writer
/// (`<name>_left.jpg`, …, ×32 PNG disparity) under `dir`, real JPEG at quality 100, 4:4:4 (the
/// layout's own format; the analytic pairs' correspondences are exact, so their pixels should
/// carry as little compression noise as the format allows), and each pair's foreground mask as `dir/foreground/<name>.png` (for
/// `crestereo eval --fg-masks`).
pub fn write_crestereo_dataset(
    dir: &Path,
    count: usize,
    width: usize,
    height: usize,
    seed: u64,
) -> Result<()> {
    let mut writer =
        stereo_io::create_writer(WritableFormat::Crestereo, dir, ImageEncoding::Jpeg(100))?;
    std::fs::create_dir_all(dir.join("foreground"))?;
    for i in 0..count {
        let p = synthetic_pair(width, height, crate::data::mix_seed(seed, i as u64));
        let name = format!("pair{i:03}");
        let sample = StereoSample {
            left: p.left,
            right: p.right,
            disp_left: p.disp_left,
            disp_right: Some(p.disp_right),
            valid_left: None,
            meta: SampleMeta::default(),
        };
        writer.write(i, &name, &sample)?;
        let mask = p
            .foreground
            .iter()
            .map(|f| if *f { 255 } else { 0 })
            .collect();
        stereo_io::write_png(
            &dir.join("foreground").join(format!("{name}.png")),
            &stereo_io::Image {
                width,
                height,
                channels: 1,
                samples: stereo_io::Samples::U8(mask),
            },
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn views_agree_through_the_disparity() {
        let p = synthetic_pair(96, 64, 5);
        let (w, h) = (96, 64);
        let mut checked = 0;
        for y in 0..h {
            for x in 0..w {
                let d = p.disp_left.data[y * w + x] as usize;
                if x < d {
                    continue;
                }
                // The left pixel is visible in the right view unless the rectangle covers it.
                if p.disp_right.data[y * w + x - d] as usize != d {
                    continue;
                }
                assert_eq!(
                    p.left.data[(y * w + x) * 3..][..3],
                    p.right.data[(y * w + x - d) * 3..][..3],
                    "pixel {x},{y}"
                );
                checked += 1;
            }
        }
        assert!(checked > w * h / 2);
    }
}
