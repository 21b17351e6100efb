//! Histograms, percentiles, law quantiles and the bin-count rules of `stereogen stats`.
//!
//! Pixel counts are too large to keep, so pixel-level statistics stream into fixed histograms and
//! percentiles are read back from them; object-level samples are small and kept exactly.

use serde::Serialize;

use crate::plan::Dist;

/// The percentiles reported everywhere (in percent).
pub const PERCENTILES: [f64; 7] = [1.0, 5.0, 25.0, 50.0, 75.0, 95.0, 99.0];

/// Most bins the gap check uses, however large the sample.
pub const MAX_GAP_BINS: usize = 64;

/// Percentiles 1, 5, 25, 50, 75, 95, 99.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Percentiles {
    pub p1: f64,
    pub p5: f64,
    pub p25: f64,
    pub p50: f64,
    pub p75: f64,
    pub p95: f64,
    pub p99: f64,
}

impl Percentiles {
    /// From a function that maps a fraction in 0..=1 to a value; `None` when it has no data.
    pub fn from_fn(q: impl Fn(f64) -> Option<f64>) -> Option<Self> {
        let v: Vec<f64> = PERCENTILES
            .iter()
            .map(|p| q(p / 100.0))
            .collect::<Option<_>>()?;
        Some(Self {
            p1: v[0],
            p5: v[1],
            p25: v[2],
            p50: v[3],
            p75: v[4],
            p95: v[5],
            p99: v[6],
        })
    }
}

/// Equal-width bins over `[lo, hi]` (the last bin includes `hi`), with counts of the values
/// below and above the range.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct UniformHist {
    pub lo: f64,
    pub hi: f64,
    pub counts: Vec<u64>,
    pub below: u64,
    pub above: u64,
}

impl UniformHist {
    pub fn new(lo: f64, hi: f64, bins: usize) -> Self {
        assert!(
            bins > 0 && hi > lo,
            "a histogram needs bins > 0 and hi > lo"
        );
        Self {
            lo,
            hi,
            counts: vec![0; bins],
            below: 0,
            above: 0,
        }
    }

    pub fn bins(&self) -> usize {
        self.counts.len()
    }

    pub fn bin_width(&self) -> f64 {
        (self.hi - self.lo) / self.counts.len() as f64
    }

    pub fn edges(&self) -> Vec<f64> {
        let w = self.bin_width();
        (0..=self.bins()).map(|i| self.lo + i as f64 * w).collect()
    }

    #[inline]
    pub fn add(&mut self, x: f64) {
        if x < self.lo {
            self.below += 1;
        } else if x > self.hi {
            self.above += 1;
        } else {
            let n = self.counts.len();
            let i = ((x - self.lo) / (self.hi - self.lo) * n as f64) as usize;
            self.counts[i.min(n - 1)] += 1;
        }
    }

    pub fn merge(&mut self, other: &Self) {
        assert!(
            self.lo == other.lo && self.hi == other.hi && self.bins() == other.bins(),
            "merging histograms with different bins"
        );
        for (a, b) in self.counts.iter_mut().zip(&other.counts) {
            *a += b;
        }
        self.below += other.below;
        self.above += other.above;
    }

    /// All values counted, inside the range or not.
    pub fn total(&self) -> u64 {
        self.counts.iter().sum::<u64>() + self.below + self.above
    }

    /// The value below which a fraction `q` of all counted values lie. Counts of a bin are taken
    /// as spread evenly across it (linear interpolation); values below/above the range count as
    /// `lo`/`hi`. `None` when the histogram is empty.
    pub fn quantile(&self, q: f64) -> Option<f64> {
        let n = self.total();
        if n == 0 {
            return None;
        }
        let target = q.clamp(0.0, 1.0) * n as f64;
        let mut acc = self.below as f64;
        if self.below > 0 && target <= acc {
            return Some(self.lo);
        }
        let w = self.bin_width();
        for (i, &c) in self.counts.iter().enumerate() {
            if c > 0 && acc + c as f64 >= target {
                let frac = ((target - acc) / c as f64).clamp(0.0, 1.0);
                return Some(self.lo + (i as f64 + frac) * w);
            }
            acc += c as f64;
        }
        Some(self.hi)
    }

    /// The histogram with `factor` adjacent bins summed (for coarser display).
    pub fn coarsen(&self, factor: usize) -> Self {
        assert!(
            factor > 0 && self.bins().is_multiple_of(factor),
            "coarsening factor must divide the bin count"
        );
        let counts = self.counts.chunks(factor).map(|c| c.iter().sum()).collect();
        Self {
            lo: self.lo,
            hi: self.hi,
            counts,
            below: self.below,
            above: self.above,
        }
    }
}

/// Bins between arbitrary increasing edges; the last bin includes its upper edge.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EdgeHist {
    pub edges: Vec<f64>,
    pub counts: Vec<u64>,
    pub outside: u64,
}

