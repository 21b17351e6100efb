//! WebDataset export and reading: shards GNU tar lists and extracts byte for byte, samples read
//! back equal to the source's, a seeded shuffle, splits, a shard cut short named as such, an
//! interrupted export resumed to the same bytes, an existing export refused without `force`.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::Command;

use stereo_io::*;

use crate::io_fixtures;
use crate::pinned_venv;
use crate::python_script_json;
use io_fixtures::*;
use stereo_io::datasets::map_member;
use stereo_io::datasets::webdataset::decode_member_maps;

/// The readers nobody here wrote: the `webdataset` package, Pillow, OpenEXR.
const PYTHON_PINS: &[&str] = &[
    "webdataset==1.0.2",
    "pillow==13.0.0",
    "OpenEXR==3.5.3",
    "numpy==2.4.6",
];

fn opts(force: bool) -> WebDatasetOptions {
    WebDatasetOptions {
        // About two samples per shard.
        shard_bytes: 6000,
        shuffle_seed: 3,
        splits: parse_splits("train=0.7,val=0.3").unwrap(),
        force,
    }
}

fn export(source: &Path, out: &Path, o: &WebDatasetOptions) -> Result<WebDatasetSummary> {
    export_webdataset(source, out, None, &ReadOptions::default(), o)
}

/// Every file of an export folder with its size and a hash of its bytes, sorted by name.
fn files(dir: &Path) -> Vec<(String, usize, u64)> {
    use std::hash::{Hash, Hasher};
    let mut out: Vec<_> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .map(|p| {
            let bytes = fs::read(&p).unwrap();
            let mut h = std::collections::hash_map::DefaultHasher::new();
            bytes.hash(&mut h);
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                bytes.len(),
                h.finish(),
            )
        })
        .collect();
    out.sort();
    out
}

fn gnu_tar(args: &[&str], shard: &Path) -> Vec<u8> {
    test_support::run_ok(Command::new("tar").args(args).arg(shard)).stdout
}

#[test]
fn shards_hold_every_sample_as_the_source_has_it() {
    let t = tempfile::tempdir().unwrap();
    let (source, out) = (t.path().join("ours"), t.path().join("wds"));
    our_dataset(&mkdir(&source));
    let summary = export(&source, &out, &opts(false)).unwrap();
    assert_eq!((summary.samples, summary.resumed_shards), (IDS, 0));
    assert!(summary.shards >= 4, "{summary:?}");

    // GNU tar lists each shard: a sample's six members together, in order, under one key (the
    // SceneSpec travels as stored, so `stats` can compute the object figures from shards).
    let mut keys = vec![];
    for split in ["train", "val"] {
        let index: serde_json::Value =
            serde_json::from_slice(&fs::read(out.join(format!("{split}.index.json"))).unwrap())
                .unwrap();
        let mut total = 0;
        for shard in index["shards"].as_array().unwrap() {
            let path = out.join(shard["name"].as_str().unwrap());
            assert_eq!(
                fs::metadata(&path).unwrap().len(),
                shard["bytes"].as_u64().unwrap()
            );
            let listing = String::from_utf8(gnu_tar(&["-tf"], &path)).unwrap();
            let names: Vec<&str> = listing.lines().collect();
            assert_eq!(names.len() % 6, 0, "{listing}");
            for group in names.chunks(6) {
                let key = group[0].strip_suffix(".left.png").expect(group[0]);
                let want: Vec<String> = [
                    "left.png",
                    "right.png",
                    "disp_left.exr",
                    "disp_right.exr",
                    "scene.json",
                    "json",
                ]
                .iter()
                .map(|m| format!("{key}.{m}"))
                .collect();
                assert_eq!(group, want.as_slice());
                keys.push(key.to_string());
            }
            total += shard["samples"].as_u64().unwrap();
            // GNU tar extracts the source's EXR byte for byte.
            let first = names[2];
            let (category, id) = first
                .trim_end_matches(".disp_left.exr")
                .split_once('/')
                .unwrap();
            let member = Command::new("tar")
                .args(["-xOf"])
                .arg(&path)
                .arg(first)
                .output()
                .unwrap();
            assert_eq!(
                member.stdout,
                fs::read(source.join(category).join(format!("{id}_left.disp.exr"))).unwrap(),
                "{first}"
            );
        }
        assert_eq!(total, index["samples"].as_u64().unwrap());
    }
    assert_eq!(keys.len(), IDS);
    let in_order: Vec<String> = (0..IDS)
        .map(|k| format!("{}/{k:07}", ["tree", "hole"][k % 2]))
        .collect();
    assert_ne!(keys, in_order, "the seed shuffles samples across shards");
    let mut sorted = keys.clone();
    sorted.sort();
    let mut want = in_order.clone();
    want.sort();
    assert_eq!(sorted, want, "every sample once");

    // Read back through open_dataset: the source's pixels, disparities and camera.
    let ours = open_dataset(&source, None).unwrap();
    let shards = open_dataset(&out, None).unwrap();
    assert_eq!(
        (shards.format(), shards.len()),
        (DatasetFormat::WebDataset, IDS)
    );
    for i in 0..IDS {
        let got = shards.sample(i).unwrap();
        let key = shards.id(i).unwrap();
        let k = (0..IDS).find(|&k| in_order[k] == key).unwrap();
        let want = ours.sample(k).unwrap();
        assert_eq!((&got.left, &got.right), (&want.left, &want.right), "{key}");
        assert_disp_eq(&got.disp_left, &want.disp_left);
        assert_disp_eq(
            got.disp_right.as_ref().unwrap(),
            want.disp_right.as_ref().unwrap(),
        );
        assert_eq!((got.meta.f_px, got.meta.cx), (want.meta.f_px, want.meta.cx));
        assert_eq!(
            got.meta.extra.get("category"),
            want.meta.extra.get("category")
        );
        assert_eq!(got.meta.format, Some(DatasetFormat::Stereogen));
    }

    // The same options give the same bytes; an existing export is refused without force.
    let again = t.path().join("again");
    export(&source, &again, &opts(false)).unwrap();
    assert_eq!(files(&out), files(&again));
    let e = export(&source, &out, &opts(false)).unwrap_err().to_string();
    assert!(e.contains("not empty") && e.contains("--force"), "{e}");
    export(&source, &out, &opts(true)).unwrap();
    assert_eq!(files(&out), files(&again));
}

