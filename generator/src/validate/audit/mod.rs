//! `stereogen audit DATASET`: an independent check of a generated dataset's ground truth.
//!
//! For each audited sample the Blender worker rebuilds the scene from its `scene.json` and writes
//! the evaluated geometry (modifiers applied, world space, with what decides a hit) instead of
//! rendering ([`geometry`]); Rust casts its own rays through the pixel centres of both views in
//! f64 ([`raycast`], over a [`bvh`]), applies the README's ground-truth rules, and compares with
//! the disparity EXRs ([`compare`]) and, where a sample has them, with its depth, normal,
//! instance and semantic maps ([`map_check`]). Cycles' passes are never used as the reference.
//! Files are also checked against the manifest's SHA-256. [`audit`] gives an [`AuditReport`],
//! written as `audit.json`.
//!
//! Blender exports the next sample while Rust casts rays through the current one.

pub mod audit_report;
pub mod bvh;
pub mod compare;
pub mod geometry;
pub mod map_check;
pub mod raycast;
pub mod select;
pub mod tally;

use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::Instant;

use anyhow::{Context, bail};
use rayon::prelude::*;
use stereo_io::datasets::stereogen::SemanticClass;
use stereo_io::digest::sha256_file;

pub use audit_report::{AuditReport, Bars, GroupAudit, MapGroup, SampleAudit, summary_lines};
pub use select::{PixelSelection, SampleSelection};

use self::compare::{Camera, SampleCheck};
use self::geometry::{SceneGeometry, read_geometry};
use self::map_check::{SampleMaps, slot};
use self::tally::{Tally, keep_worst, keep_worst_maps};
use crate::dataset::{DatasetLayout, ManifestEntry, read_manifest, read_scene_spec};
use crate::plan::SceneSpec;
use crate::render::{RenderService, WorkerError, WorkerOptions};

/// The file an audit writes into the dataset (and `stereogen report` reads).
pub const AUDIT_FILE: &str = "audit.json";
/// Worst pixels kept over the whole audit.
const WORST_OVERALL: usize = 20;

#[derive(Debug, Clone)]
pub struct AuditOptions {
    pub dataset: PathBuf,
    pub samples: SampleSelection,
    pub pixels: PixelSelection,
    pub seed: u64,
    pub bars: Bars,
    pub worker_options: WorkerOptions,
}

impl AuditOptions {
    pub fn new(dataset: impl Into<PathBuf>) -> Self {
        Self {
            dataset: dataset.into(),
            samples: SampleSelection::Count(16),
            pixels: PixelSelection::Count(4096),
            seed: 0,
            bars: Bars::default(),
            worker_options: WorkerOptions::default(),
        }
    }
}

/// A sample's scene as the worker rebuilt it.
struct Rebuilt {
    spec: SceneSpec,
    geometry: SceneGeometry,
}

/// Files of `entry` whose checksum differs from the manifest's, and files that cannot be read.
fn verify_checksums(layout: &DatasetLayout, entry: &ManifestEntry) -> (Vec<String>, Vec<String>) {
    let (mut mismatches, mut problems) = (Vec::new(), Vec::new());
    for (key, rel) in entry.files.all() {
        let Some(expected) = entry.sha256.get(key) else {
            continue;
        };
        match sha256_file(&layout.abs(rel)) {
            Ok(actual) if &actual == expected => {}
            Ok(_) => mismatches.push(format!("{key} ({})", rel.display())),
            Err(e) => problems.push(format!("cannot read {}: {e}", layout.abs(rel).display())),
        }
    }
    (mismatches, problems)
}

