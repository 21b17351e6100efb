//! The random choices of one augmentation, drawn before any pixel is touched.
//!
//! Each augmentation draws from its own named stream of the sample's seed (see
//! [`SampleStreams`]): its coin first, then its values whether or not the coin came up. The
//! draws of one augmentation therefore depend only on the seed, the stream name and that
//! augmentation's own settings, so switching another off, retuning it or adding a new one
//! leaves them unchanged.

use rand::Rng;
use serde::{Deserialize, Serialize};

use super::{AugmentConfig, OcclusionBox, Photometric, RightWarp, SampleStreams};

/// The stream names. They are part of what a seed means: renaming one changes that
/// augmentation's draws in every run, so a new augmentation gets a new name.
pub mod stream {
    pub const SWAP: &str = "swap";
    pub const LEFT_PHOTOMETRIC: &str = "photometric/left";
    pub const RIGHT_PHOTOMETRIC: &str = "photometric/right";
    pub const RIGHT_WARP: &str = "right-warp";
    pub const SCALE: &str = "scale";
    pub const CROP: &str = "crop";
    pub const OCCLUSION: &str = "occlusion";
    /// Every name in use (kept distinct by a test).
    pub const ALL: [&str; 7] = [
        SWAP,
        LEFT_PHOTOMETRIC,
        RIGHT_PHOTOMETRIC,
        RIGHT_WARP,
        SCALE,
        CROP,
        OCCLUSION,
    ];
}

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

/// A uniform draw in `[low, high)`.
fn between(rng: &mut impl Rng, range: [f64; 2]) -> f64 {
    range[0] + rng.random::<f64>() * (range[1] - range[0])
}

/// A coin that comes up with probability `p`.
fn coin(rng: &mut impl Rng, p: f64) -> bool {
    rng.random::<f64>() < p
}

fn draw_photometric(cfg: &AugmentConfig, rng: &mut impl Rng) -> Photometric {
    Photometric {
        brightness: between(rng, cfg.brightness),
        contrast: between(rng, cfg.contrast),
        gamma: between(rng, cfg.gamma),
    }
}

fn draw_right_warp(cfg: &AugmentConfig, rng: &mut impl Rng) -> Option<RightWarp> {
    let applied = coin(rng, cfg.right_warp_prob);
    let shift_y = between(rng, [-cfg.vertical_shift_px, cfg.vertical_shift_px]);
    let angle_deg = between(rng, [-cfg.rotation_deg, cfg.rotation_deg]);
    let centre_frac = [rng.random(), rng.random()];
    applied.then_some(RightWarp {
        angle_deg,
        centre_frac,
        shift_y,
    })
}

fn draw_occlusion(cfg: &AugmentConfig, rng: &mut impl Rng) -> Option<OcclusionBox> {
    let applied = coin(rng, cfg.occlusion_prob);
    let half_size = [
        between(rng, cfg.occlusion_half_size),
        between(rng, cfg.occlusion_half_size),
    ];
    let centre_frac = [rng.random(), rng.random()];
    applied.then_some(OcclusionBox {
        half_size,
        centre_frac,
    })
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

    /// Draws all choices, each augmentation from its own stream of `streams`.
    pub fn draw(cfg: &AugmentConfig, streams: &SampleStreams) -> Self {
        let crop = &mut streams.stream(stream::CROP);
        Self {
            swap: coin(&mut streams.stream(stream::SWAP), cfg.swap_prob),
            left_photometric: draw_photometric(cfg, &mut streams.stream(stream::LEFT_PHOTOMETRIC)),
            right_photometric: draw_photometric(
                cfg,
                &mut streams.stream(stream::RIGHT_PHOTOMETRIC),
            ),
            right_warp: draw_right_warp(cfg, &mut streams.stream(stream::RIGHT_WARP)),
            scale: between(&mut streams.stream(stream::SCALE), cfg.scale),
            crop_frac: [crop.random(), crop.random()],
            occlusion: draw_occlusion(cfg, &mut streams.stream(stream::OCCLUSION)),
        }
    }
}

#[cfg(test)]
mod tests {
    use rand::RngCore;

    use super::*;

    fn draws(cfg: &AugmentConfig, n: u64) -> Vec<AugmentParams> {
        (0..n)
            .map(|k| AugmentParams::draw(cfg, &SampleStreams::for_sample(k)))
            .collect()
    }

