//! The pixel pass: every disparity EXR once (from its folder or its export's shard), in parallel and streamed into fixed-size
//! accumulators, never more than one pair per thread in memory.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use rayon::prelude::*;

use super::StatsOptions;
use super::files::{FileError, read_sample_file, verify_other_files};
use super::load::Loaded;
use crate::dataset::ManifestEntry;
use crate::plan::Dist;
use crate::validate::accumulate::{Binning, PixelAcc};

/// Upper end of the pixel histograms: the largest disparity the manifest reports, or the law's
/// maximum, with 2% headroom. Manifest summaries come from the maps themselves; a value beyond
/// this range is still counted (as `outside_range`).
pub fn pixel_hi(entries: &[ManifestEntry], law: &Dist) -> f64 {
    let manifest_max = entries
        .iter()
        .flat_map(|e| [e.disparity_left, e.disparity_right])
        .flatten()
        .map(|s| f64::from(s.max))
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max);
    let hi = manifest_max.max(law.support().1).max(1.0) * 1.02;
    // Round up to 2 significant digits so bins have readable edges.
    let scale = 10f64.powf(hi.log10().floor() - 1.0);
    (hi / scale).ceil() * scale
}

/// A line on stderr at every 10% of a large pass (from whichever thread crosses the mark).
struct Progress {
    total: usize,
    done: AtomicUsize,
    start: Instant,
}

impl Progress {
    fn new(total: usize) -> Self {
        Self {
            total,
            done: AtomicUsize::new(0),
            start: Instant::now(),
        }
    }

    fn tick(&self) {
        let n = self.done.fetch_add(1, Ordering::Relaxed) + 1;
        if self.total >= 2000 && n * 10 / self.total != (n - 1) * 10 / self.total {
            eprintln!(
                "stats: {n}/{} samples read ({:.0} s)",
                self.total,
                self.start.elapsed().as_secs_f64()
            );
        }
    }
}

/// The pixel accumulators per category (`None`: no map of it could be read), and the files that
/// could not be read or failed verification.
pub struct PixelPass {
    pub accs: Vec<Option<PixelAcc>>,
    pub errors: Vec<FileError>,
}

impl PixelPass {
    fn empty(categories: usize) -> Self {
        Self {
            accs: vec![None; categories],
            errors: Vec::new(),
        }
    }

    fn merge(mut self, other: PixelPass) -> Self {
        for (x, y) in self.accs.iter_mut().zip(other.accs) {
            match (x.as_mut(), y) {
                (Some(x), Some(y)) => x.merge(&y),
                (None, y) => *x = y,
                (Some(_), None) => {}
            }
        }
        self.errors.extend(other.errors);
        self
    }
}

/// `new_acc(c)`: a fresh accumulator for category `c` (its gap-check bins differ).
pub fn pixel_pass(
    loaded: &Loaded,
    opts: &StatsOptions,
    new_acc: impl Fn(usize) -> PixelAcc + Sync,
) -> PixelPass {
    let categories = loaded.categories.len();
    let progress = Progress::new(loaded.entries.len());
    loaded
        .entries
        .par_iter()
        .fold(
            || PixelPass::empty(categories),
            |mut pass, e| {
                let c = loaded.category_of(e);
                let files = &loaded.files;
                for (view, key) in ["disp_left", "disp_right"].into_iter().enumerate() {
                    let read = read_sample_file(files, e, key, opts.verify).and_then(|bytes| {
                        stereo_io::decode_disparity_exr(&bytes, &files.path(e, key))
                            .map_err(FileError::Io)
                    });
                    match read {
                        Ok((map, _)) => pass.accs[c]
                            .get_or_insert_with(|| new_acc(c))
                            .add_map(view, &map),
                        Err(err) => pass.errors.push(err),
                    }
                }
                if opts.verify {
                    pass.errors.extend(verify_other_files(files, e));
                }
                progress.tick();
                pass
            },
        )
        .reduce(|| PixelPass::empty(categories), PixelPass::merge)
}

/// Width and height of the largest image (coverage bands are relative, so sizes may differ).
pub fn largest_image(entries: &[ManifestEntry]) -> (usize, usize) {
    let width = entries.iter().map(|e| e.width as usize).max().unwrap_or(1);
    let height = entries.iter().map(|e| e.height as usize).max().unwrap_or(1);
    (width, height)
}

/// The binning of every pixel histogram of this dataset.
pub fn binning(loaded: &Loaded, law: &Dist, bins: usize) -> Binning {
    let (width, height) = largest_image(&loaded.entries);
    Binning::new(
        pixel_hi(&loaded.entries, law),
        law.support(),
        bins.clamp(1, 4096),
        width,
        height,
    )
}
