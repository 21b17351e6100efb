//! Finding the samples of each layout, and recognising a layout from its root folder.

use std::path::{Path, PathBuf};

use walkdir::WalkDir;

use super::{DatasetFormat, DispKind, MaskKind, SampleFiles, SampleMeta};
use crate::error::{Error, Result};
use crate::png_disp::{CRESTEREO_SCALE, KITTI_SCALE};

pub(crate) fn scan(format: DatasetFormat, root: &Path) -> Result<Vec<SampleFiles>> {
    let mut samples = match format {
        DatasetFormat::Stereogen => stereogen(root)?,
        DatasetFormat::Crestereo => crestereo(root)?,
        DatasetFormat::SceneFlow => sceneflow(root)?,
        DatasetFormat::Middlebury => middlebury_like(root, format, "disp0.pfm", Some("disp1.pfm"))?,
        DatasetFormat::Eth3d => middlebury_like(root, format, "disp0GT.pfm", None)?,
        DatasetFormat::Kitti2012 => kitti(root, format, ("colored_0", "colored_1"), "disp_occ", None, "disp_noc")?,
        DatasetFormat::Kitti2015 => kitti(root, format, ("image_2", "image_3"), "disp_occ_0", Some("disp_occ_1"), "disp_noc_0")?,
        DatasetFormat::Sintel => sintel(root)?,
        DatasetFormat::FallingThings => falling_things(root)?,
    };
    if format != DatasetFormat::Stereogen {
        samples.sort_by(|a, b| a.left.cmp(&b.left));
    }
    for s in &mut samples {
        s.meta.format = Some(format);
        s.meta.left_path = s.left.clone();
        s.meta.right_path = s.right.clone();
        s.meta.disp_left_path = s.disp_left.0.clone();
    }
    Ok(samples)
}

fn rel_id(root: &Path, path: &Path) -> String {
    path.strip_prefix(root).unwrap_or(path).to_string_lossy().into_owned()
}

fn walk(root: &Path, max_depth: usize) -> impl Iterator<Item = walkdir::DirEntry> {
    WalkDir::new(root).max_depth(max_depth).follow_links(true).sort_by_file_name().into_iter().filter_map(|e| e.ok())
}

fn file_name(p: &Path) -> String {
    p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()
}

fn require(path: PathBuf, what: &str, for_: &Path) -> Result<PathBuf> {
    if path.is_file() {
        Ok(path)
    } else {
        Err(Error::format(&path, format!("missing: the {what} of {}", for_.display())))
    }
}

// ---------------------------------------------------------------- stereogen (ours)

fn stereogen(root: &Path) -> Result<Vec<SampleFiles>> {
    let manifest = root.join("manifest.jsonl");
    let text = std::fs::read_to_string(&manifest).map_err(|e| Error::io(&manifest, e))?;
    let mut out = Vec::new();
    let lines: Vec<&str> = text.split_inclusive('\n').collect();
    for (n, line) in lines.iter().enumerate() {
        let body = line.trim();
        if body.is_empty() {
            continue;
        }
        let v: serde_json::Value = match serde_json::from_str(body) {
            Ok(v) => v,
            // A last line without its newline was cut by a kill mid-append: not a sample yet.
            Err(_) if n + 1 == lines.len() && !line.ends_with('\n') => break,
            Err(e) => return Err(Error::format(&manifest, format!("line {} is not JSON: {e}", n + 1))),
        };
        let field = |k: &str| v.get(k).ok_or_else(|| Error::format(&manifest, format!("line {}: no field `{k}`", n + 1)));
        let text_of = |k: &str| -> Result<String> { field(k)?.as_str().map(str::to_owned).ok_or_else(|| Error::format(&manifest, format!("line {}: `{k}` is not a string", n + 1))) };
        let num = |k: &str| v.get(k).and_then(|x| x.as_f64());
        let file = |k: &str| -> Result<PathBuf> {
            let rel = field("files")?.get(k).and_then(|x| x.as_str()).ok_or_else(|| Error::format(&manifest, format!("line {}: no `files.{k}`", n + 1)))?;
            Ok(root.join(rel))
        };
        let id = text_of("id")?;
        let mut meta = SampleMeta { id: id.clone(), f_px: num("f_px"), baseline_m: num("baseline_m"), cx: num("cx"), cy: num("cy"), ..Default::default() };
        if let Ok(c) = text_of("category") {
            meta.extra.insert("category".into(), c);
        }
        for k in ["index", "seed", "width", "height"] {
            if let Some(x) = v.get(k).and_then(|x| x.as_u64()) {
                meta.extra.insert(k.into(), x.to_string());
            }
        }
        out.push(SampleFiles {
            id,
            left: file("left")?,
            right: file("right")?,
            disp_left: (file("disp_left")?, DispKind::Exr),
            disp_right: Some((file("disp_right")?, DispKind::Exr)),
            masks: vec![],
            meta,
        });
    }
    Ok(out)
}

