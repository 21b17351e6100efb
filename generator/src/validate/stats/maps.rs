//! The maps beside the disparity (a recipe's `[render] outputs`, [`stereo_io::maps`]), summarised
//! over the whole dataset, both views: every map file once, in parallel, into fixed-size
//! accumulators.
//!
//! - depth: min, median (from a histogram of log10 depth, 0.001 decade bins), max and mean of
//!   the surface pixels (depth > 0) in metres, and their share of all pixels;
//! - normals: the share of surface pixels whose normal lies within 30°, 60° and 90° of the
//!   direction back to the camera along the pixel's ray, and the share of unit length (within
//!   1e-3);
//! - instance: the instances visible per sample (distinct non-zero ids of either view), and the
//!   content objects among them (the manifest's `instances` table);
//! - semantic: each class's share of all pixels (id 0: no surface), named by the dataset's
//!   `semantic_classes`.
//!
//! A dataset without maps has no such summary, and `stats` says nothing about maps.

use std::collections::{BTreeMap, BTreeSet};

use rayon::prelude::*;
use serde::Serialize;
use stereo_io::MapKind;
use stereo_io::datasets::MapData;

use super::StatsOptions;
use super::files::{FileError, read_sample_file};
use super::load::Loaded;
use crate::dataset::ManifestEntry;
use crate::validate::hist::UniformHist;

/// Range of the log10 depth histogram (0.1 mm to 1000 km) and its bins (0.001 decade each).
const LOG_DEPTH: (f64, f64, usize) = (-4.0, 6.0, 10_000);
/// Bins of the log10 depth histogram written to stats.json (0.05 decade each).
const LOG_DEPTH_DISPLAY_BINS: usize = 200;
/// The angles of [`NormalStats::facing`], degrees.
pub const FACING_DEG: [f64; 3] = [30.0, 60.0, 90.0];
/// Bins of the histogram of normal angles over 0..180°.
const ANGLE_BINS: usize = 36;
/// How far from 1 a unit normal's length may be.
const UNIT_TOLERANCE: f64 = 1e-3;

#[derive(Debug, Clone)]
struct DepthAcc {
    pixels: u64,
    valid: u64,
    sum: f64,
    min: f64,
    max: f64,
    log10: UniformHist,
}

#[derive(Debug, Clone)]
struct NormalAcc {
    pixels: u64,
    surface: u64,
    facing: [u64; 3],
    unit: u64,
    angles: UniformHist,
}

/// The accumulators of one thread; merged at the end.
#[derive(Debug, Default)]
struct MapAcc {
    samples: BTreeMap<MapKind, u64>,
    depth: Option<DepthAcc>,
    normals: Option<NormalAcc>,
    /// Per sample: instances visible, content objects visible, instances listed.
    visible: Vec<[u32; 3]>,
    semantic: BTreeMap<u16, u64>,
    errors: Vec<FileError>,
}

impl MapAcc {
    fn add_depth(&mut self, m: &stereo_io::DepthMap) {
        let (lo, hi, bins) = LOG_DEPTH;
        let a = self.depth.get_or_insert_with(|| DepthAcc {
            pixels: 0,
            valid: 0,
            sum: 0.0,
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
            log10: UniformHist::new(lo, hi, bins),
        });
        a.pixels += m.data.len() as u64;
        for z in m.data.iter().map(|&z| f64::from(z)) {
            if z.is_finite() && z > 0.0 {
                a.valid += 1;
                a.sum += z;
                a.min = a.min.min(z);
                a.max = a.max.max(z);
                a.log10.add(z.log10());
            }
        }
    }