/// The error `r` must be, as text (an `Ok` fails the test).
fn error_text<T>(r: Result<T>) -> String {
    r.err().expect("an error").to_string()
}

/// Our tiny dataset written to `dir/ours` and exported with [`opts`] to `dir/wds`; returns both.
fn exported_ours(dir: &Path) -> (PathBuf, PathBuf) {
    let (source, out) = (dir.join("ours"), dir.join("wds"));
    our_dataset(&mkdir(&source));
    export(&source, &out, &opts(false)).unwrap();
    (source, out)
}

/// A split is opened on its own: `open_splits` reads the named splits' shards only (in index
/// order, whatever the order asked), `open` every split, and a split the export lacks is an
/// error listing those it has.
#[test]
fn splits_open_on_their_own() {
    let t = tempfile::tempdir().unwrap();
    let (_, out) = exported_ours(t.path());
    assert_eq!(WebDataset::split_names(&out).unwrap(), ["train", "val"]);
    let ids = |ds: &WebDataset| -> Vec<String> {
        (0..ds.len())
            .map(|i| ds.id(i).unwrap().to_string())
            .collect()
    };
    let index_count = |split: &str| -> usize {
        let index: serde_json::Value =
            serde_json::from_slice(&fs::read(out.join(format!("{split}.index.json"))).unwrap())
                .unwrap();
        index["samples"].as_u64().unwrap() as usize
    };
    let train = WebDataset::open_splits(&out, &["train"]).unwrap();
    let val = WebDataset::open_splits(&out, &["val"]).unwrap();
    assert_eq!(
        (train.splits(), val.splits()),
        (&["train".to_string()][..], &["val".to_string()][..])
    );
    assert_eq!(
        (train.len(), val.len()),
        (index_count("train"), index_count("val"))
    );
    assert!(train.len() > val.len() && !val.is_empty());
    let (train_ids, val_ids) = (ids(&train), ids(&val));
    assert!(train_ids.iter().all(|k| !val_ids.contains(k)));
    let all = WebDataset::open(&out).unwrap();
    assert_eq!(ids(&all), [train_ids.clone(), val_ids.clone()].concat());
    let both = WebDataset::open_splits(&out, &["val", "train", "val"]).unwrap();
    assert_eq!(ids(&both), ids(&all));
    // A val sample read from its split alone is the one read from the whole export.
    let k = train.len();
    assert!(val.sample(0).unwrap().left == all.sample(k).unwrap().left);
    // Streaming numbers the shards of the opened splits only.
    assert_eq!(val.shard_samples().iter().sum::<usize>(), val.len());
    assert_eq!(val.shard_reader(0).unwrap().read(&val, 0).unwrap().index, 0);
    let e = error_text(WebDataset::open_splits(&out, &["test"]));
    assert!(
        e.contains("no split \"test\"") && e.contains("its splits: train, val"),
        "{e}"
    );
    let none: [&str; 0] = [];
    let e = error_text(WebDataset::open_splits(&out, &none));
    assert!(e.contains("no split asked for"), "{e}");
}