// ---------------------------------------------------------------- CREStereo release

fn crestereo(root: &Path) -> Result<Vec<SampleFiles>> {
    let mut out = Vec::new();
    for e in walk(root, 8) {
        let name = file_name(e.path());
        let Some(prefix) = name.strip_suffix("_left.jpg") else { continue };
        let dir = e.path().parent().unwrap_or(root);
        let right = require(dir.join(format!("{prefix}_right.jpg")), "right image", e.path())?;
        let disp = require(dir.join(format!("{prefix}_left.disp.png")), "left disparity", e.path())?;
        let disp_r = dir.join(format!("{prefix}_right.disp.png"));
        out.push(SampleFiles {
            id: rel_id(root, &dir.join(prefix)),
            left: e.path().to_path_buf(),
            right,
            disp_left: (disp, DispKind::Png16(CRESTEREO_SCALE)),
            disp_right: disp_r.is_file().then_some((disp_r, DispKind::Png16(CRESTEREO_SCALE))),
            masks: vec![],
            meta: SampleMeta::default(),
        });
    }
    Ok(out)
}

// ---------------------------------------------------------------- SceneFlow

/// Replaces one path component.
fn swap_component(path: &Path, from: &str, to: &str) -> Option<PathBuf> {
    let mut swapped = false;
    let out: PathBuf = path
        .components()
        .map(|c| {
            if !swapped && c.as_os_str() == from {
                swapped = true;
                std::ffi::OsStr::new(to).to_owned()
            } else {
                c.as_os_str().to_owned()
            }
        })
        .collect();
    swapped.then_some(out)
}

/// The last `left` component of `path` (the camera folder) replaced by `right`.
fn left_to_right(path: &Path) -> Option<PathBuf> {
    let comps: Vec<_> = path.components().collect();
    let at = comps.iter().rposition(|c| c.as_os_str() == "left")?;
    Some(comps.iter().enumerate().map(|(i, c)| if i == at { std::ffi::OsStr::new("right") } else { c.as_os_str() }).collect())
}

fn sceneflow(root: &Path) -> Result<Vec<SampleFiles>> {
    // Clean pass where present, else final: one pass, so a pair is not counted twice.
    let pass_dirs: Vec<PathBuf> = walk(root, 4).filter(|e| e.file_type().is_dir() && file_name(e.path()) == "frames_cleanpass").map(|e| e.into_path()).collect();
    let pass_dirs = if pass_dirs.is_empty() {
        walk(root, 4).filter(|e| e.file_type().is_dir() && file_name(e.path()) == "frames_finalpass").map(|e| e.into_path()).collect()
    } else {
        pass_dirs
    };
    let mut out = Vec::new();
    for pass_dir in pass_dirs {
        let pass = file_name(&pass_dir);
        for e in walk(&pass_dir, 12) {
            let p = e.path();
            if !e.file_type().is_file() || p.extension().is_none_or(|x| x != "png") || p.parent().is_none_or(|d| file_name(d) != "left") {
                continue;
            }
            let right = require(left_to_right(p).unwrap_or_default(), "right image", p)?;
            let disp = swap_component(p, &pass, "disparity").unwrap_or_default().with_extension("pfm");
            let disp = require(disp, "disparity (disparity/…/left/*.pfm)", p)?;
            let disp_r = left_to_right(&disp).unwrap_or_default();
            let rel = rel_id(root, p);
            // Sensor 32 mm wide at 960 px: 35 mm lenses give 1050 px, Driving's 15 mm 450 px.
            let f_px = if rel.contains("15mm_focallength") { 450.0 } else { 1050.0 };
            out.push(SampleFiles {
                id: rel,
                left: p.to_path_buf(),
                right,
                disp_left: (disp, DispKind::Pfm),
                disp_right: disp_r.is_file().then_some((disp_r, DispKind::Pfm)),
                masks: vec![],
                meta: SampleMeta { f_px: Some(f_px), ..Default::default() },
            });
        }
    }
    Ok(out)
}

// ---------------------------------------------------------------- Middlebury 2014 / ETH3D

