//! A mesh folder feeds the presets' object categories (issue 27, point 9): `generate --meshes DIR`
//! with the default preset draws the folder's meshes where the recipe says `shapenet`, renders
//! them, and lists the folder's broken files in `skipped_assets.jsonl`.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use stereo_io::datasets::stereogen::read_skipped_assets;
use stereogen::assets::{AssetIndex, MeshAsset};
use stereogen::dataset::{Manifest, read_scene_spec};
use stereogen::plan::{Recipe, Shape, plan_scene};
use test_support::{generate_cmd, run_ok, stereogen_cmd, write_tiny_recipe};

/// A tetrahedron around the origin, stretched by `k` so the files differ.
fn tetrahedron(k: usize) -> String {
    let s = 1.0 + k as f64 * 0.1;
    format!(
        "v {s} 0 {m}\nv {m} {s} 0\nv 0 {m} {s}\nv 0 0 0\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n",
        m = -0.3 * s
    )
}

/// 19 valid OBJ tetrahedra and two broken OBJs (random bytes, a NaN vertex).
fn mesh_folder(dir: &Path) -> (PathBuf, Vec<PathBuf>) {
    let root = dir.join("meshes");
    std::fs::create_dir_all(&root).unwrap();
    for k in 0..19 {
        std::fs::write(root.join(format!("tetra_{k:02}.obj")), tetrahedron(k)).unwrap();
    }
    let noise: Vec<u8> = (0u32..512)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
        .collect();
    let broken = vec![root.join("noise.obj"), root.join("nan_vertex.obj")];
    std::fs::write(&broken[0], noise).unwrap();
    std::fs::write(
        &broken[1],
        tetrahedron(0).replacen("v 0 0 0", "v 0 nan 0", 1),
    )
    .unwrap();
    (root, broken)
}

/// The `source` of every object drawn from a mesh folder, over `samples` plans.
fn mesh_sources(assets: &AssetIndex, samples: u64) -> BTreeMap<String, usize> {
    let recipe = Recipe::preset("crestereo").unwrap();
    let mut n = BTreeMap::new();
    for i in 0..samples {
        for o in plan_scene(&recipe, assets, 0, i).objects {
            if let Shape::MeshFile { candidates, .. } = &o.shape {
                let folder = if candidates[0].starts_with("/shapenet") {
                    "shapenet"
                } else {
                    "meshes"
                };
                assert_eq!(
                    o.source, folder,
                    "{}: recorded source and file differ",
                    o.name
                );
                *n.entry(o.source).or_default() += 1;
            }
        }
    }
    n
}

fn files(root: &str, n: usize) -> Vec<MeshAsset> {
    (0..n)
        .map(|i| MeshAsset {
            path: PathBuf::from(format!("{root}/{i}.obj")),
            synset: None,
            label: None,
        })
        .collect()
}

#[test]
fn the_preset_draws_the_mesh_folder_alone_and_shares_evenly_with_shapenet() {
    let only_meshes = AssetIndex {
        meshes: files("/meshes", 19),
        ..Default::default()
    };
    let n = mesh_sources(&only_meshes, 40);
    assert!(
        n.get("meshes").copied().unwrap_or(0) > 20 && !n.contains_key("shapenet"),
        "{n:?}"
    );

    let only_shapenet = AssetIndex {
        shapenet: files("/shapenet", 500),
        ..Default::default()
    };
    let n = mesh_sources(&only_shapenet, 40);
    assert!(!n.contains_key("meshes"), "{n:?}");

    // Both: each draw takes one of the two folders with equal chance, however many files each has.
    let both = AssetIndex {
        shapenet: files("/shapenet", 500),
        meshes: files("/meshes", 19),
        ..Default::default()
    };
    let n = mesh_sources(&both, 200);
    let (s, m) = (n["shapenet"] as f64, n["meshes"] as f64);
    let share = m / (s + m);
    assert!(
        (0.4..0.6).contains(&share),
        "share of the mesh folder {share} ({n:?})"
    );
}

