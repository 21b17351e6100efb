//! Re-rendering a spec: the meshes Blender builds are identical in every process, also those cut
//! by the exact boolean solver (which returns its vertices and faces in an order that changes from
//! run to run, and now are stored in canonical order); the rendered files stay within a stated
//! bound of each other (see README, "How exact is the disparity?").

use std::path::Path;

use stereogen::assets::AssetIndex;
use stereogen::plan::recipe::DEFAULT_PRESET;
use stereogen::plan::{Modifier, Recipe, SceneSpec, plan_scene};
use stereogen::render::RenderService;
use stereogen_e2e::{render, worker_config};

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
    let out = cfg
        .runtime
        .command(probe, &[scripts, spec_path.to_string_lossy().into_owned()])
        .output()
        .expect("run the mesh probe");
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "mesh probe failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
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

/// Largest disparity difference between two renders of one spec (px): measured up to 2.3e-5 px
/// in under 0.4% of the pixels over 19 default-preset specs once the boolean order was fixed
/// (subdivision surfaces still vary; see README).
const DISPARITY_BOUND_PX: f32 = 1e-4;

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
    spec.render.samples = 4;
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
        let read = |r: &stereogen_e2e::RenderedPair| {
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
