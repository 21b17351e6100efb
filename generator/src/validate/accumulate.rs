//! Streaming pixel-level accumulators: one disparity map at a time goes in, fixed-size histograms
//! stay. Accumulators of the same binning merge, so a parallel pass folds per thread and reduces.

use stereo_io::DisparityMap;

use super::hist::{EdgeHist, UniformHist};

/// Bins of all pixel-level histograms of one stats run (shared by every category so they merge).
#[derive(Debug, Clone, PartialEq)]
pub struct Binning {
    /// Upper end of the full-range histograms (px); their lower end is 0.
    pub hi: f64,
    /// Bins of the fine full-range histogram that percentiles are read from.
    pub fine_bins: usize,
    /// Range and bins of the histogram inside the law's support (written and plotted).
    pub support: (f64, f64),
    pub display_bins: usize,
    /// Disparity bins of each row/column coverage histogram.
    pub coverage_bins: usize,
    /// Image rows and columns are grouped into this many bands (by relative position).
    pub rows: usize,
    pub cols: usize,
    /// Pixels at or above this disparity count as content (the law's minimum: recipes keep the
    /// background wall below it); row/column disparity bands describe content pixels only.
    pub content_min: f64,
}

/// Fine bins of the full-range histogram: percentiles resolve `hi / FINE_BINS`.
pub const FINE_BINS: usize = 16384;

impl Binning {
    /// `support`: the law's support (widened by 0.5 px each side when it is a single value).
    pub fn new(
        hi: f64,
        support: (f64, f64),
        display_bins: usize,
        width: usize,
        height: usize,
    ) -> Self {
        let (lo, up) = if support.1 > support.0 {
            support
        } else {
            (support.0 - 0.5, support.1 + 0.5)
        };
        Self {
            hi,
            fine_bins: FINE_BINS,
            support: (lo, up),
            display_bins: display_bins.max(1),
            coverage_bins: 256,
            rows: height.clamp(1, 96),
            cols: width.clamp(1, 128),
            content_min: support.0,
        }
    }
}

/// One view's valid/invalid counts and value summary.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewAcc {
    pub fine: UniformHist,
    pub pixels: u64,
    pub invalid: u64,
    /// Pixels flagged valid whose value is NaN or infinite (broken ground truth).
    pub nonfinite: u64,
    pub sum: f64,
    pub min: f64,
    pub max: f64,
}

impl ViewAcc {
    fn new(b: &Binning) -> Self {
        Self {
            fine: UniformHist::new(0.0, b.hi, b.fine_bins),
            pixels: 0,
            invalid: 0,
            nonfinite: 0,
            sum: 0.0,
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
        }
    }

    fn merge(&mut self, o: &Self) {
        self.fine.merge(&o.fine);
        self.pixels += o.pixels;
        self.invalid += o.invalid;
        self.nonfinite += o.nonfinite;
        self.sum += o.sum;
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
    }

    pub fn valid(&self) -> u64 {
        self.pixels - self.invalid - self.nonfinite
    }
}

/// Disparity by image row (or column) band: pixel, valid and content counts per band, and a
/// histogram and sum of the content pixels' disparities.
#[derive(Debug, Clone, PartialEq)]
pub struct Coverage {
    pub hists: Vec<UniformHist>,
    pub sums: Vec<f64>,
    pub content: Vec<u64>,
    pub valid: Vec<u64>,
    pub pixels: Vec<u64>,
}

impl Coverage {
    fn new(bands: usize, b: &Binning) -> Self {
        let z = vec![0; bands];
        Self {
            hists: vec![UniformHist::new(0.0, b.hi, b.coverage_bins); bands],
            sums: vec![0.0; bands],
            content: z.clone(),
            valid: z.clone(),
            pixels: z,
        }
    }

