//! Re-rendering a spec: the meshes Blender builds are identical in every process, also those cut
//! by the exact boolean solver (which returns its vertices and faces in an order that changes from
//! run to run, and now are stored in canonical order); the rendered files stay within a stated
//! bound of each other (see README, "How exact is the disparity?").

use std::path::Path;

use stereogen::assets::AssetIndex;
use stereogen::plan::recipe::DEFAULT_PRESET;
use stereogen::plan::{Modifier, Recipe, SceneSpec, plan_scene};
use stereogen::render::RenderService;
use test_support::{render, run_ok, worker_config};

/// Builds a spec's scene inside Blender (no render) and prints one line per mesh object: its
/// name and a hash of its evaluated vertices and face corners, in Blender's order.
const MESH_PROBE: &str = r#"
import array, hashlib, json, sys
args = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
scripts, spec_path = args
sys.path.insert(0, scripts)
import bpy
bpy.ops.wm.read_factory_settings(use_empty=True)
import scene_builder
scene, _, _ = scene_builder.build(json.load(open(spec_path)), 0, "cpu")
dg = bpy.context.evaluated_depsgraph_get()
for ob in sorted(scene.objects, key=lambda o: o.name):
    if ob.type != "MESH" or ob.hide_render:
        continue
    ev = ob.evaluated_get(dg)
    me = ev.to_mesh()
    co = array.array("f", [0.0]) * (len(me.vertices) * 3)
    me.vertices.foreach_get("co", co)
    corners = array.array("i", [0]) * len(me.loops)
    me.loops.foreach_get("vertex_index", corners)
    print("MESH %s %s" % (ob.name, hashlib.sha256(co.tobytes() + corners.tobytes()).hexdigest()))
    ev.to_mesh_clear()
"#;

/// The default preset's sample 2 of seed 0 (960×540, reflective): six primitives cut by the
/// exact boolean solver, some then subdivided and displaced; the issue's reproduction.
fn boolean_heavy_spec() -> SceneSpec {
    let spec = plan_scene(
        &Recipe::preset(DEFAULT_PRESET).unwrap(),
        &AssetIndex::default(),
        0,
        2,
    );
    let cuts = spec
        .objects
        .iter()
        .filter(|o| {
            o.modifiers
                .iter()
                .any(|m| matches!(m, Modifier::BooleanCut { .. }))
        })
        .count();
    assert!(
        cuts >= 4,
        "the spec should exercise the boolean solver: {cuts} cut objects"
    );
    spec
}

fn mesh_hashes(spec_path: &Path, probe: &Path) -> Vec<String> {
    let cfg = worker_config();
    let scripts = cfg.script.parent().unwrap().to_string_lossy().into_owned();
    let out = run_ok(
        &mut cfg
            .runtime
            .command(probe, &[scripts, spec_path.to_string_lossy().into_owned()]),
    );
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    let lines: Vec<String> = text
        .lines()
        .filter(|l| l.starts_with("MESH "))
        .map(str::to_string)
        .collect();
    assert!(!lines.is_empty(), "the probe printed no mesh: {text}");
    lines
}

#[test]
fn boolean_cut_meshes_come_out_in_the_same_order_in_every_process() {
    let dir = tempfile::tempdir().unwrap();
    let spec_path = dir.path().join("spec.json");
    std::fs::write(&spec_path, boolean_heavy_spec().to_json()).unwrap();
    let probe = dir.path().join("mesh_probe.py");
    std::fs::write(&probe, MESH_PROBE).unwrap();
    // Without canonical order, four of the six cut objects differed between any two processes.
    let first = mesh_hashes(&spec_path, &probe);
    for _ in 0..2 {
        assert_eq!(
            mesh_hashes(&spec_path, &probe),
            first,
            "an evaluated mesh differs between two builds of one spec"
        );
    }
}