#[test]
fn a_shard_cut_short_is_named_not_read_as_fewer_samples() {
    let t = tempfile::tempdir().unwrap();
    let (_, out) = exported_ours(t.path());
    let shard = out.join("train-000001.tar");
    let bytes = fs::read(&shard).unwrap();
    // Cut at a block boundary (what a killed copy leaves): tar itself would read fewer members.
    fs::write(&shard, &bytes[..bytes.len() / 1024 * 512]).unwrap();
    let e = error_text(open_dataset(&out, None));
    assert!(
        e.contains("train-000001.tar") && e.contains("cut short"),
        "{e}"
    );
    // An export that never wrote its index is not a dataset at all.
    fs::remove_file(out.join("train.index.json")).unwrap();
    fs::remove_file(out.join("val.index.json")).unwrap();
    let e = error_text(open_dataset(&out, Some(DatasetFormat::WebDataset)));
    assert!(e.contains("did not finish"), "{e}");
}

#[test]
fn an_interrupted_export_resumes_from_its_last_whole_shard() {
    let t = tempfile::tempdir().unwrap();
    let (source, out, clean) = (
        t.path().join("ours"),
        t.path().join("wds"),
        t.path().join("clean"),
    );
    our_dataset(&mkdir(&source));
    export(&source, &clean, &opts(false)).unwrap();
    // A sample late in the shuffled order cannot be read: the export stops there, after some
    // whole shards.
    let late = {
        let shards = open_dataset(&clean, None).unwrap();
        shards.id(IDS - 3).unwrap().to_string()
    };
    let (category, id) = late.split_once('/').unwrap();
    let victim = source.join(category).join(format!("{id}_right.png"));
    let good = fs::read(&victim).unwrap();
    fs::write(&victim, b"not a png").unwrap();
    let e = export(&source, &out, &opts(false)).unwrap_err().to_string();
    assert!(e.contains(&format!("{id}_right.png")), "{e}");
    assert!(!out.join("train.index.json").exists() || !out.join("val.index.json").exists());
    // Fixed and re-run: the whole shards are kept, the rest written, the result the clean one.
    fs::write(&victim, good).unwrap();
    let summary = export(&source, &out, &opts(false)).unwrap();
    assert!(summary.resumed_shards > 0, "{summary:?}");
    assert_eq!(files(&out), files(&clean));
    // Other options than the unfinished run's are refused rather than mixed into it.
    fs::write(&victim, b"not a png").unwrap();
    let _ = export(&source, &t.path().join("wds2"), &opts(false));
    let mut other = opts(false);
    other.shuffle_seed = 4;
    let e = export(&source, &t.path().join("wds2"), &other)
        .unwrap_err()
        .to_string();
    assert!(e.contains("same ones") && e.contains("--force"), "{e}");
}