/// Parses a Middlebury/ETH3D `calib.txt` (`cam0=[f 0 cx; 0 f cy; 0 0 1]`, `baseline` in mm,
/// `ndisp`, `doffs`, ...) into `meta`.
pub(crate) fn parse_calib(path: &Path, meta: &mut SampleMeta) -> Result<()> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    for line in text.lines() {
        let Some((k, v)) = line.split_once('=') else { continue };
        let (k, v) = (k.trim(), v.trim());
        let num = |s: &str| s.parse::<f64>().map_err(|_| Error::format(path, format!("`{k}` value {s:?} is not a number")));
        match k {
            "cam0" => {
                let nums: Vec<f64> = v.trim_matches(['[', ']']).split([' ', ';']).filter(|s| !s.is_empty()).map(num).collect::<Result<_>>()?;
                if nums.len() != 9 {
                    return Err(Error::format(path, format!("cam0 has {} numbers, expected a 3x3 matrix", nums.len())));
                }
                meta.f_px = Some(nums[0]);
                meta.cx = Some(nums[2]);
                meta.cy = Some(nums[5]);
            }
            "baseline" => meta.baseline_m = Some(num(v)? / 1000.0),
            "ndisp" => meta.ndisp = Some(num(v)? as u32),
            _ => {
                meta.extra.insert(k.to_string(), v.to_string());
            }
        }
    }
    Ok(())
}

fn middlebury_like(root: &Path, format: DatasetFormat, disp_name: &str, disp_right_name: Option<&str>) -> Result<Vec<SampleFiles>> {
    let mut out = Vec::new();
    for e in walk(root, 4) {
        if file_name(e.path()) != disp_name {
            continue;
        }
        let dir = e.path().parent().unwrap_or(root);
        let left = require(dir.join("im0.png"), "left image im0.png", dir)?;
        let right = require(dir.join("im1.png"), "right image im1.png", dir)?;
        let mut meta = SampleMeta::default();
        let calib = dir.join("calib.txt");
        if calib.is_file() {
            parse_calib(&calib, &mut meta)?;
        } else if format == DatasetFormat::Middlebury {
            return Err(Error::format(&calib, "missing: Middlebury scenes carry a calib.txt"));
        }
        let disp_r = disp_right_name.map(|n| dir.join(n)).filter(|p| p.is_file());
        let mask = dir.join("mask0nocc.png");
        out.push(SampleFiles {
            id: rel_id(root, dir),
            left,
            right,
            disp_left: (e.path().to_path_buf(), DispKind::Pfm),
            disp_right: disp_r.map(|p| (p, DispKind::Pfm)),
            masks: if mask.is_file() { vec![(mask, MaskKind::Is255)] } else { vec![] },
            meta,
        });
    }
    Ok(out)
}

// ---------------------------------------------------------------- KITTI

fn kitti_training(root: &Path, left_dir: &str) -> Option<PathBuf> {
    [root.join("training"), root.to_path_buf()].into_iter().find(|d| d.join(left_dir).is_dir())
}

fn kitti(root: &Path, _format: DatasetFormat, (l, r): (&str, &str), occ: &str, occ_right: Option<&str>, noc: &str) -> Result<Vec<SampleFiles>> {
    let base = kitti_training(root, l).ok_or_else(|| Error::format(root, format!("no {l}/ folder (here or under training/)")))?;
    let mut out = Vec::new();
    for e in walk(&base.join(l), 1) {
        let name = file_name(e.path());
        // Only the reference frame `_10` of each pair has ground truth.
        if !name.ends_with("_10.png") {
            continue;
        }
        let right = require(base.join(r).join(&name), "right image", e.path())?;
        let disp = require(base.join(occ).join(&name), "disparity", e.path())?;
        let disp_r = occ_right.map(|d| base.join(d).join(&name)).filter(|p| p.is_file());
        let noc_path = base.join(noc).join(&name);
        out.push(SampleFiles {
            id: rel_id(root, e.path()),
            left: e.path().to_path_buf(),
            right,
            disp_left: (disp, DispKind::Png16(KITTI_SCALE)),
            disp_right: disp_r.map(|p| (p, DispKind::Png16(KITTI_SCALE))),
            masks: if noc_path.is_file() { vec![(noc_path, MaskKind::Png16NonZero)] } else { vec![] },
            meta: SampleMeta::default(),
        });
    }
    Ok(out)
}

// ---------------------------------------------------------------- Sintel

fn sintel_base(root: &Path) -> Option<PathBuf> {
    [root.join("training"), root.to_path_buf()].into_iter().find(|d| d.join("disparities").is_dir() && (d.join("clean_left").is_dir() || d.join("final_left").is_dir()))
}

fn sintel(root: &Path) -> Result<Vec<SampleFiles>> {
    let base = sintel_base(root).ok_or_else(|| Error::format(root, "no clean_left|final_left and disparities/ folders (here or under training/)"))?;
    let pass = if base.join("clean_left").is_dir() { "clean" } else { "final" };
    let left_root = base.join(format!("{pass}_left"));
    let mut out = Vec::new();
    for e in walk(&left_root, 2) {
        let p = e.path();
        if !e.file_type().is_file() || p.extension().is_none_or(|x| x != "png") {
            continue;
        }
        let rel = p.strip_prefix(&left_root).expect("under the left folder");
        let right = require(base.join(format!("{pass}_right")).join(rel), "right image", p)?;
        let disp = require(base.join("disparities").join(rel), "disparity", p)?;
        let masks = [("occlusions", MaskKind::IsZero), ("outofframe", MaskKind::IsZero)]
            .into_iter()
            .map(|(d, k)| (base.join(d).join(rel), k))
            .filter(|(p, _)| p.is_file())
            .collect();
        out.push(SampleFiles {
            id: rel_id(root, p),
            left: p.to_path_buf(),
            right,
            disp_left: (disp, DispKind::Sintel),
            disp_right: None,
            masks,
            meta: SampleMeta::default(),
        });
    }
    Ok(out)
}