/// Rebuilds one sample's scene in the worker and reads its geometry. `Err(Ok(msg))`: this sample
/// cannot be audited; `Err(Err(e))`: no sample can (Blender does not start).
fn rebuild(
    service: &mut RenderService,
    layout: &DatasetLayout,
    entry: &ManifestEntry,
) -> Result<Rebuilt, Result<String, WorkerError>> {
    let spec =
        read_scene_spec(&layout.abs(&entry.files.scene)).map_err(|e| Ok(format!("{e:#}")))?;
    let exported = match service.export_geometry(&spec) {
        Ok(x) => x,
        Err(e) if e.is_fatal() => return Err(Err(e)),
        Err(e) => return Err(Ok(format!("Blender could not rebuild the scene: {e}"))),
    };
    let reply = &exported.reply;
    if reply.renders != 0 {
        return Err(Ok(format!(
            "the worker ran {} render(s) during the geometry export",
            reply.renders
        )));
    }
    if reply.report.notes != entry.notes {
        return Err(Ok(format!(
            "the scene was built differently than when it was rendered: now {:?}, then {:?}",
            reply.report.notes, entry.notes
        )));
    }
    let geometry = read_geometry(&reply.file).map_err(|e| Ok(format!("{e:#}")))?;
    Ok(Rebuilt { spec, geometry })
}

/// Whether Blender built the cameras the spec's rig describes (position, lens, sensor, shift).
fn camera_problems(spec: &SceneSpec, geometry: &SceneGeometry) -> Vec<String> {
    let facts = spec.cameras();
    let mut out = Vec::new();
    for (name, built, stated) in [
        ("left", &geometry.cameras.left, &facts.left),
        ("right", &geometry.cameras.right, &facts.right),
    ] {
        let m = &built.matrix_world;
        let position = [m[0][3], m[1][3], m[2][3]];
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-5 * a.abs().max(b.abs()).max(1.0);
        let identity =
            (0..3).all(|i| (0..3).all(|j| close(m[i][j], if i == j { 1.0 } else { 0.0 })));
        let b = &facts.blender;
        let same = identity
            && position
                .iter()
                .zip(&stated.position)
                .all(|(a, b)| close(*a, *b))
            && close(built.lens_mm, b.lens_mm)
            && close(built.sensor_width_mm, b.sensor_width_mm)
            && close(built.shift_x, b.shift_x)
            && close(built.shift_y, b.shift_y)
            && built.sensor_fit == "HORIZONTAL";
        if !same {
            out.push(format!("Blender built the {name} camera unlike the spec's rig: at {position:?}, lens {} mm, shift ({}, {})", built.lens_mm, built.shift_x, built.shift_y));
        }
    }
    out
}

fn read_map(
    layout: &DatasetLayout,
    rel: &Path,
    spec: &SceneSpec,
) -> Result<stereo_io::DisparityMap, String> {
    let path = layout.abs(rel);
    let (map, _) = stereo_io::read_disparity_exr(&path).map_err(|e| {
        let msg = e.to_string();
        if msg.contains(&*path.to_string_lossy()) {
            msg
        } else {
            format!("{}: {msg}", path.display())
        }
    })?;
    if (map.width, map.height) != (spec.rig.width as usize, spec.rig.height as usize) {
        return Err(format!(
            "{}: {}x{}, the spec says {}x{}",
            path.display(),
            map.width,
            map.height,
            spec.rig.width,
            spec.rig.height
        ));
    }
    Ok(map)
}

/// The class table of the dataset's semantic maps: `dataset.json`'s, or (a dataset without
/// one) this stereogen's.
fn class_table(layout: &DatasetLayout) -> Vec<SemanticClass> {
    let stated = layout
        .read_info::<serde_json::Value>()
        .map(|i| i.semantic_classes)
        .unwrap_or_default();
    if !stated.is_empty() {
        return stated;
    }
    crate::plan::SEMANTIC_CLASSES
        .iter()
        .enumerate()
        .map(|(i, name)| SemanticClass {
            id: i as u16 + 1,
            name: name.to_string(),
        })
        .collect()
}

