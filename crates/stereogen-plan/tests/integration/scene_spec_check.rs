//! The check of a scene spec before it is rendered: specs the planner writes pass, and each
//! impossible or hostile value (a file name climbing out of the output, geometry without bound)
//! is refused with its key and value named.

use stereogen_plan::spec::{Modifier, Shape};
use stereogen_plan::{
    AssetIndex, HdriSpec, Recipe, SceneSpec, SkySpec, check_scene_spec, plan_scene,
};

fn hdri(name: &str, strength: f64) -> HdriSpec {
    HdriSpec {
        name: name.into(),
        rotation: 0.3,
        strength,
    }
}

/// A key, how to spoil its value, and what the message must say.
type Case = (&'static str, fn(&mut SceneSpec), &'static str);

#[test]
fn planned_specs_pass_and_impossible_values_are_named() {
    for (name, _) in stereogen_plan::recipe::PRESETS {
        let spec = plan_scene(&Recipe::preset(name).unwrap(), &AssetIndex::default(), 5, 2);
        check_scene_spec(&spec).unwrap_or_else(|e| panic!("{name}: {e}"));
    }
    let good = plan_scene(&Recipe::builtin_default(), &AssetIndex::default(), 1, 0);
    let cases: [Case; 16] = [
        (
            "id",
            |s| s.id = "../../../tmp/x".into(),
            "got \"../../../tmp/x\"",
        ),
        ("category", |s| s.category = "/etc".into(), "need letters"),
        (
            "objects[0].shape",
            |s| {
                s.objects[0].shape = Shape::UvSphere {
                    segments: u32::MAX,
                    rings: 16,
                }
            },
            "need segments in 1..=1024, got 4294967295",
        ),
        (
            "objects[0].shape",
            |s| s.objects[0].modifiers = vec![Modifier::Subdivide { levels: 12 }],
            "need subdivision levels in 0..=4, got 12",
        ),
        (
            "objects[0].shape",
            |s| {
                s.objects[0].shape = Shape::Mesh {
                    vertices: vec![[0.0; 3]; 3],
                    triangles: vec![[0, 1, 7]],
                }
            },
            "names a vertex the mesh lacks",
        ),
        (
            "objects[0].shape",
            |s| {
                s.objects[0].shape = Shape::Grid {
                    x_segments: 1024,
                    y_segments: 1024,
                };
                s.objects[0].modifiers = vec![Modifier::Subdivide { levels: 4 }];
            },
            "need at most 1.6e7 triangles an object",
        ),
        (
            "objects",
            |s| s.objects = vec![s.objects[0].clone(); 5000],
            "need 0..=4096, got 5000",
        ),
        ("rig.width", |s| s.rig.width = 0, "need 16..=16384, got 0"),
        // The recipe's image-size limit, the same for specs.
        (
            "rig.height",
            |s| s.rig.height = 15,
            "need 16..=16384, got 15",
        ),
        (
            "rig.baseline_m",
            |s| s.rig.baseline_m = 1e308,
            "need 0 < value <= 1000, got 1000000",
        ),
        (
            "render.clip_start",
            |s| s.render.clip_start = f64::NAN,
            "got NaN",
        ),
        (
            "render.clip_end",
            |s| s.render.clip_end = s.render.clip_start / 2.0,
            "must lie beyond render.clip_start",
        ),
        (
            "render.samples",
            |s| s.render.recipe.samples = 0,
            "need 1..=65536, got 0",
        ),
        // The HDR map's name picks a file in Blender's folder: never a path.
        (
            "world.hdri.name",
            |s| s.world.hdri = Some(hdri("../../../../etc/passwd", 1.0)),
            "got \"../../../../etc/passwd\"",
        ),
        (
            "world.hdri.strength",
            |s| s.world.hdri = Some(hdri("forest", -1.0)),
            "got -1",
        ),
        (
            "world.hdri",
            |s| {
                s.world.hdri = Some(hdri("forest", 1.0));
                s.world.sky = Some(SkySpec {
                    sun_elevation: 0.5,
                    sun_rotation: 0.0,
                    turbidity: 3.0,
                    ground_albedo: 0.3,
                });
            },
            "not both",
        ),
    ];
    for (key, spoil, allowed) in cases {
        let mut spec = good.clone();
        spoil(&mut spec);
        let e = check_scene_spec(&spec).expect_err(key);
        assert_eq!(e.key, key, "{e}");
        let message = e.to_string();
        assert!(
            message.contains(&format!("key `{key}` is invalid")) && message.contains(allowed),
            "{message}"
        );
    }
}