    fn add_normals(&mut self, m: &stereo_io::NormalMap, e: &ManifestEntry) {
        let a = self.normals.get_or_insert_with(|| NormalAcc {
            pixels: 0,
            surface: 0,
            facing: [0; 3],
            unit: 0,
            angles: UniformHist::new(0.0, 180.0, ANGLE_BINS),
        });
        a.pixels += m.data.len() as u64;
        let cos_limits = FACING_DEG.map(|d| d.to_radians().cos());
        for (i, n) in m.data.iter().enumerate() {
            let n = n.map(f64::from);
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            if !(len.is_finite() && len > 0.0) {
                continue;
            }
            a.surface += 1;
            if (len - 1.0).abs() <= UNIT_TOLERANCE {
                a.unit += 1;
            }
            // The pixel's ray (x right, y down, z forward), through its centre.
            let (u, v) = ((i % m.width) as f64 + 0.5, (i / m.width) as f64 + 0.5);
            let ray = [(u - e.cx) / e.f_px, (v - e.cy) / e.f_px, 1.0];
            let ray_len = (ray[0] * ray[0] + ray[1] * ray[1] + 1.0).sqrt();
            let cos = -(n[0] * ray[0] + n[1] * ray[1] + n[2] * ray[2]) / (len * ray_len);
            for (k, &limit) in cos_limits.iter().enumerate() {
                // 90°: cos >= 0 exactly (the side a ray sees).
                if cos >= limit - 1e-12 {
                    a.facing[k] += 1;
                }
            }
            a.angles.add(cos.clamp(-1.0, 1.0).acos().to_degrees());
        }
    }

    fn merge(mut self, o: MapAcc) -> Self {
        for (k, n) in o.samples {
            *self.samples.entry(k).or_default() += n;
        }
        match (&mut self.depth, o.depth) {
            (Some(a), Some(b)) => {
                a.pixels += b.pixels;
                a.valid += b.valid;
                a.sum += b.sum;
                a.min = a.min.min(b.min);
                a.max = a.max.max(b.max);
                a.log10.merge(&b.log10);
            }
            (a @ None, b) => *a = b,
            (Some(_), None) => {}
        }
        match (&mut self.normals, o.normals) {
            (Some(a), Some(b)) => {
                a.pixels += b.pixels;
                a.surface += b.surface;
                a.unit += b.unit;
                for (x, y) in a.facing.iter_mut().zip(b.facing) {
                    *x += y;
                }
                a.angles.merge(&b.angles);
            }
            (a @ None, b) => *a = b,
            (Some(_), None) => {}
        }
        self.visible.extend(o.visible);
        for (id, n) in o.semantic {
            *self.semantic.entry(id).or_default() += n;
        }
        self.errors.extend(o.errors);
        self
    }

    /// Every map of sample `e`, both views.
    fn add_sample(&mut self, loaded: &Loaded, opts: &StatsOptions, e: &ManifestEntry) {
        let mut ids = BTreeSet::new();
        for kind in e.files.maps() {
            let mut read_both = true;
            for view in ["left", "right"] {
                if let Err(err) = self.add_file(loaded, opts, e, kind, view, &mut ids) {
                    self.errors.push(err);
                    read_both = false;
                }
            }
            if read_both {
                *self.samples.entry(kind).or_default() += 1;
                if kind == MapKind::Instance {
                    let content = e
                        .instances
                        .iter()
                        .filter(|i| i.role == "content" && ids.contains(&i.id))
                        .count();
                    self.visible
                        .push([ids.len() as u32, content as u32, e.instances.len() as u32]);
                }
            }
        }
    }

    fn add_file(
        &mut self,
        loaded: &Loaded,
        opts: &StatsOptions,
        e: &ManifestEntry,
        kind: MapKind,
        view: &str,
        ids: &mut BTreeSet<u16>,
    ) -> Result<(), FileError> {
        let files = &loaded.files;
        let key = kind.file_key(view);
        let bytes = read_sample_file(files, e, &key, opts.verify)?;
        let path = files.path(e, &key);
        let map = MapData::decode(kind, &bytes, &path).map_err(FileError::Io)?;
        let (w, h) = map.size();
        if (w, h) != (e.width as usize, e.height as usize) {
            return Err(FileError::Io(stereo_io::Error::format(
                &path,
                format!("is {w}x{h}, the sample {}x{}", e.width, e.height),
            )));
        }
        match (kind, map) {
            (_, MapData::Depth(m)) => self.add_depth(&m),
            (_, MapData::Normals(m)) => self.add_normals(&m, e),
            (MapKind::Instance, MapData::Ids(m)) => {
                ids.extend(m.data.iter().copied().filter(|&id| id != 0))
            }
            (_, MapData::Ids(m)) => {
                for &id in &m.data {
                    *self.semantic.entry(id).or_default() += 1;
                }
            }
        }
        Ok(())
    }
}