/// Casts and compares one rebuilt sample (its checksum results already in `audit`); `classes`
/// is the dataset's semantic class table.
fn check_sample(
    opts: &AuditOptions,
    layout: &DatasetLayout,
    entry: &ManifestEntry,
    rebuilt: &Rebuilt,
    classes: &[SemanticClass],
    audit: &mut SampleAudit,
) {
    let Rebuilt { spec, geometry } = rebuilt;
    audit.objects = geometry.objects.len();
    audit.triangles = geometry.scene.triangles.len();
    audit.problems.extend(camera_problems(spec, geometry));
    let maps = read_map(layout, &entry.files.disp_left, spec)
        .and_then(|l| Ok((l, read_map(layout, &entry.files.disp_right, spec)?)));
    let (left, right) = match maps {
        Ok(m) => m,
        Err(e) => return audit.problems.push(e),
    };
    let names: Vec<&str> = geometry.objects.iter().map(|o| o.name.as_str()).collect();
    let (other_maps, problems) = SampleMaps::read(layout, entry, spec, &names, classes);
    audit.problems.extend(problems);
    let check = SampleCheck {
        id: &entry.id,
        category: &entry.category,
        camera: Camera {
            rig: &spec.rig,
            clip_start: spec.render.clip_start,
            clip_end: spec.render.clip_end,
        },
        scene: &geometry.scene,
        left: &left,
        right: &right,
        maps: (!other_maps.is_empty()).then_some(&other_maps),
    };
    let pixels =
        select::choose_pixels(left.width, left.height, opts.pixels, opts.seed, entry.index);
    let t0 = Instant::now();
    let outcome = check.run(&pixels);
    audit.seconds = t0.elapsed().as_secs_f64();
    audit.tally = outcome.tally;
    audit.worst = outcome.worst;
    for kind in stereo_io::MapKind::ALL {
        if other_maps.has(kind) {
            audit
                .maps
                .insert(kind.name().to_string(), outcome.maps[slot(kind)].clone());
        }
    }
    audit.map_worst = outcome.map_worst;
}

fn empty_audit(entry: &ManifestEntry) -> SampleAudit {
    SampleAudit {
        id: entry.id.clone(),
        category: entry.category.clone(),
        index: entry.index,
        tally: Tally::default(),
        worst: Vec::new(),
        checksum_mismatches: Vec::new(),
        problems: Vec::new(),
        objects: 0,
        triangles: 0,
        seconds: 0.0,
        maps: Default::default(),
        map_worst: Vec::new(),
        pass: false,
    }
}

/// Reads the manifest; an audit needs at least one finished sample.
fn finished_samples(layout: &DatasetLayout) -> anyhow::Result<(Vec<ManifestEntry>, bool)> {
    // A dataset whose samples all failed (or none finished yet) may have no manifest at all.
    let contents = if !layout.manifest().exists() && layout.info().exists() {
        Default::default()
    } else {
        read_manifest(&layout.manifest())
            .with_context(|| format!("{} is not a stereogen dataset", layout.root.display()))?
    };
    if contents.entries.is_empty() {
        let failures = crate::dataset::manifest::read_failures(&layout.failures())?
            .records
            .len();
        let why = if failures > 0 {
            format!(
                "; {failures} sample(s) failed, see {}",
                layout.failures().display()
            )
        } else {
            String::new()
        };
        bail!(
            "{} has no finished samples to audit ({} is empty){why}",
            layout.root.display(),
            layout.manifest().display()
        );
    }
    let unfinished = contents.has_unfinished_line();
    Ok((contents.entries, unfinished))
}

/// Audits the dataset at `opts.dataset`; `progress(done, total, sample)` after each sample.
pub fn audit(
    opts: &AuditOptions,
    progress: &(dyn Fn(usize, usize, &SampleAudit) + Sync),
) -> anyhow::Result<AuditReport> {
    let started = Instant::now();
    let layout = DatasetLayout::new(&opts.dataset);
    let (entries, unfinished) = finished_samples(&layout)?;
    let chosen = select::choose_samples(&entries, opts.samples, opts.seed);
    let checksums: Vec<(Vec<String>, Vec<String>)> = chosen
        .par_iter()
        .map(|&i| verify_checksums(&layout, &entries[i]))
        .collect();
    let cfg = opts.worker_options.resolve(1)?;
    let classes = class_table(&layout);

    let (tx, rx) = mpsc::sync_channel::<(usize, Result<Rebuilt, Result<String, WorkerError>>)>(1);
    let mut samples = Vec::with_capacity(chosen.len());
    std::thread::scope(|s| -> anyhow::Result<()> {
        let producer_layout = &layout;
        let order = &chosen;
        let entries = &entries;
        s.spawn(move || {
            let mut service = RenderService::new(cfg);
            for (k, &i) in order.iter().enumerate() {
                if tx
                    .send((k, rebuild(&mut service, producer_layout, &entries[i])))
                    .is_err()
                {
                    break;
                }
            }
            service.shutdown();
        });
        for (k, rebuilt) in rx {
            let entry = &entries[chosen[k]];
            let mut audit = empty_audit(entry);
            (audit.checksum_mismatches, audit.problems) = checksums[k].clone();
            match rebuilt {
                Ok(r) => check_sample(opts, &layout, entry, &r, &classes, &mut audit),
                Err(Ok(problem)) => audit.problems.push(problem),
                Err(Err(fatal)) => {
                    return Err(anyhow::Error::new(fatal)
                        .context("cannot start the Blender worker for the geometry export"));
                }
            }
            audit.pass = audit.reasons(&opts.bars).is_empty();
            progress(samples.len() + 1, chosen.len(), &audit);
            samples.push(audit);
        }
        Ok(())
    })?;
    let mut report = assemble(
        opts,
        &entries,
        unfinished,
        samples,
        started.elapsed().as_secs_f64(),
    );
    // A curated dataset: the replaced samples out of the manifest, their replacements in.
    if let Ok(info) = layout.read_info::<serde_json::Value>() {
        let (lines, problems) =
            crate::dataset::curate::apply::check_curation(&layout, &info.curation, &entries);
        report.curation = lines;
        report.pass &= problems.is_empty();
        report.problems.extend(problems);
    }
    Ok(report)
}