/// Largest disparity difference between two renders of one spec (px): measured up to 1.2e-4 px,
/// in 0.03% of the pixels, over 20 default-preset samples at 480×270 (subdivision surfaces vary
/// between processes; see README). Disparities grow with the image width, so the bound keeps a
/// margin for full-size samples; it is still 20× under the audit's 0.01 px.
const DISPARITY_BOUND_PX: f32 = 5e-4;

/// Compares two 8-bit images: (pixels differing, largest difference in levels).
fn image_difference(a: &stereo_io::RgbImage, b: &stereo_io::RgbImage) -> (usize, u8) {
    let diffs: Vec<u8> = a
        .data
        .chunks(3)
        .zip(b.data.chunks(3))
        .map(|(p, q)| p.iter().zip(q).map(|(x, y)| x.abs_diff(*y)).max().unwrap())
        .collect();
    (
        diffs.iter().filter(|d| **d > 0).count(),
        diffs.into_iter().max().unwrap_or(0),
    )
}

#[test]
fn re_rendering_a_boolean_heavy_spec_stays_within_the_stated_bound() {
    let mut spec = boolean_heavy_spec();
    // Smaller and fewer samples to keep CI fast; geometry and denoiser as in the preset; two
    // render threads, as `generate` uses on a 2-core machine.
    spec.rig.width = 240;
    spec.rig.height = 135;
    spec.render.recipe.samples = 4;
    let mut cfg = worker_config();
    cfg.threads = 2;
    let a = render(&mut RenderService::new(cfg.clone()), &spec);
    let b = render(&mut RenderService::new(cfg), &spec);
    assert_eq!(a.entry.sha256["scene"], b.entry.sha256["scene"]);
    for (x, y, view) in [(&a.left, &b.left, "left"), (&a.right, &b.right, "right")] {
        assert_eq!(
            x.valid, y.valid,
            "{view}: the valid pixels differ between two renders"
        );
        let worst = x
            .data
            .iter()
            .zip(&y.data)
            .map(|(p, q)| (p - q).abs())
            .fold(0f32, f32::max);
        println!("{view} disparity: largest difference between two renders {worst:e} px");
        assert!(
            worst <= DISPARITY_BOUND_PX,
            "{view}: disparity differs by {worst} px between two renders"
        );
    }
    for key in ["left", "right"] {
        let read = |r: &test_support::RenderedPair| {
            stereo_io::read_rgb(&r.layout.abs(if key == "left" {
                &r.entry.files.left
            } else {
                &r.entry.files.right
            }))
            .unwrap()
        };
        let (n, worst) = image_difference(&read(&a), &read(&b));
        println!("{key} image: {n} pixels differ, by up to {worst} levels");
        assert!(
            worst <= 4 && n * 100 <= (spec.rig.width * spec.rig.height) as usize,
            "{key} image: {n} pixels differ by up to {worst} levels"
        );
    }
}