// ---------------------------------------------------------------- Falling Things

/// The cameras of Falling Things are 6 cm apart.
pub const FALLING_THINGS_BASELINE_M: f64 = 0.06;

fn fat_fx(path: &Path) -> Result<(f64, Option<f64>, Option<f64>)> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| Error::format(path, format!("not JSON: {e}")))?;
    let intr = &v["camera_settings"][0]["intrinsic_settings"];
    let fx = intr["fx"].as_f64().ok_or_else(|| Error::format(path, "no camera_settings[0].intrinsic_settings.fx"))?;
    Ok((fx, intr["cx"].as_f64(), intr["cy"].as_f64()))
}

fn falling_things(root: &Path) -> Result<Vec<SampleFiles>> {
    let mut out = Vec::new();
    for settings in walk(root, 6).filter(|e| file_name(e.path()) == "_camera_settings.json") {
        let dir = settings.path().parent().unwrap_or(root);
        let (fx, cx, cy) = fat_fx(settings.path())?;
        let kind = DispKind::FatDepth { fx, baseline_m: FALLING_THINGS_BASELINE_M };
        for e in walk(dir, 1) {
            let name = file_name(e.path());
            let Some(stem) = name.strip_suffix(".left.jpg") else { continue };
            let right = require(dir.join(format!("{stem}.right.jpg")), "right image", e.path())?;
            let depth = require(dir.join(format!("{stem}.left.depth.png")), "left depth", e.path())?;
            let depth_r = dir.join(format!("{stem}.right.depth.png"));
            out.push(SampleFiles {
                id: rel_id(root, &dir.join(stem)),
                left: e.path().to_path_buf(),
                right,
                disp_left: (depth, kind),
                disp_right: depth_r.is_file().then_some((depth_r, kind)),
                masks: vec![],
                meta: SampleMeta { f_px: Some(fx), baseline_m: Some(FALLING_THINGS_BASELINE_M), cx, cy, ..Default::default() },
            });
        }
    }
    Ok(out)
}

// ---------------------------------------------------------------- detection

/// Recognises a layout from the files under `root`, most specific first: `manifest.jsonl`
/// (ours), Sintel's and KITTI's fixed folders, SceneFlow's `frames_*pass`, Falling Things'
/// `_camera_settings.json`, ETH3D's `disp0GT.pfm`, Middlebury's `disp0.pfm`, CREStereo's
/// `*_left.disp.png`.
pub fn detect_format(root: &Path) -> Result<DatasetFormat> {
    if root.join("manifest.jsonl").is_file() {
        return Ok(DatasetFormat::Stereogen);
    }
    if sintel_base(root).is_some() {
        return Ok(DatasetFormat::Sintel);
    }
    if kitti_training(root, "image_2").is_some_and(|b| b.join("disp_occ_0").is_dir()) {
        return Ok(DatasetFormat::Kitti2015);
    }
    if kitti_training(root, "colored_0").is_some_and(|b| b.join("disp_occ").is_dir()) {
        return Ok(DatasetFormat::Kitti2012);
    }
    let mut found: Option<DatasetFormat> = None;
    let mut rank = usize::MAX;
    let mut note = |f: DatasetFormat, r: usize| {
        if r < rank {
            rank = r;
            found = Some(f);
        }
    };
    for e in walk(root, 6).take(200_000) {
        let name = file_name(e.path());
        if e.file_type().is_dir() && (name == "frames_cleanpass" || name == "frames_finalpass") {
            note(DatasetFormat::SceneFlow, 0);
            break;
        }
        match name.as_str() {
            "_camera_settings.json" => note(DatasetFormat::FallingThings, 1),
            "disp0GT.pfm" => note(DatasetFormat::Eth3d, 2),
            "disp0.pfm" => note(DatasetFormat::Middlebury, 3),
            n if n.ends_with("_left.disp.png") => note(DatasetFormat::Crestereo, 4),
            _ => {}
        }
    }
    found.ok_or_else(|| {
        Error::format(root, "cannot recognise the dataset layout (stereogen, crestereo, sceneflow, middlebury, eth3d, kitti2012, kitti2015, sintel, fallingthings); pass the format explicitly")
    })
}