/// Depth of the surface pixels, metres.
#[derive(Debug, Clone, Serialize)]
pub struct DepthStats {
    pub samples: u64,
    pub pixels: u64,
    /// Pixels with a surface (depth > 0).
    pub valid: u64,
    pub valid_fraction: f64,
    pub min: Option<f64>,
    pub p5: Option<f64>,
    pub median: Option<f64>,
    pub p95: Option<f64>,
    pub max: Option<f64>,
    pub mean: Option<f64>,
    /// Surface pixels by log10 of their depth in metres.
    pub histogram_log10_m: UniformHist,
}

#[derive(Debug, Clone, Serialize)]
pub struct NormalStats {
    pub samples: u64,
    pub pixels: u64,
    /// Pixels with a surface (a non-zero normal).
    pub surface: u64,
    pub surface_fraction: f64,
    /// The angles of `facing`, degrees.
    pub facing_deg: [f64; 3],
    /// Share of surface pixels whose normal lies within each angle of the direction back to the
    /// camera along the pixel's ray.
    pub facing: [f64; 3],
    /// Share of surface pixels whose normal has unit length (within 1e-3).
    pub unit_fraction: f64,
    /// Surface pixels by that angle, degrees (0..180).
    pub angle_histogram_deg: UniformHist,
}

#[derive(Debug, Clone, Serialize)]
pub struct InstanceStats {
    pub samples: u64,
    /// Distinct instance ids in either view, per sample: min, mean, max.
    pub visible: [f64; 3],
    /// The content objects among them (role `content` in the manifest's instance table).
    pub content_visible: [f64; 3],
    /// Instances the manifest lists per sample, mean.
    pub listed_mean: f64,
    /// Samples by instances visible (index = count).
    pub visible_counts: Vec<u64>,
}

