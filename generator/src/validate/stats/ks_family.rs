//! The object-level KS tests of a dataset (each category and `all`) as one family: a dataset
//! that follows its law fails any of them with probability at most `alpha` (Holm's step-down,
//! valid whatever the dependence between the tests; `all` shares its objects with the
//! categories). Each test on its own at `alpha` would raise a false alarm on about `m·alpha` of
//! correct datasets.
//!
//! The tests are ordered by p-value, smallest first; the i-th (0-based) of the m judged tests is
//! run at level `alpha / (m − i)` until one passes, and that one and all after it pass. A test's
//! p-value and critical value come from the same asymptotic formula ([`ks_critical`]), so the
//! order by p-value is the order by `d · (√n + 0.12 + 0.11/√n)`, and "p < level" is "d > critical
//! at level".

use super::stats_report::{MIN_OBJECTS_TO_JUDGE, ObjectStats};
use crate::plan::dist::ks_critical;

/// `d · (√n + 0.12 + 0.11/√n)`: the larger, the smaller the test's p-value.
fn strength(d: f64, n: usize) -> f64 {
    let r = (n as f64).sqrt();
    d * (r + 0.12 + 0.11 / r)
}

/// Sets `ks_level` and `ks_critical` of every judged group (at least [`MIN_OBJECTS_TO_JUDGE`]
/// objects) by Holm's step-down at family rate `alpha`; the others keep neither.
pub fn holm_levels(groups: &mut [&mut ObjectStats], alpha: f64) {
    let mut judged: Vec<&mut ObjectStats> = groups
        .iter_mut()
        .map(|g| &mut **g)
        .filter(|g| g.count >= MIN_OBJECTS_TO_JUDGE && g.ks_distance.is_some())
        .collect();
    let key = |g: &ObjectStats| strength(g.ks_distance.unwrap_or(0.0), g.count);
    judged.sort_by(|a, b| key(b).total_cmp(&key(a)));
    let m = judged.len();
    let mut stopped_at: Option<f64> = None;
    for (i, g) in judged.into_iter().enumerate() {
        let level = stopped_at.unwrap_or(alpha / (m - i) as f64);
        let critical = ks_critical(g.count, level);
        g.ks_level = Some(level);
        g.ks_critical = Some(critical);
        if stopped_at.is_none() && g.ks_distance.is_some_and(|d| d <= critical) {
            // The first test that passes ends the step-down: the rest pass at its level.
            stopped_at = Some(level);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::Dist;

    fn group(d: f64, n: usize) -> ObjectStats {
        let mut s = ObjectStats::new(&mut vec![1.0; n], &Dist::uniform(0.0, 2.0));
        s.ks_distance = Some(d);
        s
    }

    #[test]
    fn the_stated_minimum_is_where_the_critical_value_reaches_one_half() {
        assert!(ks_critical(MIN_OBJECTS_TO_JUDGE, 0.01 / 5.0) <= 0.5);
        assert!(ks_critical(MIN_OBJECTS_TO_JUDGE - 1, 0.01 / 5.0) > 0.5);
    }

    #[test]
    fn holm_steps_down_until_a_test_passes() {
        let (mut a, mut b, mut c, mut small) = (
            group(0.9, 100),
            group(0.2, 100),
            group(0.01, 100),
            group(0.9, 5),
        );
        holm_levels(&mut [&mut c, &mut a, &mut small, &mut b], 0.01);
        // Three judged tests, smallest p-value first: a at 0.01/3, b at 0.01/2, then c at 0.01.
        assert_eq!(a.ks_level, Some(0.01 / 3.0));
        assert_eq!(b.ks_level, Some(0.01 / 2.0));
        assert!(
            b.ks_distance.unwrap() > b.ks_critical.unwrap(),
            "b is rejected"
        );
        assert_eq!(c.ks_level, Some(0.01));
        assert_eq!((small.ks_level, small.ks_critical), (None, None));
        // A first test that passes stops the step-down: the later ones pass at its level.
        let (mut x, mut y) = (group(0.05, 100), group(0.04, 100));
        holm_levels(&mut [&mut y, &mut x], 0.01);
        assert_eq!(x.ks_level, Some(0.005));
        assert_eq!(y.ks_level, Some(0.005));
    }
}