#[test]
fn the_webdataset_package_reads_our_shards_as_we_read_the_source() {
    let venv = pinned_venv::ensure_venv("venv-webdataset", PYTHON_PINS);
    let t = tempfile::tempdir().unwrap();
    let (source, out) = exported_ours(t.path());
    let read = t.path().join("read");
    let keys = python_script_json(&venv, "webdataset_reader.py", &out, &read);
    let keys = keys.as_array().unwrap();
    assert_eq!(keys.len(), IDS, "every sample, once");
    let ours = open_dataset(&source, None).unwrap();
    let npy = |name: String| read_npy(&read.join(name)).unwrap().data;
    let disparity = |d: &DisparityMap| -> Vec<f32> {
        d.data
            .iter()
            .zip(&d.valid)
            .map(|(&v, &ok)| if ok { v } else { f32::NAN })
            .collect()
    };
    let same = |a: &[f32], b: &[f32]| {
        a.len() == b.len()
            && a.iter()
                .zip(b)
                .all(|(x, y)| x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()))
    };
    for (n, k) in keys.iter().enumerate() {
        let (key, id) = (k["key"].as_str().unwrap(), k["id"].as_str().unwrap());
        assert!(key.ends_with(id), "{key} names sample {id}");
        let i = (0..IDS)
            .find(|&i| ours.id(i).is_some_and(|x| x.ends_with(id)))
            .unwrap();
        let s = ours.sample(i).unwrap();
        let pixels = |img: &RgbImage| img.data.iter().map(|&v| f32::from(v)).collect::<Vec<_>>();
        assert_eq!(npy(format!("{n}_left.npy")), pixels(&s.left), "{key}");
        assert_eq!(npy(format!("{n}_right.npy")), pixels(&s.right), "{key}");
        assert!(
            same(&npy(format!("{n}_disp_left.npy")), &disparity(&s.disp_left)),
            "{key}"
        );
        let right = s.disp_right.as_ref().unwrap();
        assert!(
            same(&npy(format!("{n}_disp_right.npy")), &disparity(right)),
            "{key}"
        );
    }
}

/// Adds every map to each sample of [`our_dataset`] at `root`, as `generate` names them, with an
/// instance table in each manifest line: depth `f·B/d` where the disparity is valid, unit
/// normals, instance and class ids that vary per pixel (0 where there is no surface).
fn add_maps(root: &Path) {
    let text = fs::read_to_string(root.join("manifest.jsonl")).unwrap();
    let mut lines = String::new();
    for line in text.lines() {
        let mut e: serde_json::Value = serde_json::from_str(line).unwrap();
        let (category, id) = (e["category"].as_str().unwrap(), e["id"].as_str().unwrap());
        let k: u16 = id.parse().unwrap();
        let paths = SamplePaths::with_maps(category, id, &MapKind::ALL);
        for (view, disp_key) in [("left", "disp_left"), ("right", "disp_right")] {
            let rel = e["files"][disp_key].as_str().unwrap().to_string();
            let (d, _) = read_disparity_exr(&root.join(rel)).unwrap();
            let surface = |i: usize| d.valid[i] && d.data[i] > 0.0;
            let depth = DepthMap {
                width: W,
                height: H,
                data: (0..W * H)
                    .map(|i| {
                        if surface(i) {
                            (6.4 / f64::from(d.data[i])) as f32
                        } else {
                            0.0
                        }
                    })
                    .collect(),
            };
            let normals = NormalMap {
                width: W,
                height: H,
                data: (0..W * H)
                    .map(|i| {
                        let a = i as f32 * 0.3 + f32::from(k);
                        if surface(i) {
                            [a.sin() * 0.6, a.cos() * 0.6, -0.8]
                        } else {
                            [0.0; 3]
                        }
                    })
                    .collect(),
            };
            let ids = |base: u16| IdMap {
                width: W,
                height: H,
                data: (0..W * H)
                    .map(|i| {
                        if surface(i) {
                            base + (i as u16 + k) % 3
                        } else {
                            0
                        }
                    })
                    .collect(),
            };
            let path = |kind| root.join(paths.map(kind, view).unwrap());
            write_depth_exr(&path(MapKind::Depth), &depth, view).unwrap();
            stereo_io::maps::write_normals_exr(&path(MapKind::Normals), &normals, view).unwrap();
            write_id_png(&path(MapKind::Instance), &ids(1)).unwrap();
            write_id_png(&path(MapKind::Semantic), &ids(500)).unwrap();
        }
        for (key, p) in paths.all().into_iter().skip(5) {
            e["files"][key] = p.to_string_lossy().into();
        }
        e["instances"] = (1..=3)
            .map(|n| serde_json::json!({"id": n, "name": format!("obj{n}"), "role": "content", "source": "primitive", "material": "textured", "semantic": 499 + n}))
            .collect();
        lines += &format!("{e}\n");
    }
    fs::write(root.join("manifest.jsonl"), lines).unwrap();
}

