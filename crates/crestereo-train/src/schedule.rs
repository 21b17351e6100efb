//! The paper's learning-rate schedule: linear warm-up from a fraction of the base rate, constant,
//! then linear decay back down to that fraction by the last step (reference `train.py`: 5% over
//! the first 6k steps, decay from 180k to 300k).

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LrScheduleConfig {
    pub base_lr: f64,
    /// Fraction of `base_lr` at step 0 and at the last step.
    pub floor_fraction: f64,
    pub warmup_steps: u64,
    pub decay_start: u64,
    pub total_steps: u64,
}

impl Default for LrScheduleConfig {
    fn default() -> Self {
        Self {
            base_lr: 4e-4,
            floor_fraction: 0.05,
            warmup_steps: 6_000,
            decay_start: 180_000,
            total_steps: 300_000,
        }
    }
}

impl LrScheduleConfig {
    /// Checks the phases are in order.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.base_lr > 0.0 && self.base_lr.is_finite()) {
            return Err(format!("base_lr must be > 0, got {}", self.base_lr));
        }
        if !(0.0..=1.0).contains(&self.floor_fraction) {
            return Err(format!(
                "floor_fraction must be in 0..=1, got {}",
                self.floor_fraction
            ));
        }
        if !(self.warmup_steps <= self.decay_start && self.decay_start <= self.total_steps) {
            return Err(format!(
                "need warmup_steps ({}) <= decay_start ({}) <= total_steps ({})",
                self.warmup_steps, self.decay_start, self.total_steps
            ));
        }
        Ok(())
    }

    /// Learning rate at `step` (0-based).
    pub fn lr(&self, step: u64) -> f64 {
        let lerp = |a: f64, b: f64, t: f64| a + (b - a) * t.clamp(0.0, 1.0);
        let floor = self.floor_fraction;
        let factor = if step < self.warmup_steps {
            lerp(floor, 1.0, step as f64 / self.warmup_steps as f64)
        } else if step < self.decay_start {
            1.0
        } else {
            let span = (self.total_steps - self.decay_start).max(1) as f64;
            lerp(1.0, floor, (step - self.decay_start) as f64 / span)
        };
        self.base_lr * factor
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_schedule_at_its_corners() {
        let s = LrScheduleConfig::default();
        s.validate().unwrap();
        let close = |a: f64, b: f64| (a - b).abs() < 1e-15;
        assert!(close(s.lr(0), 2e-5));
        assert!(close(s.lr(3_000), 4e-4 * 0.525));
        assert!(close(s.lr(6_000), 4e-4));
        assert!(close(s.lr(179_999), 4e-4));
        assert!(close(s.lr(240_000), 4e-4 * 0.525));
        assert!(close(s.lr(300_000), 2e-5));
        assert!(close(s.lr(400_000), 2e-5));
        let bad = LrScheduleConfig {
            decay_start: 1_000,
            ..s
        };
        assert!(bad.validate().unwrap_err().contains("warmup_steps"));
    }
}