    fn merge(&mut self, o: &Self) {
        for (a, b) in self.hists.iter_mut().zip(&o.hists) {
            a.merge(b);
        }
        for i in 0..self.sums.len() {
            self.sums[i] += o.sums[i];
            self.content[i] += o.content[i];
            self.valid[i] += o.valid[i];
            self.pixels[i] += o.pixels[i];
        }
    }

    /// Band of position `i` out of `n` (rows or columns of one map).
    #[inline]
    fn band(&self, i: usize, n: usize) -> usize {
        (i * self.sums.len() / n.max(1)).min(self.sums.len() - 1)
    }
}

/// Everything the pixel-level statistics of one category need.
#[derive(Debug, Clone, PartialEq)]
pub struct PixelAcc {
    /// Left and right views.
    pub views: [ViewAcc; 2],
    /// Both views, display bins over the law's support.
    pub display: UniformHist,
    /// Gap-check bins of this category (equal-mass bins of the law for its object count).
    pub gap: Option<EdgeHist>,
    /// Gap-check bins of the whole dataset, so the overall check can merge categories.
    pub gap_all: Option<EdgeHist>,
    pub rows: Coverage,
    pub cols: Coverage,
    pub content_min: f64,
    pub maps: u64,
}

impl PixelAcc {
    pub fn new(b: &Binning, gap_edges: Option<&[f64]>, all_edges: Option<&[f64]>) -> Self {
        Self {
            views: [ViewAcc::new(b), ViewAcc::new(b)],
            display: UniformHist::new(b.support.0, b.support.1, b.display_bins),
            gap: gap_edges.map(|e| EdgeHist::new(e.to_vec())),
            gap_all: all_edges.map(|e| EdgeHist::new(e.to_vec())),
            rows: Coverage::new(b.rows, b),
            cols: Coverage::new(b.cols, b),
            content_min: b.content_min,
            maps: 0,
        }
    }

    /// Adds every pixel of one view's map (`view` 0 = left, 1 = right).
    pub fn add_map(&mut self, view: usize, map: &DisparityMap) {
        let (w, h) = (map.width, map.height);
        let content_min = self.content_min;
        let col_band: Vec<usize> = (0..w).map(|x| self.cols.band(x, w)).collect();
        let v = &mut self.views[view];
        v.pixels += (w * h) as u64;
        for y in 0..h {
            let rb = self.rows.band(y, h);
            self.rows.pixels[rb] += w as u64;
            let row = &map.data[y * w..(y + 1) * w];
            let valid = &map.valid[y * w..(y + 1) * w];
            for x in 0..w {
                let cb = col_band[x];
                self.cols.pixels[cb] += 1;
                if !valid[x] {
                    v.invalid += 1;
                    continue;
                }
                let d = f64::from(row[x]);
                if !d.is_finite() {
                    v.nonfinite += 1;
                    continue;
                }
                v.fine.add(d);
                v.sum += d;
                v.min = v.min.min(d);
                v.max = v.max.max(d);
                self.display.add(d);
                if let Some(g) = &mut self.gap {
                    g.add(d);
                }
                if let Some(g) = &mut self.gap_all {
                    g.add(d);
                }
                self.rows.valid[rb] += 1;
                self.cols.valid[cb] += 1;
                if d >= content_min {
                    self.rows.content[rb] += 1;
                    self.rows.hists[rb].add(d);
                    self.rows.sums[rb] += d;
                    self.cols.content[cb] += 1;
                    self.cols.hists[cb].add(d);
                    self.cols.sums[cb] += d;
                }
            }
        }
        self.maps += 1;
    }

    /// Adds `o`; the category-specific gap bins are kept only if both have the same ones.
    pub fn merge(&mut self, o: &Self) {
        self.views[0].merge(&o.views[0]);
        self.views[1].merge(&o.views[1]);
        self.display.merge(&o.display);
        match (&mut self.gap, &o.gap) {
            (Some(a), Some(b)) if a.edges == b.edges => a.merge(b),
            (a, _) => *a = None,
        }
        if let (Some(a), Some(b)) = (&mut self.gap_all, &o.gap_all) {
            a.merge(b);
        }
        self.rows.merge(&o.rows);
        self.cols.merge(&o.cols);
        self.maps += o.maps;
    }