/// The measurement behind the README's figures, as a user reproduces a dataset: `generate` the
/// default preset (content pack, 960×540 unless `STEREOGEN_RERENDER_SIZE=WxH` is given through a
/// recipe) for `STEREOGEN_RERENDER_COUNT` samples (20), then `render --spec` each sample's
/// `scene.json.gz` into a fresh folder, and compare all five files. Prints a table and asserts
/// the bound. Slow (a few minutes per sample pair at full size):
/// `cargo test --release --workspace --test integration rerender_exact -- --ignored --nocapture`.
#[test]
#[ignore = "measurement: minutes per sample; run explicitly"]
fn re_rendering_default_preset_samples_measured() {
    use stereogen::dataset::Manifest;
    let count: u64 = std::env::var("STEREOGEN_RERENDER_COUNT")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20);
    let dir = tempfile::tempdir().unwrap();
    let first = dir.path().join("first");
    // Not `generate_cmd`: a measurement at the default thread count, of the default recipe
    // unless STEREOGEN_RERENDER_SIZE asks for another size.
    let mut generate =
        test_support::stereogen_cmd(["generate", "--no-progress", "--seed", "0", "--count"]);
    generate.arg(count.to_string()).arg("--out").arg(&first);
    if let Ok(size) = std::env::var("STEREOGEN_RERENDER_SIZE") {
        let (w, h) = size.split_once('x').expect("STEREOGEN_RERENDER_SIZE=WxH");
        let mut recipe = Recipe::preset(DEFAULT_PRESET).unwrap();
        recipe.camera.width = w.parse().unwrap();
        recipe.camera.height = h.parse().unwrap();
        let path = dir.path().join("recipe.toml");
        std::fs::write(&path, toml::to_string(&recipe).unwrap()).unwrap();
        generate.arg("--recipe").arg(path);
    }
    let t0 = std::time::Instant::now();
    let o = generate.output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    println!(
        "generated {count} samples in {:.0} s",
        t0.elapsed().as_secs_f64()
    );
    let entries = Manifest::read(&first.join("manifest.jsonl")).unwrap();
    assert_eq!(entries.len() as u64, count);
    let (mut identical, mut worst_disp, mut worst_level) = (0, 0f32, 0u8);
    let (mut disp_px, mut image_px, mut pixels) = (0usize, 0usize, 0usize);
    println!(
        "index  category      files differing  disparity px (max diff)  image px (max levels)"
    );
    for e in &entries {
        let again = dir.path().join(format!("again-{}", e.index));
        let o = test_support::stereogen_cmd(["render"])
            .arg("--spec")
            .arg(first.join(&e.files.scene))
            .arg("--out")
            .arg(&again)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let b: stereogen::dataset::ManifestEntry =
            serde_json::from_slice(o.stdout.trim_ascii()).unwrap();
        let differing: Vec<&String> = e
            .sha256
            .iter()
            .filter(|(k, v)| b.sha256.get(*k) != Some(*v))
            .map(|(k, _)| k)
            .collect();
        identical += usize::from(differing.is_empty());
        let (mut dn, mut dmax, mut inn, mut imax) = (0, 0f32, 0, 0u8);
        for (x, y) in [
            (&e.files.disp_left, &b.files.disp_left),
            (&e.files.disp_right, &b.files.disp_right),
        ] {
            let (p, _) = stereo_io::read_disparity_exr(&first.join(x)).unwrap();
            let (q, _) = stereo_io::read_disparity_exr(&again.join(y)).unwrap();
            assert_eq!(p.valid, q.valid, "sample {}: valid masks differ", e.index);
            for (u, v) in p.data.iter().zip(&q.data) {
                let d = (u - v).abs();
                dn += usize::from(d > 0.0);
                dmax = dmax.max(d);
            }
        }
        for (x, y) in [
            (&e.files.left, &b.files.left),
            (&e.files.right, &b.files.right),
        ] {
            let p = stereo_io::read_rgb(&first.join(x)).unwrap();
            let q = stereo_io::read_rgb(&again.join(y)).unwrap();
            let (n, m) = image_difference(&p, &q);
            inn += n;
            imax = imax.max(m);
        }
        println!(
            "{:>5}  {:<12}  {:<15}  {:>6} ({:.1e})  {:>8} ({imax})",
            e.index,
            e.category,
            format!("{differing:?}"),
            dn,
            dmax,
            inn
        );
        (disp_px, image_px) = (disp_px + dn, image_px + inn);
        (worst_disp, worst_level) = (worst_disp.max(dmax), worst_level.max(imax));
        pixels += 2 * (e.width * e.height) as usize;
    }
    println!(
        "{identical} of {count} samples identical in all files; disparity: {disp_px} of {pixels} \
         pixels differ ({:.3}%), by at most {worst_disp:e} px; images: {image_px} pixels differ \
         ({:.3}%), by at most {worst_level} levels",
        100.0 * disp_px as f64 / pixels as f64,
        100.0 * image_px as f64 / pixels as f64
    );
    assert!(worst_disp <= DISPARITY_BOUND_PX, "{worst_disp}");
    assert!(
        worst_level <= 4 && image_px * 100 <= pixels,
        "{worst_level}"
    );
}
