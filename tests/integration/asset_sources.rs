//! ShapeNet trees (both layouts), mesh folders in every format, photo textures — with broken
//! files among them that must be skipped and listed, never crash a run.

use std::collections::BTreeMap;
use std::path::Path;

use stereogen::dataset::Manifest;
use stereogen::plan::recipe::ShapeSource;
use stereogen::plan::{BaseColor, MaterialSpec, SceneSpec, Shape};
use stereogen::render::RenderService;
use test_support::scenes::{base, object, plane};
use test_support::{generate_cmd, tiny_recipe, worker_config};

const CUBE_OBJ: &str = "v -1 -1 -1\nv 1 -1 -1\nv 1 1 -1\nv -1 1 -1\nv -1 -1 1\nv 1 -1 1\nv 1 1 1\nv -1 1 1\n\
f 1 2 3 4\nf 5 8 7 6\nf 1 5 6 2\nf 2 6 7 3\nf 3 7 8 4\nf 5 1 4 8\n";
const TETRA_PLY: &str = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n\
element face 4\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n";
const TETRA_STL: &str = "solid t\nfacet normal 0 0 -1\nouter loop\nvertex 0 0 0\nvertex 0 1 0\nvertex 1 0 0\nendloop\nendfacet\n\
facet normal 0 -1 0\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 0 1\nendloop\nendfacet\n\
facet normal -1 0 0\nouter loop\nvertex 0 0 0\nvertex 0 0 1\nvertex 0 1 0\nendloop\nendfacet\n\
facet normal 1 1 1\nouter loop\nvertex 1 0 0\nvertex 0 1 0\nvertex 0 0 1\nendloop\nendfacet\nendsolid t\n";
const OCTA_OFF: &str = "OFF\n6 8 0\n1 0 0\n-1 0 0\n0 1 0\n0 -1 0\n0 0 1\n0 0 -1\n\
3 0 2 4\n3 2 1 4\n3 1 3 4\n3 3 0 4\n3 2 0 5\n3 1 2 5\n3 3 1 5\n3 0 3 5\n";
/// Not a mesh in any format.
const GARBAGE: &[u8] = b"\x00\x01\x02 this was a mesh before the disk went bad \xff\xfe";

fn write(path: &Path, bytes: &[u8]) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, bytes).unwrap();
}

fn mesh_file(candidates: Vec<std::path::PathBuf>) -> Shape {
    Shape::MeshFile {
        candidates,
        max_triangles: 100_000,
    }
}

#[test]
fn every_mesh_format_loads_and_broken_candidates_fall_back() {
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n);
    write(&p("cube.obj"), CUBE_OBJ.as_bytes());
    write(&p("tetra.ply"), TETRA_PLY.as_bytes());
    write(&p("tetra.stl"), TETRA_STL.as_bytes());
    write(&p("octa.off"), OCTA_OFF.as_bytes());
    write(&p("broken.obj"), GARBAGE);
    write(&p("broken.ply"), GARBAGE);
    // Distinct vertices, but every triangle collapsed onto one line: zero area.
    write(
        &p("flat.obj"),
        b"v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nf 1 2 3\nf 2 3 4\n",
    );
    let flat = MaterialSpec::flat([0.6, 0.5, 0.4], 0.5);
    let mut objects = vec![plane("wall", [0.0, 0.0, -6.0], [0.0; 3], 40.0)];
    for (i, name) in ["cube.obj", "tetra.ply", "tetra.stl", "octa.off"]
        .iter()
        .enumerate()
    {
        objects.push(object(
            name,
            mesh_file(vec![p(name)]),
            [-0.9 + 0.6 * i as f64, 0.0, -3.0],
            [0.3, 0.4, 0.0],
            [0.25; 3],
            flat.clone(),
        ));
    }
    objects.push(object(
        "fallback",
        mesh_file(vec![
            p("broken.obj"),
            p("missing.obj"),
            p("broken.ply"),
            p("flat.obj"),
            p("cube.obj"),
        ]),
        [0.0, 0.6, -3.0],
        [0.0; 3],
        [0.2; 3],
        flat.clone(),
    ));
    objects.push(object(
        "hopeless",
        mesh_file(vec![p("broken.obj")]),
        [0.0, -0.6, -3.0],
        [0.0; 3],
        [0.2; 3],
        flat,
    ));
    let spec = base("meshes", objects);
    let rendered = RenderService::new(worker_config())
        .render(&spec, |_| None)
        .expect("a broken asset never fails the scene");
    let notes = rendered.reply.report.notes.join("\n");
    println!("{notes}");
    for name in ["cube.obj", "tetra.ply", "tetra.stl", "octa.off"] {
        assert!(
            notes.contains(&format!("{} uses {}", name, p(name).display())),
            "{name} not loaded:\n{notes}"
        );
    }
    assert!(
        notes.contains(&format!("fallback uses {}", p("cube.obj").display())),
        "{notes}"
    );
    assert!(notes.contains("hopeless dropped"), "{notes}");
    let skipped: BTreeMap<String, String> = rendered
        .reply
        .report
        .skipped_assets
        .iter()
        .map(|s| {
            (
                s.path.file_name().unwrap().to_string_lossy().into_owned(),
                s.reason.clone(),
            )
        })
        .collect();
    println!("{skipped:?}");
    for name in ["broken.obj", "missing.obj", "broken.ply"] {
        assert!(
            skipped.contains_key(name),
            "{name} not reported: {skipped:?}"
        );
    }
    assert_eq!(skipped["missing.obj"], "file not found");
    assert_eq!(
        skipped.get("flat.obj").map(String::as_str),
        Some("degenerate: its triangles have zero area"),
        "{skipped:?}"
    );
}

