//! Step 1 of a measurement: which of the dataset's planned samples are rendered.

use std::collections::{BTreeMap, BTreeSet};

use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::plan::{Recipe, scene_category};

/// Draws which samples to measure: `k` indices of `start..start+count`, spread over the
/// categories by weight (largest remainder), at least one per category of positive weight when
/// `k` allows; random, from `sample_seed`.
pub fn pick_indices(
    recipe: &Recipe,
    seed: u64,
    start: u64,
    count: u64,
    k: u64,
    sample_seed: u64,
) -> Vec<u64> {
    let k = k.min(count);
    let quotas = quotas(recipe, k);
    let mut want: BTreeMap<&str, u64> = recipe
        .categories
        .iter()
        .zip(&quotas)
        .map(|(c, &q)| (c.name.as_str(), q))
        .collect();
    let mut rng = ChaCha8Rng::seed_from_u64(sample_seed);
    const DRAWS: u64 = 200_000;
    let candidates: Vec<u64> = if count <= DRAWS {
        let mut all: Vec<u64> = (start..start + count).collect();
        all.shuffle(&mut rng);
        all
    } else {
        (0..DRAWS)
            .map(|_| start + rng.random_range(0..count))
            .collect()
    };
    let mut picked = BTreeSet::new();
    let mut spare = Vec::new();
    for i in candidates {
        if picked.len() as u64 == k {
            break;
        }
        if picked.contains(&i) {
            continue;
        }
        let name = scene_category(recipe, seed, i).name.as_str();
        match want.get_mut(name) {
            Some(q) if *q > 0 => {
                *q -= 1;
                picked.insert(i);
            }
            _ if spare.len() < k as usize => spare.push(i),
            _ => {}
        }
    }
    // A category too rare to be met in the draws leaves its share to the others.
    for i in spare {
        if picked.len() as u64 >= k {
            break;
        }
        picked.insert(i);
    }
    picked.into_iter().collect()
}

/// Samples per category: one each (of positive weight) first, the rest by largest remainder.
fn quotas(recipe: &Recipe, k: u64) -> Vec<u64> {
    let weights: Vec<f64> = recipe
        .categories
        .iter()
        .map(|c| c.weight.max(0.0))
        .collect();
    let positive = weights.iter().filter(|w| **w > 0.0).count() as u64;
    let mut q = vec![0u64; weights.len()];
    let mut left = k;
    if k >= positive {
        for (q, w) in q.iter_mut().zip(&weights) {
            if *w > 0.0 {
                *q = 1;
            }
        }
        left -= positive;
    }
    let total: f64 = weights.iter().sum();
    let shares: Vec<f64> = weights.iter().map(|w| w / total * left as f64).collect();
    let mut given = 0;
    for (q, s) in q.iter_mut().zip(&shares) {
        *q += s.floor() as u64;
        given += s.floor() as u64;
    }
    let mut order: Vec<usize> = (0..weights.len()).collect();
    order.sort_by(|&a, &b| {
        let (ra, rb) = (shares[a] - shares[a].floor(), shares[b] - shares[b].floor());
        rb.total_cmp(&ra).then(a.cmp(&b))
    });
    for &i in order.iter().take((left - given) as usize) {
        q[i] += 1;
    }
    q
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quotas_give_each_category_one_then_shares_by_weight() {
        let mut r = Recipe::preset("crestereo").unwrap();
        assert_eq!(quotas(&r, 8), vec![2, 2, 2, 2]);
        assert_eq!(quotas(&r, 2).iter().sum::<u64>(), 2);
        r.categories[0].weight = 0.7;
        for c in &mut r.categories[1..] {
            c.weight = 0.1;
        }
        assert_eq!(quotas(&r, 8), vec![4, 2, 1, 1]);
        r.categories[3].weight = 0.0;
        assert_eq!(quotas(&r, 8)[3], 0);
    }

    #[test]
    fn picked_indices_are_the_datasets_own_spread_over_categories_and_seeded() {
        let r = Recipe::preset("crestereo").unwrap();
        let a = pick_indices(&r, 3, 100, 200_000, 8, 0);
        assert_eq!(a, pick_indices(&r, 3, 100, 200_000, 8, 0));
        assert_ne!(a, pick_indices(&r, 3, 100, 200_000, 8, 1));
        assert_eq!(a.len(), 8);
        assert!(a.iter().all(|i| (100..200_100).contains(i)));
        let mut per: BTreeMap<String, usize> = BTreeMap::new();
        for &i in &a {
            *per.entry(scene_category(&r, 3, i).name.clone())
                .or_default() += 1;
        }
        assert!(per.values().all(|&n| n == 2), "{per:?}");
        // A short range: every index at most once.
        assert_eq!(pick_indices(&r, 3, 0, 5, 8, 0).len(), 5);
    }
}