/// The maps a source of ours has travel as members (`<key>.depth_left.exr`, ... the source's
/// files byte for byte, after the disparities) and read back unchanged: by `open_dataset` of the
/// export (seeking and streaming), and by the `webdataset` package with OpenEXR and Pillow.
#[test]
fn maps_travel_as_members_and_read_back_unchanged() {
    let venv = pinned_venv::ensure_venv("venv-webdataset", PYTHON_PINS);
    let t = tempfile::tempdir().unwrap();
    let (source, out) = (t.path().join("ours"), t.path().join("wds"));
    our_dataset(&mkdir(&source));
    add_maps(&source);
    export(&source, &out, &opts(false)).unwrap();
    let ours = open_dataset(&source, None).unwrap();
    let shards = WebDataset::open(&out).unwrap();
    let members = stereo_io::datasets::webdataset::members::ShardMembers::open(&out).unwrap();
    let maps: Vec<String> = MapKind::ALL
        .iter()
        .flat_map(|&k| ["left", "right"].map(|v| map_member(k, v)))
        .collect();
    let mut by_id = std::collections::HashMap::new();
    for i in 0..IDS {
        let got = shards.sample(i).unwrap();
        let k = (0..IDS)
            .find(|&k| ours.id(k) == Some(got.meta.id.as_str()))
            .unwrap();
        by_id.insert(got.meta.id.clone(), k);
        let want = ours.sample(k).unwrap();
        assert_eq!((&got.left, &got.disp_left), (&want.left, &want.disp_left));
        assert_eq!(got.meta.instances, want.meta.instances);
        assert_eq!(got.meta.instances.len(), 3);
        // Members in order: images, disparities, the eight maps, SceneSpec, facts.
        let suffixes: Vec<&str> = members.suffixes(i).collect();
        let mut order = vec!["left.png", "right.png", "disp_left.exr", "disp_right.exr"];
        order.extend(maps.iter().map(String::as_str));
        order.extend(["scene.json", "json"]);
        assert_eq!(suffixes, order);
        // The source's files byte for byte.
        for f in &want.meta.maps {
            let bytes = members
                .read(i, &map_member(f.kind, f.view))
                .unwrap()
                .unwrap();
            assert!(bytes == fs::read(&f.path).unwrap(), "{}", f.path.display());
        }
        let source_maps = ours.maps(k).unwrap();
        assert_eq!(source_maps.kinds(), MapKind::ALL);
        // Every map in both views: 8 in all.
        for kind in MapKind::ALL {
            assert!(
                source_maps.left.has(kind) && source_maps.right.has(kind),
                "{kind}"
            );
        }
        assert_eq!(shards.maps(i).unwrap(), source_maps);
        // Streamed: the raw members decode to the same maps.
        let raw = shards.read_raw(i).unwrap();
        assert_eq!(shards.decode_maps(&raw).unwrap(), source_maps);
        let streamed =
            decode_member_maps(Path::new("x.tar"), shards.id(i).unwrap(), &raw.members).unwrap();
        assert_eq!(streamed, source_maps);
    }
    assert!(ours.maps(IDS).is_err() && shards.maps(IDS).is_err());

    let read = t.path().join("read");
    let keys = python_script_json(&venv, "webdataset_reader.py", &out, &read);
    let keys = keys.as_array().unwrap();
    assert_eq!(keys.len(), IDS, "every sample, once");
    let npy = |name: String| read_npy(&read.join(name)).unwrap().data;
    for (n, k) in keys.iter().enumerate() {
        assert_eq!(k["maps"], serde_json::json!(maps), "{k}");
        let m = ours.maps(by_id[k["id"].as_str().unwrap()]).unwrap();
        for (kind, view) in MapKind::ALL
            .into_iter()
            .flat_map(|k| [(k, "left"), (k, "right")])
        {
            let v = m.view(view);
            let want: Vec<f32> = match kind {
                MapKind::Depth => v.depth.clone().unwrap().data,
                MapKind::Normals => v
                    .normals
                    .clone()
                    .unwrap()
                    .data
                    .into_iter()
                    .flatten()
                    .collect(),
                MapKind::Instance | MapKind::Semantic => {
                    let ids = if kind == MapKind::Instance {
                        &v.instance
                    } else {
                        &v.semantic
                    };
                    ids.as_ref()
                        .unwrap()
                        .data
                        .iter()
                        .map(|&i| f32::from(i))
                        .collect()
                }
            };
            let got = npy(format!("{n}_{kind}_{view}.npy"));
            assert!(
                got.iter()
                    .map(|v| v.to_bits())
                    .eq(want.iter().map(|v| v.to_bits())),
                "{kind} {view} of sample {n}: {got:?} != {want:?}"
            );
        }
    }
}