fn generate(recipe: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    generate_cmd(recipe, out, 3)
        .args(["--seed", "3"])
        .args(extra)
        .output()
        .unwrap()
}

fn scenes(out: &Path) -> Vec<SceneSpec> {
    Manifest::read(&out.join("manifest.jsonl"))
        .unwrap()
        .iter()
        .map(|e| stereogen::dataset::read_scene_spec(&out.join(&e.files.scene)).unwrap())
        .collect()
}

#[test]
fn shapenet_layouts_and_a_texture_folder_with_broken_files() {
    let dir = tempfile::tempdir().unwrap();
    let shapenet = dir.path().join("ShapeNetCore");
    write(
        &shapenet.join("02691156/plane01/model.obj"),
        CUBE_OBJ.as_bytes(),
    ); // v1
    write(
        &shapenet.join("03001627/chair01/models/model_normalized.obj"),
        CUBE_OBJ.as_bytes(),
    ); // v2
    write(
        &shapenet.join("03001627/chair02/models/model_normalized.obj"),
        GARBAGE,
    );
    write(
        &shapenet.join("04379243/table01/models/model_normalized.obj"),
        b"",
    );
    write(
        &shapenet.join("taxonomy.json"),
        br#"[{"synsetId":"03001627","name":"chair","children":[],"numInstances":2}]"#,
    );
    let textures = dir.path().join("photos");
    for (i, c) in [[200u8, 40, 40], [30, 160, 90]].iter().enumerate() {
        std::fs::create_dir_all(&textures).unwrap();
        image::RgbImage::from_fn(16, 16, |x, y| {
            if (x / 4 + y / 4) % 2 == 0 {
                image::Rgb(*c)
            } else {
                image::Rgb([250, 250, 250])
            }
        })
        .save(textures.join(format!("photo{i}.png")))
        .unwrap();
    }
    write(
        &textures.join("corrupt.jpg"),
        b"\xff\xd8\xff\xe0 truncated jpeg",
    );

    let mut recipe = tiny_recipe("shapenet");
    recipe.categories[0].shapes = BTreeMap::from([(ShapeSource::Shapenet, 1.0)]);
    recipe.categories[0].objects = stereogen::plan::recipe::CountRange { min: 4, max: 5 };
    let recipe_path = dir.path().join("recipe.toml");
    std::fs::write(&recipe_path, toml::to_string(&recipe).unwrap()).unwrap();
    let out = dir.path().join("data");
    let o = generate(
        &recipe_path,
        &out,
        &[
            "--shapenet",
            shapenet.to_str().unwrap(),
            "--textures",
            textures.to_str().unwrap(),
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");

    let skipped = std::fs::read_to_string(out.join("skipped_assets.jsonl")).unwrap();
    println!("{skipped}");
    assert!(
        skipped.contains("table01") && skipped.contains("empty file"),
        "zero-byte model listed: {skipped}"
    );
    assert!(
        skipped.contains("corrupt.jpg"),
        "corrupt photo listed: {skipped}"
    );
    // Listed and warned about once each, however many samples drew them.
    assert_eq!(skipped.matches("corrupt.jpg").count(), 1, "{skipped}");
    assert_eq!(
        err.matches("corrupt.jpg").count(),
        1,
        "one warning for the bad photo:\n{err}"
    );
    assert!(
        skipped.contains("chair02"),
        "the corrupt model was drawn and listed: {skipped}"
    );

    let specs = scenes(&out);
    assert_eq!(specs.len(), 3);
    let meshes: Vec<&Shape> = specs
        .iter()
        .flat_map(|s| s.objects.iter())
        .filter(|o| o.source == "shapenet")
        .map(|o| &o.shape)
        .collect();
    assert!(meshes.len() >= 12);
    let drawn: String = meshes.iter().map(|s| format!("{s:?}")).collect();
    assert!(
        drawn.contains("plane01") && drawn.contains("chair01"),
        "both layouts drawn"
    );
    assert!(!drawn.contains("table01"), "empty files are never drawn");
    let photos = specs
        .iter()
        .flat_map(|s| s.objects.iter())
        .filter(|o| matches!(&o.material.base, BaseColor::Image { .. }))
        .count();
    assert!(photos > 0, "photo textures used");
    let notes: Vec<String> = Manifest::read(&out.join("manifest.jsonl"))
        .unwrap()
        .into_iter()
        .flat_map(|e| e.notes)
        .collect();
    assert!(notes.iter().any(|n| n.contains("uses")), "{notes:?}");
}

#[test]
fn a_missing_asset_folder_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let recipe = test_support::write_tiny_recipe(dir.path(), "shapenet");
    let o = generate(
        &recipe,
        &dir.path().join("data"),
        &["--textures", "/no/such/photos"],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.contains("texture folder /no/such/photos does not exist"),
        "{err}"
    );
}