#[derive(Debug, Clone, Serialize)]
pub struct ClassShare {
    pub id: u16,
    pub name: String,
    pub pixels: u64,
    /// Of all pixels of the semantic maps.
    pub share: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct SemanticStats {
    pub samples: u64,
    pub pixels: u64,
    /// Every class of the dataset's table, then ids outside it that occur; id 0 (`no surface`)
    /// first where it occurs. Shares sum to 1.
    pub classes: Vec<ClassShare>,
}

/// What `stats.json` holds about the maps: one entry per map the dataset has.
#[derive(Debug, Clone, Serialize)]
pub struct MapStats {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub depth: Option<DepthStats>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub normals: Option<NormalStats>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub instance: Option<InstanceStats>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub semantic: Option<SemanticStats>,
}

fn fraction(a: u64, b: u64) -> f64 {
    if b == 0 { 0.0 } else { a as f64 / b as f64 }
}

fn min_mean_max(values: impl Iterator<Item = u32> + Clone) -> [f64; 3] {
    let n = values.clone().count().max(1) as f64;
    [
        values.clone().min().unwrap_or(0) as f64,
        values.clone().map(f64::from).sum::<f64>() / n,
        values.max().unwrap_or(0) as f64,
    ]
}

/// The summary of every map of the dataset, and the map files that could not be read; `None`
/// when no sample has a map.
pub fn map_pass(loaded: &Loaded, opts: &StatsOptions) -> Option<(MapStats, Vec<FileError>)> {
    if !loaded.entries.iter().any(|e| !e.files.maps().is_empty()) {
        return None;
    }
    let acc = loaded
        .entries
        .par_iter()
        .fold(MapAcc::default, |mut acc, e| {
            acc.add_sample(loaded, opts, e);
            acc
        })
        .reduce(MapAcc::default, MapAcc::merge);
    let samples = |k: MapKind| acc.samples.get(&k).copied().unwrap_or(0);
    let depth = acc.depth.as_ref().map(|a| {
        let q = |p: f64| (a.valid > 0).then(|| 10f64.powf(a.log10.quantile(p).unwrap_or(0.0)));
        DepthStats {
            samples: samples(MapKind::Depth),
            pixels: a.pixels,
            valid: a.valid,
            valid_fraction: fraction(a.valid, a.pixels),
            min: (a.valid > 0).then_some(a.min),
            p5: q(0.05),
            median: q(0.5),
            p95: q(0.95),
            max: (a.valid > 0).then_some(a.max),
            mean: (a.valid > 0).then(|| a.sum / a.valid as f64),
            histogram_log10_m: a.log10.coarsen(LOG_DEPTH.2 / LOG_DEPTH_DISPLAY_BINS),
        }
    });
    let normals = acc.normals.as_ref().map(|a| NormalStats {
        samples: samples(MapKind::Normals),
        pixels: a.pixels,
        surface: a.surface,
        surface_fraction: fraction(a.surface, a.pixels),
        facing_deg: FACING_DEG,
        facing: a.facing.map(|n| fraction(n, a.surface)),
        unit_fraction: fraction(a.unit, a.surface),
        angle_histogram_deg: a.angles.clone(),
    });
    let instance = (!acc.visible.is_empty()).then(|| {
        let max = acc.visible.iter().map(|v| v[0]).max().unwrap_or(0) as usize;
        let mut visible_counts = vec![0u64; max + 1];
        acc.visible
            .iter()
            .for_each(|v| visible_counts[v[0] as usize] += 1);
        InstanceStats {
            samples: samples(MapKind::Instance),
            visible: min_mean_max(acc.visible.iter().map(|v| v[0])),
            content_visible: min_mean_max(acc.visible.iter().map(|v| v[1])),
            listed_mean: min_mean_max(acc.visible.iter().map(|v| v[2]))[1],
            visible_counts,
        }
    });
    let semantic = (!acc.semantic.is_empty()).then(|| {
        let pixels: u64 = acc.semantic.values().sum();
        let table = &loaded.info.semantic_classes;
        let mut classes: Vec<(u16, String)> = Vec::new();
        if acc.semantic.contains_key(&0) {
            classes.push((0, "no surface".into()));
        }
        classes.extend(table.iter().map(|c| (c.id, c.name.clone())));
        for &id in acc.semantic.keys() {
            if id != 0 && !table.iter().any(|c| c.id == id) {
                classes.push((id, format!("class {id}")));
            }
        }
        SemanticStats {
            samples: samples(MapKind::Semantic),
            pixels,
            classes: classes
                .into_iter()
                .map(|(id, name)| {
                    let n = acc.semantic.get(&id).copied().unwrap_or(0);
                    ClassShare {
                        id,
                        name,
                        pixels: n,
                        share: fraction(n, pixels),
                    }
                })
                .collect(),
        }
    });
    let stats = MapStats {
        depth,
        normals,
        instance,
        semantic,
    };
    Some((stats, acc.errors))
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("-".into(), |v| format!("{v:.digits$}"))
}

fn pct(v: f64) -> String {
    format!("{:.1}%", 100.0 * v)
}

impl MapStats {
    /// The terminal summary: one line per map, `map <name> ...`.
    pub fn lines(&self) -> Vec<String> {
        let mut lines = Vec::new();
        if let Some(d) = &self.depth {
            lines.push(format!(
                "map depth    {:>6} samples  depth min/median/max {}/{}/{} m  mean {} m  valid {}",
                d.samples,
                opt(d.min, 3),
                opt(d.median, 3),
                opt(d.max, 3),
                opt(d.mean, 3),
                pct(d.valid_fraction)
            ));
        }
        if let Some(n) = &self.normals {
            lines.push(format!(
                "map normals  {:>6} samples  facing the camera within 30/60/90 deg {}/{}/{}  unit length {}  surface {}",
                n.samples,
                pct(n.facing[0]),
                pct(n.facing[1]),
                pct(n.facing[2]),
                pct(n.unit_fraction),
                pct(n.surface_fraction)
            ));
        }
        if let Some(i) = &self.instance {
            let [a, b, c] = i.visible;
            let [d, e, f] = i.content_visible;
            lines.push(format!(
                "map instance {:>6} samples  instances visible per sample min/mean/max {a:.0}/{b:.2}/{c:.0}  content objects {d:.0}/{e:.2}/{f:.0} of {:.2} listed",
                i.samples, i.listed_mean
            ));
        }
        if let Some(s) = &self.semantic {
            let shares: Vec<String> = s
                .classes
                .iter()
                .filter(|c| c.pixels > 0)
                .map(|c| format!("{} {}", c.name, pct(c.share)))
                .collect();
            lines.push(format!(
                "map semantic {:>6} samples  pixel share: {}",
                s.samples,
                shares.join(", ")
            ));
        }
        lines
    }
}