/// Pixels of `a` and `b` whose disparity differs (validity or value).
fn differing(a: &stereo_io::DisparityMap, b: &stereo_io::DisparityMap) -> Vec<usize> {
    (0..a.data.len())
        .filter(|&i| a.valid[i] != b.valid[i] || (a.data[i] - b.data[i]).abs() > 1e-3)
        .collect()
}

#[test]
fn generate_with_a_mesh_folder_renders_its_meshes_and_lists_its_broken_files() {
    let dir = tempfile::tempdir().unwrap();
    let (meshes, broken) = mesh_folder(dir.path());
    let recipe = write_tiny_recipe(dir.path(), "crestereo");
    let out = dir.path().join("data");
    run_ok(generate_cmd(&recipe, &out, 4).arg("--meshes").arg(&meshes));

    // The broken files are listed as skipped, with a reason each.
    let skipped = read_skipped_assets(&out.join("skipped_assets.jsonl"))
        .unwrap()
        .records;
    let listed: BTreeSet<&Path> = skipped.iter().map(|r| r.path.as_path()).collect();
    for b in &broken {
        assert!(
            listed.contains(b.as_path()),
            "{} not in {skipped:?}",
            b.display()
        );
    }

    let entries = Manifest::read(&out.join("manifest.jsonl")).unwrap();
    assert_eq!(entries.len(), 4);
    let mut checked = 0;
    for e in &entries {
        let spec = read_scene_spec(&out.join(&e.files.scene)).unwrap();
        let drawn: Vec<usize> = (0..spec.objects.len())
            .filter(|&i| spec.objects[i].source == "meshes")
            .collect();
        for &i in &drawn {
            let Shape::MeshFile { candidates, .. } = &spec.objects[i].shape else {
                panic!(
                    "{}: a mesh-folder object without a mesh file",
                    spec.objects[i].name
                )
            };
            assert!(
                candidates
                    .iter()
                    .all(|c| c.starts_with(&meshes) && !broken.contains(c))
            );
        }
        if drawn.is_empty() {
            continue;
        }
        // The worker says which file each object used.
        assert!(
            e.notes
                .iter()
                .any(|n| n.contains(" uses ") && n.contains(&*meshes.to_string_lossy())),
            "{}: {:?}",
            e.id,
            e.notes
        );
        // Visible: rendering the same scene without the folder's objects changes the left
        // disparity, and the changed pixels sit near those objects' target disparities.
        let mut without = spec.clone();
        without.objects = (0..spec.objects.len())
            .filter(|i| !drawn.contains(i))
            .map(|i| spec.objects[i].clone())
            .collect();
        let spec_file = dir.path().join(format!("{}-without.scene.json", e.id));
        std::fs::write(&spec_file, without.to_json()).unwrap();
        let rerender = dir.path().join(format!("without-{}", e.id));
        run_ok(
            stereogen_cmd(["render", "--threads", "1", "--spec"])
                .arg(&spec_file)
                .arg("--out")
                .arg(&rerender),
        );
        let (with, _) = stereo_io::read_disparity_exr(&out.join(&e.files.disp_left)).unwrap();
        let (bare, _) = stereo_io::read_disparity_exr(&rerender.join(&e.files.disp_left)).unwrap();
        let changed = differing(&with, &bare);
        assert!(
            !changed.is_empty(),
            "{}: the folder's objects change no pixel",
            e.id
        );
        let targets: Vec<f64> = drawn
            .iter()
            .filter_map(|&i| spec.objects[i].target_disparity)
            .collect();
        let near = changed
            .iter()
            .filter(|&&p| {
                with.valid[p]
                    && targets
                        .iter()
                        .any(|t| ((with.data[p] as f64) - t).abs() < 0.5 * t)
            })
            .count();
        assert!(
            near * 2 > changed.len(),
            "{}: {near} of {} changed pixels near the targets {targets:?}",
            e.id,
            changed.len()
        );
        eprintln!(
            "{}: {} mesh-folder object(s), {} pixel(s) change without them, {near} near their targets",
            e.id,
            drawn.len(),
            changed.len()
        );
        checked += 1;
    }
    assert!(checked > 0, "no sample drew from the mesh folder");
}
