//! Which samples and which pixels an audit looks at: a pure function of the manifest and the seed,
//! so an audit can be repeated exactly.

use std::collections::BTreeMap;

use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

use crate::dataset::ManifestEntry;

/// Which samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SampleSelection {
    All,
    /// At most this many, spread over the categories.
    Count(usize),
}

/// Which pixels of each view.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelSelection {
    Every,
    /// This many distinct pixels per sample (the same positions in both views).
    Count(usize),
}

/// Positions in `entries` of the samples to audit, in manifest order. With a count, categories
/// take turns (each in its own seeded shuffle), so a small audit still covers every category.
pub fn choose_samples(
    entries: &[ManifestEntry],
    selection: SampleSelection,
    seed: u64,
) -> Vec<usize> {
    let k = match selection {
        SampleSelection::All => return (0..entries.len()).collect(),
        SampleSelection::Count(k) => k.min(entries.len()),
    };
    let mut by_category: BTreeMap<&str, Vec<usize>> = BTreeMap::new();
    for (i, e) in entries.iter().enumerate() {
        by_category.entry(&e.category).or_default().push(i);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut queues: Vec<std::vec::IntoIter<usize>> = by_category
        .into_values()
        .map(|mut v| {
            v.shuffle(&mut rng);
            v.into_iter()
        })
        .collect();
    let mut chosen = Vec::with_capacity(k);
    while chosen.len() < k {
        for q in &mut queues {
            if chosen.len() < k
                && let Some(i) = q.next()
            {
                chosen.push(i);
            }
        }
    }
    chosen.sort_unstable();
    chosen
}

/// Pixel indices (y·width + x) to audit in a `width`×`height` sample, sorted.
pub fn choose_pixels(
    width: usize,
    height: usize,
    selection: PixelSelection,
    seed: u64,
    sample_index: u64,
) -> Vec<usize> {
    let n = width * height;
    match selection {
        PixelSelection::Every => (0..n).collect(),
        PixelSelection::Count(p) if p >= n => (0..n).collect(),
        PixelSelection::Count(p) => {
            let mut rng =
                ChaCha8Rng::seed_from_u64(seed ^ sample_index.wrapping_mul(0x9E37_79B9_7F4A_7C15));
            let mut v = rand::seq::index::sample(&mut rng, n, p).into_vec();
            v.sort_unstable();
            v
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stereo_io::SamplePaths;

    fn entry(i: u64, category: &str) -> ManifestEntry {
        let id = format!("{i:07}");
        ManifestEntry {
            files: SamplePaths::new(category, &id),
            id,
            category: category.into(),
            seed: 0,
            index: i,
            width: 8,
            height: 6,
            f_px: 10.0,
            baseline_m: 0.1,
            cx: 4.0,
            cy: 3.0,
            disparity_left: None,
            disparity_right: None,
            difficulty: None,
            render_seconds: 0.0,
            render_timings: Default::default(),
            notes: vec![],
            instances: Vec::new(),
            sha256: Default::default(),
            stereogen_version: String::new(),
        }
    }

    #[test]
    fn a_small_audit_covers_every_category_and_repeats() {
        let cats = [
            "tree",
            "tree",
            "tree",
            "tree",
            "hole",
            "shapenet",
            "shapenet",
            "reflective",
            "tree",
            "tree",
        ];
        let entries: Vec<ManifestEntry> = cats
            .iter()
            .enumerate()
            .map(|(i, c)| entry(i as u64, c))
            .collect();
        let chosen = choose_samples(&entries, SampleSelection::Count(4), 7);
        let mut seen: Vec<&str> = chosen
            .iter()
            .map(|&i| entries[i].category.as_str())
            .collect();
        seen.sort();
        assert_eq!(seen, ["hole", "reflective", "shapenet", "tree"]);
        assert_eq!(
            chosen,
            choose_samples(&entries, SampleSelection::Count(4), 7)
        );
        assert_eq!(
            choose_samples(&entries, SampleSelection::Count(99), 7).len(),
            10
        );
        assert_eq!(
            choose_samples(&entries, SampleSelection::All, 7),
            (0..10).collect::<Vec<_>>()
        );
    }

    #[test]
    fn pixels_are_distinct_and_repeat() {
        let p = choose_pixels(16, 8, PixelSelection::Count(20), 3, 5);
        assert_eq!(p.len(), 20);
        assert!(p.windows(2).all(|w| w[0] < w[1]) && p[19] < 128);
        assert_eq!(p, choose_pixels(16, 8, PixelSelection::Count(20), 3, 5));
        assert_ne!(p, choose_pixels(16, 8, PixelSelection::Count(20), 3, 6));
        assert_eq!(
            choose_pixels(4, 2, PixelSelection::Count(20), 3, 5).len(),
            8
        );
    }
}
