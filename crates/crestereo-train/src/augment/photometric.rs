//! Brightness, contrast and gamma of one image.

use serde::{Deserialize, Serialize};

use super::BgrImage;

/// Brightness, contrast and gamma factors for one image.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Photometric {
    pub brightness: f64,
    pub contrast: f64,
    pub gamma: f64,
}

impl Photometric {
    pub const IDENTITY: Self = Self {
        brightness: 1.0,
        contrast: 1.0,
        gamma: 1.0,
    };
}

/// ITU-R 601 luma weights, the ones PIL's grey conversion uses.
fn mean_grey(img: &BgrImage) -> f64 {
    let n = (img.width * img.height).max(1) as f64;
    let sum = |channel: usize| {
        img.plane(channel)
            .iter()
            .map(|&v| f64::from(v))
            .sum::<f64>()
    };
    (0.114 * sum(0) + 0.587 * sum(1) + 0.299 * sum(2)) / n
}

/// Brightness (scale towards black), contrast (blend with the image's mean grey) and gamma
/// (`255 · (v/255)^γ`), in that order like PIL's `ImageEnhance` + lookup table; each step is
/// clamped to 0..255 as an 8-bit image would be.
pub fn photometric(img: &mut BgrImage, factors: &Photometric) {
    let brightness = factors.brightness as f32;
    for v in &mut img.data {
        *v = (*v * brightness).clamp(0.0, 255.0);
    }
    // Written as v·c + m·(1−c) so that c = 1 returns v bit for bit.
    let contrast = factors.contrast as f32;
    let grey_part = (mean_grey(img) * (1.0 - factors.contrast)) as f32;
    for v in &mut img.data {
        *v = (*v * contrast + grey_part).clamp(0.0, 255.0);
    }
    let gamma = factors.gamma as f32;
    for v in &mut img.data {
        *v = (255.0 * (*v / 255.0).powf(gamma)).clamp(0.0, 255.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::augment::test_support::*;

    fn mid_grey_image() -> BgrImage {
        planar_from_fn(W, H, |c, x, y| {
            60.0 + noise(x as i64, y as i64, c as u64) * 0.5
        })
    }

    #[test]
    fn photometric_factor_one_is_the_identity() {
        let img = mid_grey_image();
        let mut out = img.clone();
        photometric(&mut out, &Photometric::IDENTITY);
        for (a, b) in out.data.iter().zip(&img.data) {
            assert!((a - b).abs() < 1e-4);
        }
    }

    #[test]
    fn brightness_multiplies() {
        let img = mid_grey_image();
        let mut out = img.clone();
        photometric(
            &mut out,
            &Photometric {
                brightness: 1.2,
                ..Photometric::IDENTITY
            },
        );
        for (a, b) in out.data.iter().zip(&img.data) {
            assert!((a - 1.2 * b).abs() < 1e-3);
        }
    }

    #[test]
    fn contrast_keeps_the_mean_grey_and_stretches_around_it() {
        let img = mid_grey_image();
        let mean = mean_grey(&img);
        let mut out = img.clone();
        photometric(
            &mut out,
            &Photometric {
                contrast: 1.2,
                ..Photometric::IDENTITY
            },
        );
        assert!((mean_grey(&out) - mean).abs() < 1e-3);
        for (a, b) in out.data.iter().zip(&img.data) {
            let expected = mean + 1.2 * (f64::from(*b) - mean);
            assert!((f64::from(*a) - expected).abs() < 1e-3);
        }
        // The grey level is luma, not the plain channel average: a pure blue image has grey
        // 0.114·200, and contrast 0 turns every channel into it.
        let mut blue = planar_from_fn(4, 4, |c, _, _| if c == 0 { 200.0 } else { 0.0 });
        photometric(
            &mut blue,
            &Photometric {
                contrast: 0.0,
                ..Photometric::IDENTITY
            },
        );
        assert!(blue.data.iter().all(|&v| (v - 22.8).abs() < 1e-3));
    }

    #[test]
    fn gamma_bends_intensities() {
        let mut img = planar_from_fn(3, 1, |_, x, _| [0.0, 63.75, 255.0][x]);
        photometric(
            &mut img,
            &Photometric {
                gamma: 2.0,
                ..Photometric::IDENTITY
            },
        );
        assert_eq!(at(&img, 0, 0, 0), 0.0);
        assert!((at(&img, 0, 1, 0) - 255.0 / 16.0).abs() < 1e-3);
        assert!((at(&img, 0, 2, 0) - 255.0).abs() < 1e-3);
    }

    #[test]
    fn photometric_output_is_clamped() {
        let mut img = noise_image();
        photometric(
            &mut img,
            &Photometric {
                brightness: 1.5,
                contrast: 2.0,
                gamma: 0.8,
            },
        );
        assert!(img.data.iter().all(|v| (0.0..=255.0).contains(v)));
        assert!(img.data.contains(&255.0) && img.data.contains(&0.0));
    }
}
