//! The random choices of one augmentation, drawn before any pixel is touched.

use rand::Rng;
use serde::{Deserialize, Serialize};

use super::{AugmentConfig, OcclusionBox, Photometric, RightWarp};

/// Every random choice of one augmentation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AugmentParams {
    /// Swap and mirror the views; ignored when the sample has no right-view disparity.
    pub swap: bool,
    pub left_photometric: Photometric,
    pub right_photometric: Photometric,
    pub right_warp: Option<RightWarp>,
    pub scale: f64,
    /// Crop position `[y, x]` as fractions in `[0, 1)` of the possible offsets, because the
    /// resized size is not known when drawing: see [`crop_offset`](super::crop_offset).
    pub crop_frac: [f64; 2],
    pub occlusion: Option<OcclusionBox>,
}

impl AugmentParams {
    /// Nothing changes except the crop, at the given position.
    pub fn identity(crop_frac: [f64; 2]) -> Self {
        Self {
            swap: false,
            left_photometric: Photometric::IDENTITY,
            right_photometric: Photometric::IDENTITY,
            right_warp: None,
            scale: 1.0,
            crop_frac,
            occlusion: None,
        }
    }

    /// Draws all choices: always 20 uniform numbers in the same order (the reference's order
    /// of use), whatever the config and whichever coins come up, so one sample's draws never
    /// shift the next sample's.
    pub fn draw(cfg: &AugmentConfig, rng: &mut impl Rng) -> Self {
        let mut unit = || rng.random::<f64>();
        let between = |range: [f64; 2], u: f64| range[0] + u * (range[1] - range[0]);

        let swap = unit() < cfg.swap_prob;
        let mut photometric = || Photometric {
            brightness: between(cfg.brightness, unit()),
            contrast: between(cfg.contrast, unit()),
            gamma: between(cfg.gamma, unit()),
        };
        let left_photometric = photometric();
        let right_photometric = photometric();

        let warp_coin = unit() < cfg.right_warp_prob;
        let shift_y = between([-cfg.vertical_shift_px, cfg.vertical_shift_px], unit());
        let angle_deg = between([-cfg.rotation_deg, cfg.rotation_deg], unit());
        let centre_frac = [unit(), unit()];
        let right_warp = warp_coin.then_some(RightWarp {
            angle_deg,
            centre_frac,
            shift_y,
        });

        let scale = between(cfg.scale, unit());
        let crop_frac = [unit(), unit()];

        let occlusion_coin = unit() < cfg.occlusion_prob;
        let half_size = [
            between(cfg.occlusion_half_size, unit()),
            between(cfg.occlusion_half_size, unit()),
        ];
        let centre_frac = [unit(), unit()];
        let occlusion = occlusion_coin.then_some(OcclusionBox {
            half_size,
            centre_frac,
        });

        Self {
            swap,
            left_photometric,
            right_photometric,
            right_warp,
            scale,
            crop_frac,
            occlusion,
        }
    }
}

#[cfg(test)]
mod tests {
    use rand::{RngCore, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;

    #[test]
    fn draw_always_consumes_the_same_number_of_draws() {
        let never = AugmentConfig {
            swap_prob: 0.0,
            right_warp_prob: 0.0,
            occlusion_prob: 0.0,
            ..AugmentConfig::none([8, 8])
        };
        let always = AugmentConfig {
            swap_prob: 1.0,
            right_warp_prob: 1.0,
            occlusion_prob: 1.0,
            ..AugmentConfig::default()
        };
        let mut rng_never = ChaCha8Rng::seed_from_u64(9);
        let mut rng_always = ChaCha8Rng::seed_from_u64(9);
        let p_never = AugmentParams::draw(&never, &mut rng_never);
        let p_always = AugmentParams::draw(&always, &mut rng_always);
        assert!(!p_never.swap && p_never.right_warp.is_none() && p_never.occlusion.is_none());
        assert!(p_always.swap && p_always.right_warp.is_some() && p_always.occlusion.is_some());
        // And the count is the documented 20.
        let mut counted = ChaCha8Rng::seed_from_u64(9);
        for _ in 0..20 {
            counted.random::<f64>();
        }
        let next = counted.next_u64();
        assert_eq!(rng_never.next_u64(), next);
        assert_eq!(rng_always.next_u64(), next);
    }

    #[test]
    fn drawn_values_have_the_configured_distribution() {
        let cfg = AugmentConfig::default();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let draws: Vec<AugmentParams> = (0..2000)
            .map(|_| AugmentParams::draw(&cfg, &mut rng))
            .collect();
        let rate = |f: &dyn Fn(&AugmentParams) -> bool| {
            draws.iter().filter(|p| f(p)).count() as f64 / 2000.0
        };
        for (name, r) in [
            ("swap", rate(&|p| p.swap)),
            ("warp", rate(&|p| p.right_warp.is_some())),
            ("occlusion", rate(&|p| p.occlusion.is_some())),
        ] {
            assert!((r - 0.5).abs() < 0.05, "{name} rate {r}");
        }
        assert!(draws.iter().all(|p| (0.6..=1.0).contains(&p.scale)));
        let mean_scale = draws.iter().map(|p| p.scale).sum::<f64>() / 2000.0;
        assert!((mean_scale - 0.8).abs() < 0.02, "mean scale {mean_scale}");
        for p in &draws {
            for f in [p.left_photometric, p.right_photometric] {
                assert!(
                    [f.brightness, f.contrast, f.gamma]
                        .iter()
                        .all(|v| (0.8..=1.2).contains(v))
                );
            }
            if let Some(w) = p.right_warp {
                assert!(w.angle_deg.abs() <= 0.1 && w.shift_y.abs() < 2.0);
                assert!(w.centre_frac.iter().all(|f| (0.0..1.0).contains(f)));
            }
            assert!(p.crop_frac.iter().all(|f| (0.0..1.0).contains(f)));
        }
    }

    #[test]
    fn drawn_occlusion_half_sizes_are_in_range() {
        let cfg = AugmentConfig {
            occlusion_prob: 1.0,
            ..AugmentConfig::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for _ in 0..500 {
            let box_ = AugmentParams::draw(&cfg, &mut rng).occlusion.unwrap();
            assert!(
                box_.half_size.iter().all(|h| (50.0..100.0).contains(h)),
                "{box_:?}"
            );
            let [top, bottom, left, right] = box_.rect(384, 512);
            assert!(bottom <= 384 && right <= 512);
            assert!((100..200).contains(&(bottom - top)) && (100..200).contains(&(right - left)));
        }
    }
}