impl EdgeHist {
    pub fn new(edges: Vec<f64>) -> Self {
        assert!(
            edges.len() >= 2 && edges.windows(2).all(|w| w[1] > w[0]),
            "edges must increase"
        );
        let n = edges.len() - 1;
        Self {
            edges,
            counts: vec![0; n],
            outside: 0,
        }
    }

    #[inline]
    pub fn add(&mut self, x: f64) {
        let (lo, hi) = (self.edges[0], self.edges[self.edges.len() - 1]);
        if !(lo..=hi).contains(&x) {
            self.outside += 1;
            return;
        }
        let last = self.counts.len() - 1;
        let i = self.edges.partition_point(|e| *e <= x).saturating_sub(1);
        self.counts[i.min(last)] += 1;
    }

    pub fn merge(&mut self, other: &Self) {
        assert_eq!(
            self.edges, other.edges,
            "merging histograms with different edges"
        );
        for (a, b) in self.counts.iter_mut().zip(&other.counts) {
            *a += b;
        }
        self.outside += other.outside;
    }

    /// The `[lo, hi)` ranges of the bins that counted nothing.
    pub fn empty_bins(&self) -> Vec<[f64; 2]> {
        self.counts
            .iter()
            .enumerate()
            .filter(|(_, c)| **c == 0)
            .map(|(i, _)| [self.edges[i], self.edges[i + 1]])
            .collect()
    }
}

/// Linear-interpolation percentile of a sorted sample (numpy's default): position `q·(n−1)`.
pub fn quantile_sorted(sorted: &[f64], q: f64) -> Option<f64> {
    let n = sorted.len();
    if n == 0 {
        return None;
    }
    let pos = q.clamp(0.0, 1.0) * (n - 1) as f64;
    let i = pos.floor() as usize;
    let frac = pos - i as f64;
    Some(if i + 1 < n {
        sorted[i] + frac * (sorted[i + 1] - sorted[i])
    } else {
        sorted[n - 1]
    })
}

/// The law's quantile: the `x` in its support with `cdf(x) = q` (bisection on the CDF).
pub fn law_quantile(law: &Dist, q: f64) -> f64 {
    let (mut lo, mut hi) = law.support();
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if law.cdf(mid) < q { lo = mid } else { hi = mid }
    }
    0.5 * (lo + hi)
}

/// The law's density, as the mass of each of `cells` equal cells over `[lo, hi]` divided by the
/// cell width: `(x_centre, density)` points of a curve that keeps the law's steep edges.
pub fn law_density(law: &Dist, lo: f64, hi: f64, cells: usize) -> Vec<(f64, f64)> {
    let w = (hi - lo) / cells as f64;
    (0..cells)
        .map(|i| {
            let a = lo + i as f64 * w;
            (a + 0.5 * w, (law.cdf(a + w) - law.cdf(a)) / w)
        })
        .collect()
}

/// Number of equal-mass bins for the gap check with `n` objects at significance `alpha`.
///
/// If `n` object disparities follow the law, a given bin of `k` equal-mass bins receives none of
/// them with probability `(1 − 1/k)^n`, so the chance that a correct dataset shows any empty bin is
/// at most `k·(1 − 1/k)^n` (union bound). The rule takes the largest `k ≤ MAX_GAP_BINS` that keeps
/// this at or below `alpha` (at 0.01: 8 objects allow 2 bins, 15 allow 3, 60 allow 9, 300 allow 37,
/// 1000 and more 64). Every visible object puts pixels near its target, so pixel-level bins are
/// about as well filled.
/// Returns 0 (no check possible) when `n == 0`.
pub fn gap_bins_for(n: usize, alpha: f64) -> usize {
    if n == 0 {
        return 0;
    }
    let miss = |k: usize| k as f64 * (1.0 - 1.0 / k as f64).powi(n.min(i32::MAX as usize) as i32);
    (1..=MAX_GAP_BINS)
        .take_while(|&k| miss(k) <= alpha)
        .last()
        .unwrap_or(1)
}

/// Bin edges at the law's quantiles `0, 1/k, …, 1`: each bin holds `1/k` of its mass.
pub fn equal_mass_edges(law: &Dist, k: usize) -> Vec<f64> {
    let (min, max) = law.support();
    let mut edges: Vec<f64> = (0..=k)
        .map(|i| {
            if i == 0 {
                min
            } else if i == k {
                max
            } else {
                law_quantile(law, i as f64 / k as f64)
            }
        })
        .collect();
    edges.dedup_by(|b, a| *b <= *a);
    edges
}