/// Groups the sample audits by category and decides the verdict.
fn assemble(
    opts: &AuditOptions,
    entries: &[ManifestEntry],
    unfinished: bool,
    samples: Vec<SampleAudit>,
    seconds: f64,
) -> AuditReport {
    let mut names: Vec<&str> = samples.iter().map(|s| s.category.as_str()).collect();
    names.sort_unstable();
    names.dedup();
    let categories: Vec<GroupAudit> = names
        .iter()
        .map(|name| {
            GroupAudit::new(
                name,
                &samples
                    .iter()
                    .filter(|s| s.category == *name)
                    .collect::<Vec<_>>(),
                &opts.bars,
            )
        })
        .collect();
    let overall = GroupAudit::new("all", &samples.iter().collect::<Vec<_>>(), &opts.bars);
    let mut worst: Vec<_> = samples
        .iter()
        .flat_map(|s| s.worst.iter().cloned())
        .collect();
    keep_worst(&mut worst, WORST_OVERALL);
    let mut map_worst: Vec<_> = samples
        .iter()
        .flat_map(|s| s.map_worst.iter().cloned())
        .collect();
    keep_worst_maps(&mut map_worst, map_check::WORST_PER_MAP);
    let cast_seconds: f64 = samples.iter().map(|s| s.seconds).sum();
    let megapixels = overall.tally.pixels as f64 / 1e6;
    let pass = overall.pass && categories.iter().all(|c| c.pass) && samples.iter().all(|s| s.pass);
    AuditReport {
        dataset: opts.dataset.display().to_string(),
        stereogen_version: env!("CARGO_PKG_VERSION").to_string(),
        seed: opts.seed,
        samples_requested: match opts.samples {
            SampleSelection::All => "all".into(),
            SampleSelection::Count(k) => k.to_string(),
        },
        pixels_requested: match opts.pixels {
            PixelSelection::Every => "every".into(),
            PixelSelection::Count(p) => p.to_string(),
        },
        manifest_samples: entries.len(),
        unfinished_manifest_line: unfinished,
        bars: opts.bars,
        categories,
        overall,
        worst,
        map_worst,
        samples,
        seconds,
        cast_seconds,
        cast_seconds_per_megapixel: (megapixels > 0.0).then(|| cast_seconds / megapixels),
        problems: Vec::new(),
        curation: Vec::new(),
        pass,
    }
}

/// Writes the report as JSON to `path` atomically.
pub fn write_json(report: &AuditReport, path: &Path) -> anyhow::Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let json = serde_json::to_string_pretty(report)?;
    stereo_io::write_bytes_atomically(path, json.as_bytes())
        .with_context(|| format!("cannot write {}", path.display()))
}

/// Reads an `audit.json`.
pub fn read_json(path: &Path) -> anyhow::Result<AuditReport> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("{}: cannot read", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{}: not an audit report", path.display()))
}
