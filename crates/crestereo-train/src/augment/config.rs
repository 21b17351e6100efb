//! What the augmentation may do, as read from the training config.

use serde::{Deserialize, Serialize};

/// What the augmentation may do. Ranges are `[low, high]`, drawn uniformly.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AugmentConfig {
    /// Output size `[height, width]`.
    pub crop: [usize; 2],
    /// Probability of swapping the views (mirrored), which needs the right-view disparity.
    pub swap_prob: f64,
    /// Multiplicative brightness factor, per image.
    pub brightness: [f64; 2],
    /// Contrast factor (blend with the image's mean grey), per image.
    pub contrast: [f64; 2],
    /// Gamma exponent on 0..1 intensities, per image.
    pub gamma: [f64; 2],
    /// Probability of rotating and vertically shifting the right image.
    pub right_warp_prob: f64,
    /// Rotation angle, drawn in `±rotation_deg` degrees.
    pub rotation_deg: f64,
    /// Vertical shift of the right image, drawn in `±vertical_shift_px` pixels.
    pub vertical_shift_px: f64,
    /// Resize factor of the whole sample.
    pub scale: [f64; 2],
    /// Ground truth counts only where `0 < d < max_disp / scale` before resizing, i.e.
    /// `d < max_disp` after it.
    pub max_disp: f64,
    /// Probability of an occluding box on the right image.
    pub occlusion_prob: f64,
    /// Half height and half width of the box are each drawn from this range (pixels, after
    /// resizing and cropping).
    pub occlusion_half_size: [f64; 2],
}

impl Default for AugmentConfig {
    /// The reference's training values (crop 384×512).
    fn default() -> Self {
        Self {
            crop: [384, 512],
            swap_prob: 0.5,
            brightness: [0.8, 1.2],
            contrast: [0.8, 1.2],
            gamma: [0.8, 1.2],
            right_warp_prob: 0.5,
            rotation_deg: 0.1,
            vertical_shift_px: 2.0,
            scale: [0.6, 1.0],
            max_disp: 256.0,
            occlusion_prob: 0.5,
            occlusion_half_size: [50.0, 100.0],
        }
    }
}

impl AugmentConfig {
    /// Every augmentation off except the (random-offset) crop to `crop`, for validation and
    /// overfitting runs. `max_disp` keeps its default: it defines which ground truth is
    /// trained on, it does not perturb the sample.
    pub fn none(crop: [usize; 2]) -> Self {
        Self {
            crop,
            swap_prob: 0.0,
            brightness: [1.0, 1.0],
            contrast: [1.0, 1.0],
            gamma: [1.0, 1.0],
            right_warp_prob: 0.0,
            rotation_deg: 0.0,
            vertical_shift_px: 0.0,
            scale: [1.0, 1.0],
            occlusion_prob: 0.0,
            ..Self::default()
        }
    }

    /// Checks that every value is usable; the message names the offending field.
    pub fn validate(&self) -> Result<(), String> {
        if self.crop[0] == 0 || self.crop[1] == 0 {
            return Err(format!(
                "crop must be > 0 in both dimensions, got {:?}",
                self.crop
            ));
        }
        for (name, p) in [
            ("swap_prob", self.swap_prob),
            ("right_warp_prob", self.right_warp_prob),
            ("occlusion_prob", self.occlusion_prob),
        ] {
            if !(0.0..=1.0).contains(&p) {
                return Err(format!("{name} must be a probability in 0..=1, got {p}"));
            }
        }
        check_range("brightness", self.brightness, 0.0, false)?;
        check_range("contrast", self.contrast, 0.0, false)?;
        check_range("gamma", self.gamma, 0.0, true)?;
        check_range("scale", self.scale, 0.0, true)?;
        check_range("occlusion_half_size", self.occlusion_half_size, 0.0, false)?;
        for (name, v) in [
            ("rotation_deg", self.rotation_deg),
            ("vertical_shift_px", self.vertical_shift_px),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!(
                    "{name} must be finite and >= 0 (it is a ± bound), got {v}"
                ));
            }
        }
        // Infinity is allowed: it switches the range filter off.
        if self.max_disp.is_nan() || self.max_disp <= 0.0 {
            return Err(format!("max_disp must be > 0, got {}", self.max_disp));
        }
        Ok(())
    }
}

/// `range` must be finite, ordered, and its low end above `min` (or at it, unless `strict`).
fn check_range(name: &str, range: [f64; 2], min: f64, strict: bool) -> Result<(), String> {
    let [low, high] = range;
    if !(low.is_finite() && high.is_finite()) {
        return Err(format!("{name} must be finite, got {range:?}"));
    }
    if low > high {
        return Err(format!("{name} must be ordered [low, high], got {range:?}"));
    }
    let low_ok = if strict { low > min } else { low >= min };
    if !low_ok {
        let relation = if strict { ">" } else { ">=" };
        return Err(format!("{name} must be {relation} {min}, got {range:?}"));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sets a field of a valid config to a value it refuses.
    type Spoil = fn(&mut AugmentConfig);

    #[test]
    fn configs_validate_and_parse() {
        assert_eq!(AugmentConfig::default().validate(), Ok(()));
        assert_eq!(AugmentConfig::none([64, 128]).validate(), Ok(()));
        // Each field with a value it refuses, set on the defaults.
        let bad: [(&str, Spoil); 11] = [
            ("crop", |c| c.crop = [0, 512]),
            ("swap_prob", |c| c.swap_prob = 1.5),
            ("occlusion_prob", |c| c.occlusion_prob = f64::NAN),
            ("scale", |c| c.scale = [1.0, 0.6]),
            ("scale", |c| c.scale = [0.0, 0.6]),
            ("gamma", |c| c.gamma = [0.0, 1.2]),
            ("brightness", |c| c.brightness = [-0.1, 1.2]),
            ("occlusion_half_size", |c| {
                c.occlusion_half_size = [100.0, 50.0]
            }),
            ("rotation_deg", |c| c.rotation_deg = -1.0),
            ("vertical_shift_px", |c| c.vertical_shift_px = f64::INFINITY),
            ("max_disp", |c| c.max_disp = 0.0),
        ];
        for (field, spoil) in bad {
            let mut cfg = AugmentConfig::default();
            spoil(&mut cfg);
            let err = cfg.validate().expect_err(field);
            assert!(err.contains(field), "{err}");
        }

        let parsed: AugmentConfig = toml::from_str("crop = [256, 320]\nswap_prob = 0.0\n").unwrap();
        assert_eq!(
            parsed,
            AugmentConfig {
                crop: [256, 320],
                swap_prob: 0.0,
                ..Default::default()
            }
        );
        assert!(toml::from_str::<AugmentConfig>("scale_range = [0.5, 1.0]\n").is_err());
        let json = serde_json::to_string(&AugmentConfig::default()).unwrap();
        assert_eq!(
            serde_json::from_str::<AugmentConfig>(&json).unwrap(),
            AugmentConfig::default()
        );
    }
}