/// Rice rule for the object-level histograms: `⌈2·n^{1/3}⌉` bins, between 4 and 64.
pub fn rice_bins(n: usize) -> usize {
    ((2.0 * (n as f64).cbrt()).ceil() as usize).clamp(4, 64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uniform_hist_bins_and_edges() {
        let mut h = UniformHist::new(0.0, 4.0, 4);
        for x in [0.0, 0.5, 1.0, 3.999, 4.0, -1.0, 4.5, 2.2] {
            h.add(x);
        }
        // 0.0, 0.5 -> bin 0; 1.0 -> bin 1; 2.2 -> bin 2; 3.999 and 4.0 (last bin is closed) -> bin 3.
        assert_eq!(h.counts, vec![2, 1, 1, 2]);
        assert_eq!((h.below, h.above, h.total()), (1, 1, 8));
        assert_eq!(h.edges(), vec![0.0, 1.0, 2.0, 3.0, 4.0]);
        assert_eq!(h.coarsen(2).counts, vec![3, 3]);
    }

    #[test]
    fn hist_quantiles_interpolate_inside_bins() {
        let mut h = UniformHist::new(0.0, 4.0, 4);
        for x in [0.5, 1.5, 2.5, 3.5] {
            h.add(x);
        }
        // Median: 2 of 4 values lie below 2.0 when each bin's value is spread over it.
        assert_eq!(h.quantile(0.5), Some(2.0));
        assert_eq!(h.quantile(0.25), Some(1.0));
        assert_eq!(h.quantile(0.125), Some(0.5));
        assert_eq!(h.quantile(1.0), Some(4.0));
        // Ten values in one bin [1, 2): the 30th percentile is 30% into it.
        let mut h = UniformHist::new(0.0, 4.0, 4);
        (0..10).for_each(|_| h.add(1.2));
        assert!((h.quantile(0.3).unwrap() - 1.3).abs() < 1e-12);
        assert_eq!(UniformHist::new(0.0, 1.0, 3).quantile(0.5), None);
        // Below-range values sit at lo.
        let mut h = UniformHist::new(0.0, 4.0, 4);
        h.add(-3.0);
        h.add(3.5);
        assert_eq!(h.quantile(0.25), Some(0.0));
    }

    #[test]
    fn sorted_quantiles_match_numpy() {
        // numpy.percentile([1, 2, 3, 4, 5], [25, 50, 99]) = [2, 3, 4.96]
        let xs = [1.0, 2.0, 3.0, 4.0, 5.0];
        assert_eq!(quantile_sorted(&xs, 0.25), Some(2.0));
        assert_eq!(quantile_sorted(&xs, 0.5), Some(3.0));
        assert!((quantile_sorted(&xs, 0.99).unwrap() - 4.96).abs() < 1e-12);
        assert_eq!(quantile_sorted(&[1.0, 2.0, 3.0, 4.0], 0.5), Some(2.5));
        assert_eq!(quantile_sorted(&[7.0], 0.3), Some(7.0));
        assert_eq!(quantile_sorted(&[], 0.3), None);
        let p = Percentiles::from_fn(|q| quantile_sorted(&[0.0, 100.0], q)).unwrap();
        assert_eq!((p.p1, p.p5, p.p50, p.p99), (1.0, 5.0, 50.0, 99.0));
    }

    #[test]
    fn edge_hist_finds_empty_bins() {
        let mut h = EdgeHist::new(vec![2.0, 10.0, 40.0, 150.0, 240.0]);
        for x in [2.0, 9.9, 10.0, 151.0, 240.0, 1.0, 241.0] {
            h.add(x);
        }
        assert_eq!(h.counts, vec![2, 1, 0, 2]);
        assert_eq!(h.outside, 2);
        assert_eq!(h.empty_bins(), vec![[40.0, 150.0]]);
    }

    #[test]
    fn law_quantiles_and_density() {
        let u = Dist::uniform(2.0, 240.0);
        assert!((law_quantile(&u, 0.5) - 121.0).abs() < 1e-9);
        let e = equal_mass_edges(&u, 4);
        assert_eq!(e.len(), 5);
        for (a, b) in e.iter().zip([2.0, 61.5, 121.0, 180.5, 240.0]) {
            assert!((a - b).abs() < 1e-9, "{e:?}");
        }
        // Log-uniform on [1, 100]: the median is 10.
        assert!((law_quantile(&Dist::log_uniform(1.0, 100.0), 0.5) - 10.0).abs() < 1e-9);
        // Uniform density is 1/(max-min) inside and 0 outside.
        let d = law_density(&Dist::uniform(2.0, 4.0), 0.0, 6.0, 6);
        let ys: Vec<f64> = d.iter().map(|p| p.1).collect();
        assert_eq!(ys, vec![0.0, 0.0, 0.5, 0.5, 0.0, 0.0]);
    }

    #[test]
    fn gap_bin_rule() {
        // k·(1−1/k)^n ≤ 0.01, computed by hand: n=8 → 2·2^-8 = 0.0078 but 3·(2/3)^8 = 0.117.
        assert_eq!(gap_bins_for(8, 0.01), 2);
        assert_eq!(gap_bins_for(7, 0.01), 1);
        assert_eq!(gap_bins_for(15, 0.01), 3);
        assert_eq!(gap_bins_for(60, 0.01), 9);
        assert_eq!(gap_bins_for(0, 0.01), 0);
        assert_eq!(gap_bins_for(1_000_000, 0.01), MAX_GAP_BINS);
        assert_eq!(rice_bins(64), 8);
        assert_eq!(rice_bins(1), 4);
    }
}