    /// Fine histogram of both views together.
    pub fn fine_both(&self) -> UniformHist {
        let mut h = self.views[0].fine.clone();
        h.merge(&self.views[1].fine);
        h
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(w: usize, h: usize, f: impl Fn(usize, usize) -> Option<f32>) -> DisparityMap {
        let mut m = DisparityMap::new(w, h);
        for y in 0..h {
            for x in 0..w {
                if let Some(d) = f(x, y) {
                    m.data[y * w + x] = d;
                    m.valid[y * w + x] = true;
                }
            }
        }
        m
    }

    /// Ten 1-px display and coverage bins over 0..10 px (the law's support), two row bands.
    fn binning_0_to_10(fine_bins: usize, cols: usize, content_min: f64) -> Binning {
        Binning {
            hi: 10.0,
            fine_bins,
            support: (0.0, 10.0),
            display_bins: 10,
            coverage_bins: 10,
            rows: 2,
            cols,
            content_min,
        }
    }

    #[test]
    fn counts_valid_invalid_and_bands() {
        let b = binning_0_to_10(100, 4, 2.0);
        let mut acc = PixelAcc::new(&b, Some(&[0.0, 5.0, 10.0]), None);
        // 4x2 map: top row valid with disparity x+1 (1..4), bottom row invalid except x=3 (NaN).
        let m = map(4, 2, |x, y| {
            if y == 0 {
                Some(x as f32 + 1.0)
            } else if x == 3 {
                Some(f32::NAN)
            } else {
                None
            }
        });
        acc.add_map(0, &m);
        let v = &acc.views[0];
        assert_eq!((v.pixels, v.invalid, v.nonfinite, v.valid()), (8, 3, 1, 4));
        assert_eq!((v.min, v.max, v.sum), (1.0, 4.0, 10.0));
        assert_eq!(acc.display.counts, vec![0, 1, 1, 1, 1, 0, 0, 0, 0, 0]);
        assert_eq!(acc.gap.as_ref().unwrap().counts, vec![4, 0]);
        assert_eq!(acc.rows.valid, vec![4, 0]);
        assert_eq!(acc.rows.pixels, vec![4, 4]);
        // Content pixels (disparity >= 2) only: 2 + 3 + 4.
        assert_eq!(acc.rows.content, vec![3, 0]);
        assert_eq!(acc.rows.sums, vec![9.0, 0.0]);
        assert_eq!(acc.cols.valid, vec![1, 1, 1, 1]);
        assert_eq!(acc.cols.content, vec![0, 1, 1, 1]);
        assert_eq!(acc.cols.sums, vec![0.0, 2.0, 3.0, 4.0]);
        // Merging doubles every count.
        let mut twice = acc.clone();
        twice.merge(&acc);
        assert_eq!(twice.views[0].valid(), 8);
        assert_eq!(twice.gap.as_ref().unwrap().counts, vec![8, 0]);
        assert_eq!(twice.maps, 2);
        // Different category gap bins cannot merge: the merged accumulator has none.
        let other = PixelAcc::new(&b, Some(&[0.0, 2.0, 10.0]), None);
        twice.merge(&other);
        assert!(twice.gap.is_none());
    }

    #[test]
    fn bands_follow_relative_position() {
        let b = binning_0_to_10(10, 2, 0.0);
        let mut acc = PixelAcc::new(&b, None, None);
        // A 6x3 map: rows 0 and 1 go to band 0 (y*2/3 = 0, 0), row 2 to band 1.
        acc.add_map(1, &map(6, 3, |_, y| Some(y as f32)));
        assert_eq!(acc.rows.valid, vec![12, 6]);
        assert_eq!(acc.rows.sums, vec![6.0, 12.0]);
        assert_eq!(acc.cols.valid, vec![9, 9]);
    }
}