    /// The choices of each augmentation, as the bits that define them.
    fn parts(p: &AugmentParams) -> [(&'static str, String); 7] {
        [
            (stream::SWAP, format!("{:?}", p.swap)),
            (
                stream::LEFT_PHOTOMETRIC,
                format!("{:?}", p.left_photometric),
            ),
            (
                stream::RIGHT_PHOTOMETRIC,
                format!("{:?}", p.right_photometric),
            ),
            (stream::RIGHT_WARP, format!("{:?}", p.right_warp)),
            (stream::SCALE, format!("{:?}", p.scale.to_bits())),
            (stream::CROP, format!("{:?}", p.crop_frac.map(f64::to_bits))),
            (stream::OCCLUSION, format!("{:?}", p.occlusion)),
        ]
    }

    /// Configs that each change one augmentation of `base`, with the stream (name prefix)
    /// whose draws may change.
    fn one_change_each(base: &AugmentConfig) -> Vec<(&'static str, AugmentConfig)> {
        let with = |change: fn(&mut AugmentConfig)| {
            let mut cfg = base.clone();
            change(&mut cfg);
            cfg
        };
        vec![
            (stream::SWAP, with(|c| c.swap_prob = 1.0)),
            (stream::RIGHT_WARP, with(|c| c.right_warp_prob = 0.0)),
            (
                stream::RIGHT_WARP,
                with(|c| (c.right_warp_prob, c.rotation_deg) = (0.9, 1.0)),
            ),
            (stream::OCCLUSION, with(|c| c.occlusion_prob = 0.0)),
            (
                stream::OCCLUSION,
                with(|c| c.occlusion_half_size = [10.0, 20.0]),
            ),
            (stream::SCALE, with(|c| c.scale = [0.9, 1.0])),
            // The photometric ranges are shared by both images: both streams may change.
            ("photometric", with(|c| c.brightness = [0.5, 0.6])),
        ]
    }

    #[test]
    fn retuning_or_disabling_one_augmentation_leaves_the_others_draws_unchanged() {
        let base = AugmentConfig::default();
        let before = draws(&base, 200);
        for (changed, cfg) in one_change_each(&base) {
            let after = draws(&cfg, 200);
            let mut differs = false;
            for (a, b) in before.iter().zip(&after) {
                for ((name, x), (_, y)) in parts(a).into_iter().zip(parts(b)) {
                    if name.starts_with(changed) {
                        differs |= x != y;
                    } else {
                        assert_eq!(x, y, "changing {changed} changed the {name} draws");
                    }
                }
            }
            assert!(differs, "changing {changed} did not change its own draws");
        }
    }

    #[test]
    fn a_new_stream_leaves_the_existing_draws_unchanged() {
        let cfg = AugmentConfig::default();
        for k in 0..50 {
            let streams = SampleStreams::for_sample(k);
            let before = AugmentParams::draw(&cfg, &streams);
            // A new augmentation drawing first from its own stream, as a new one would.
            let mut blur = streams.stream("blur");
            let blur_first = blur.next_u64();
            for _ in 0..16 {
                blur.next_u64();
            }
            assert_eq!(AugmentParams::draw(&cfg, &streams), before);
            for name in stream::ALL {
                assert_ne!(streams.stream(name).next_u64(), blur_first, "{name}");
            }
        }
        let mut firsts: Vec<u64> = stream::ALL
            .iter()
            .map(|name| SampleStreams::for_sample(1).stream(name).next_u64())
            .collect();
        firsts.sort_unstable();
        firsts.dedup();
        assert_eq!(
            firsts.len(),
            stream::ALL.len(),
            "two stream names share draws"
        );
    }

    #[test]
    fn coins_and_values_come_from_separate_streams() {
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
        let streams = SampleStreams::for_sample(9);
        let p_never = AugmentParams::draw(&never, &streams);
        let p_always = AugmentParams::draw(&always, &streams);
        assert!(!p_never.swap && p_never.right_warp.is_none() && p_never.occlusion.is_none());
        assert!(p_always.swap && p_always.right_warp.is_some() && p_always.occlusion.is_some());
        // Whatever the coins, the crop is the same one.
        assert_eq!(p_never.crop_frac, p_always.crop_frac);
    }

    #[test]
    fn drawn_values_have_the_configured_distribution() {
        let cfg = AugmentConfig::default();
        let draws = draws(&cfg, 2000);
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
        for p in draws(&cfg, 500) {
            let box_ = p.occlusion.unwrap();
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
