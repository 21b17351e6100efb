//! One scene that holds every shape, modifier, light, texture pattern, base colour and material
//! class the SceneSpec can express, rendered by the real worker: the files decode, every pixel has
//! ground truth, every object shows at its planned disparity in both views, and the worker's
//! timings reach the manifest entry. The kind lists below come from exhaustive matches, so a new
//! variant does not compile until this scene contains it.

use std::collections::BTreeSet;
use std::path::Path;

use stereogen::plan::rig::View;
use stereogen::plan::spec::{Cutter, Leaf, Modifier, Strand};
use stereogen::plan::{
    BaseColor, LightSpec, MaterialClass, MaterialSpec, ObjectSpec, Pattern, SceneSpec, Shape,
};
use stereogen::render::RenderService;
use test_support::scenes::{base, object, plane};
use test_support::{render, worker_config};

fn shape_kind(s: &Shape) -> &'static str {
    match s {
        Shape::Plane => "plane",
        Shape::Cube => "cube",
        Shape::UvSphere { .. } => "uv_sphere",
        Shape::IcoSphere { .. } => "ico_sphere",
        Shape::Cylinder { .. } => "cylinder",
        Shape::Cone { .. } => "cone",
        Shape::Torus { .. } => "torus",
        Shape::Grid { .. } => "grid",
        Shape::Monkey => "monkey",
        Shape::Mesh { .. } => "mesh",
        Shape::MeshFile { .. } => "mesh_file",
        Shape::Skeleton { leaves, .. } if leaves.is_empty() => "skeleton",
        Shape::Skeleton { .. } => "skeleton_with_leaves",
    }
}
const SHAPES: [&str; 13] = [
    "plane",
    "cube",
    "uv_sphere",
    "ico_sphere",
    "cylinder",
    "cone",
    "torus",
    "grid",
    "monkey",
    "mesh",
    "mesh_file",
    "skeleton",
    "skeleton_with_leaves",
];

fn modifier_kind(m: &Modifier) -> &'static str {
    match m {
        Modifier::Wireframe { .. } => "wireframe",
        Modifier::Subdivide { .. } => "subdivide",
        Modifier::Displace { .. } => "displace",
        Modifier::BooleanCut {
            cutter: Cutter::Cube,
            ..
        } => "boolean_cube",
        Modifier::BooleanCut {
            cutter: Cutter::Sphere,
            ..
        } => "boolean_sphere",
        Modifier::RestOnFloor { .. } => "rest_on_floor",
    }
}
const MODIFIERS: [&str; 6] = [
    "wireframe",
    "subdivide",
    "displace",
    "boolean_cube",
    "boolean_sphere",
    "rest_on_floor",
];

fn light_kind(l: &LightSpec) -> &'static str {
    match l {
        LightSpec::Point { .. } => "point",
        LightSpec::Spot { .. } => "spot",
        LightSpec::Area { .. } => "area",
        LightSpec::Sun { .. } => "sun",
    }
}
const LIGHTS: [&str; 4] = ["point", "spot", "area", "sun"];

fn base_kind(b: &BaseColor) -> String {
    match b {
        BaseColor::Flat { .. } => "flat".into(),
        BaseColor::Image { .. } => "image".into(),
        BaseColor::Procedural { pattern, .. } => format!("procedural_{}", pattern_name(*pattern)),
    }
}

fn pattern_name(p: Pattern) -> &'static str {
    match p {
        Pattern::Noise => "noise",
        Pattern::Voronoi => "voronoi",
        Pattern::Checker => "checker",
        Pattern::Wave => "wave",
        Pattern::Brick => "brick",
        Pattern::Magic => "magic",
        Pattern::Gradient => "gradient",
    }
}

fn class_name(c: MaterialClass) -> &'static str {
    match c {
        MaterialClass::Textured => "textured",
        MaterialClass::Textureless => "textureless",
        MaterialClass::Glossy => "glossy",
        MaterialClass::Metallic => "metallic",
        MaterialClass::Glass => "glass",
    }
}
const CLASSES: [&str; 5] = ["textured", "textureless", "glossy", "metallic", "glass"];

fn material(class: MaterialClass, base: BaseColor) -> MaterialSpec {
    let (metallic, transmission) = match class {
        MaterialClass::Metallic => (1.0, 0.0),
        MaterialClass::Glass => (0.0, 1.0),
        _ => (0.0, 0.0),
    };
    MaterialSpec {
        class,
        base,
        roughness: if class == MaterialClass::Glossy {
            0.05
        } else {
            0.5
        },
        metallic,
        transmission,
        ior: 1.45,
        pass_index: class.pass_index(),
    }
}

fn procedural(pattern: Pattern) -> BaseColor {
    BaseColor::Procedural {
        pattern,
        scale: 6.0,
        color_a: [0.9, 0.7, 0.2],
        color_b: [0.1, 0.3, 0.7],
        detail: 3.0,
    }
}

fn flat(color: [f64; 3]) -> BaseColor {
    BaseColor::Flat { color }
}

/// A small tree: a trunk, one branch and three leaves (object space, inside the unit sphere).
fn small_tree() -> Shape {
    let trunk = Strand {
        points: vec![[0.0, 0.0, -0.9], [0.0, 0.0, 0.0], [0.05, 0.0, 0.6]],
        radii: vec![0.12, 0.09, 0.05],
    };
    let branch = Strand {
        points: vec![[0.0, 0.0, 0.0], [0.4, 0.1, 0.3], [0.6, 0.2, 0.5]],
        radii: vec![0.06, 0.04, 0.02],
    };
    let leaf = |c: [f64; 3]| Leaf {
        center: c,
        u: [0.12, 0.0, 0.0],
        v: [0.0, 0.25, 0.0],
    };
    Shape::Skeleton {
        strands: vec![trunk, branch],
        strand_levels: vec![0, 1],
        sides: 8,
        leaves: vec![
            leaf([0.6, 0.2, 0.55]),
            leaf([-0.3, 0.0, 0.4]),
            leaf([0.1, 0.0, 0.75]),
        ],
        leaf_material: Some(Box::new(MaterialSpec::flat([0.1, 0.5, 0.1], 0.6))),
    }
}

/// A 4×4 net of strands in the XY plane.
fn small_net() -> Shape {
    let mut strands = Vec::new();
    for i in 0..4 {
        let c = -0.6 + 0.4 * f64::from(i);
        strands.push(Strand {
            points: vec![[-0.7, c, 0.0], [0.7, c, 0.0]],
            radii: vec![0.05; 2],
        });
        strands.push(Strand {
            points: vec![[c, -0.7, 0.0], [c, 0.7, 0.0]],
            radii: vec![0.05; 2],
        });
    }
    Shape::net(strands)
}

fn tetrahedron() -> Shape {
    Shape::Mesh {
        vertices: vec![
            [0.8, 0.8, 0.8],
            [-0.8, -0.8, 0.8],
            [-0.8, 0.8, -0.8],
            [0.8, -0.8, -0.8],
        ],
        triangles: vec![[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]],
    }
}

const CUBE_OBJ: &str = "v -1 -1 -1\nv 1 -1 -1\nv 1 1 -1\nv -1 1 -1\nv -1 -1 1\nv 1 -1 1\nv 1 1 1\nv -1 1 1\n\
f 1 2 3 4\nf 5 8 7 6\nf 1 5 6 2\nf 2 6 7 3\nf 3 7 8 4\nf 5 1 4 8\n";

/// The objects, one per grid cell at depth 3 m: (shape, modifiers, material).
fn contents(dir: &Path) -> Vec<(Shape, Vec<Modifier>, MaterialSpec)> {
    let photo = dir.join("photo.png");
    image::RgbImage::from_fn(32, 32, |x, y| {
        image::Rgb([(x * 8) as u8, (y * 8) as u8, ((x ^ y) * 8) as u8])
    })
    .save(&photo)
    .unwrap();
    let obj = dir.join("cube.obj");
    std::fs::write(&obj, CUBE_OBJ).unwrap();
    let image = BaseColor::Image {
        path: photo,
        scale: 2.0,
        rotation: 0.3,
        fallback: [1.0, 0.0, 1.0],
        texture_px: None,
        stretch: None,
    };
    let cut = |cutter| Modifier::BooleanCut {
        cutter,
        location: [0.5, 0.5, 0.5],
        rotation: [0.2, 0.3, 0.1],
        scale: [0.5; 3],
    };
    let displace = Modifier::Displace {
        strength: 0.1,
        noise_scale: 0.5,
        offset: [1.0, 2.0, 3.0],
    };
    use MaterialClass::*;
    vec![
        (
            Shape::Plane,
            vec![],
            material(Textured, procedural(Pattern::Noise)),
        ),
        (
            Shape::Cube,
            vec![Modifier::Subdivide { levels: 1 }],
            material(Textured, procedural(Pattern::Voronoi)),
        ),
        (
            Shape::UvSphere {
                segments: 16,
                rings: 8,
            },
            vec![],
            material(Textured, procedural(Pattern::Checker)),
        ),
        (
            Shape::IcoSphere { subdivisions: 2 },
            vec![Modifier::Subdivide { levels: 2 }, displace],
            material(Textured, procedural(Pattern::Wave)),
        ),
        (
            Shape::Cylinder { vertices: 16 },
            vec![cut(Cutter::Cube)],
            material(Textured, procedural(Pattern::Brick)),
        ),
        (
            Shape::Cone {
                vertices: 16,
                top_ratio: 0.3,
            },
            vec![cut(Cutter::Sphere)],
            material(Textured, procedural(Pattern::Magic)),
        ),
        (
            Shape::Torus {
                major_segments: 24,
                minor_segments: 8,
                minor_ratio: 0.35,
            },
            vec![],
            material(Textured, procedural(Pattern::Gradient)),
        ),
        (
            Shape::Grid {
                x_segments: 6,
                y_segments: 6,
            },
            vec![Modifier::Wireframe { thickness: 0.08 }],
            material(Textureless, flat([0.8, 0.8, 0.1])),
        ),
        (
            Shape::Monkey,
            // Its cell's centre is at y = 0: lowered a little, so its lowest point is at −0.25.
            vec![Modifier::RestOnFloor { y: -0.25 }],
            material(Glossy, flat([0.7, 0.2, 0.2])),
        ),
        (
            tetrahedron(),
            vec![],
            material(Metallic, flat([0.9, 0.8, 0.6])),
        ),
        (
            Shape::MeshFile {
                candidates: vec![obj],
                max_triangles: 1000,
            },
            vec![],
            material(Textured, image),
        ),
        (
            small_net(),
            vec![],
            material(Textureless, flat([0.2, 0.9, 0.9])),
        ),
        (
            small_tree(),
            vec![],
            material(Textureless, flat([0.4, 0.25, 0.1])),
        ),
        (
            Shape::UvSphere {
                segments: 24,
                rings: 12,
            },
            vec![],
            material(Glass, flat([0.9, 0.95, 1.0])),
        ),
    ]
}

const OBJECT_DEPTH: f64 = 3.0;
const WALL_DEPTH: f64 = 6.0;

fn every_variant_scene(dir: &Path) -> SceneSpec {
    let mut objects = vec![plane("wall", [0.0, 0.0, -WALL_DEPTH], [0.0; 3], 40.0)];
    for (i, (shape, modifiers, material)) in contents(dir).into_iter().enumerate() {
        let (col, row) = ((i % 5) as f64, (i / 5) as f64);
        let location = [-1.1 + 0.55 * col, 0.55 - 0.55 * row, -OBJECT_DEPTH];
        // Flat shapes face the rig; the others turn a little to show more than one side.
        let rotation = if matches!(
            shape,
            Shape::Plane | Shape::Grid { .. } | Shape::Skeleton { .. }
        ) {
            [0.2, 0.1, 0.0]
        } else {
            [0.5, 0.7, 0.1]
        };
        let mut o = object(
            &format!("v{i:02}_{}", shape_kind(&shape)),
            shape,
            location,
            rotation,
            [0.21; 3],
            material,
        );
        o.modifiers = modifiers;
        objects.push(o);
    }
    let mut spec = base("every_variant", objects);
    spec.lights = vec![
        LightSpec::Point {
            location: [0.3, 0.5, -1.0],
            color: [1.0, 0.9, 0.8],
            power_w: 60.0,
            radius: 0.1,
        },
        LightSpec::Spot {
            location: [-0.8, 0.8, 0.0],
            rotation: [0.3, -0.2, 0.0],
            color: [0.9, 0.9, 1.0],
            power_w: 200.0,
            radius: 0.05,
            spot_size: 1.2,
            blend: 0.2,
        },
        LightSpec::Area {
            location: [0.0, 1.0, -1.5],
            rotation: [-0.8, 0.0, 0.0],
            color: [1.0, 1.0, 1.0],
            power_w: 80.0,
            size: 0.5,
        },
        LightSpec::Sun {
            rotation: [0.4, 0.3, 0.0],
            color: [1.0, 0.95, 0.9],
            strength: 1.5,
        },
    ];
    spec
}

fn assert_covers(what: &str, seen: BTreeSet<String>, all: &[&str]) {
    let all: BTreeSet<String> = all.iter().map(|s| s.to_string()).collect();
    assert_eq!(seen, all, "the scene must contain every {what}");
}

fn assert_scene_has_every_variant(spec: &SceneSpec) {
    let content: Vec<&ObjectSpec> = spec.objects.iter().skip(1).collect();
    assert_covers(
        "shape",
        content
            .iter()
            .map(|o| shape_kind(&o.shape).to_string())
            .collect(),
        &SHAPES,
    );
    assert_covers(
        "modifier",
        content
            .iter()
            .flat_map(|o| o.modifiers.iter().map(|m| modifier_kind(m).to_string()))
            .collect(),
        &MODIFIERS,
    );
    assert_covers(
        "light",
        spec.lights
            .iter()
            .map(|l| light_kind(l).to_string())
            .collect(),
        &LIGHTS,
    );
    assert_covers(
        "material class",
        content
            .iter()
            .map(|o| class_name(o.material.class).to_string())
            .collect(),
        &CLASSES,
    );
    let mut bases: Vec<String> = vec!["flat".into(), "image".into()];
    bases.extend(
        Pattern::ALL
            .iter()
            .map(|p| format!("procedural_{}", pattern_name(*p))),
    );
    let bases: Vec<&str> = bases.iter().map(String::as_str).collect();
    assert_covers(
        "base colour and texture pattern",
        content
            .iter()
            .map(|o| base_kind(&o.material.base))
            .collect(),
        &bases,
    );
}

/// Pixels within `radius` px of (u, v) nearer than the wall (disparity above it by `margin`).
fn pixels_in_front(
    map: &stereo_io::DisparityMap,
    (u, v): (f64, f64),
    radius: f64,
    wall: f32,
    margin: f32,
) -> usize {
    let mut n = 0;
    for y in 0..map.height {
        for x in 0..map.width {
            let (dx, dy) = (x as f64 + 0.5 - u, y as f64 + 0.5 - v);
            if dx * dx + dy * dy <= radius * radius && map.get(x, y) > wall + margin {
                n += 1;
            }
        }
    }
    n
}

#[test]
fn a_scene_with_every_variant_renders_with_ground_truth() {
    let dir = tempfile::tempdir().unwrap();
    let spec = every_variant_scene(dir.path());
    assert_scene_has_every_variant(&spec);
    let pair = render(&mut RenderService::new(worker_config()), &spec);

    // Both colour images decode at the rig's size and are not blank.
    for rel in [&pair.entry.files.left, &pair.entry.files.right] {
        let img = stereo_io::read_rgb(&pair.layout.abs(rel)).expect("the colour image decodes");
        assert_eq!(
            (img.width, img.height),
            (spec.rig.width as usize, spec.rig.height as usize)
        );
        let distinct: BTreeSet<&[u8]> = img.data.chunks(3).collect();
        assert!(
            distinct.len() > 200,
            "{}: only {} distinct colours",
            rel.display(),
            distinct.len()
        );
    }
    // The wall fills the view: every pixel of both views has a disparity.
    for (view, map) in [("left", &pair.left), ("right", &pair.right)] {
        assert!(
            map.valid.iter().all(|v| *v),
            "{view}: pixels without ground truth"
        );
    }
    // Every object shows in both views where the rig projects it, nearer than the wall.
    let rig = &spec.rig;
    let wall = rig.disparity_at_depth(WALL_DEPTH) as f32;
    let gap = (rig.disparity_at_depth(OBJECT_DEPTH) as f32 - wall) / 2.0;
    let radius_px = 0.21 * rig.f_px() / OBJECT_DEPTH;
    for o in spec.objects.iter().skip(1) {
        for (view, map) in [(View::Left, &pair.left), (View::Right, &pair.right)] {
            let at = rig.project(view, o.location).unwrap();
            let n = pixels_in_front(map, at, radius_px, wall, gap);
            assert!(
                n >= 3,
                "{} does not show in the {view:?} view ({n} pixels in front of the wall)",
                o.name
            );
        }
    }
    let notes = pair.entry.notes.join("\n");
    assert!(
        notes.contains("uses") && !notes.contains("dropped"),
        "{notes}"
    );
    // Where the worker's time went reaches the manifest entry.
    let timings = &pair.entry.render_timings;
    for key in [
        "build_s",
        "colour_left_s",
        "depth_left_s",
        "colour_right_s",
        "depth_right_s",
        "save_s",
    ] {
        assert!(
            timings.get(key).is_some_and(|s| *s > 0.0),
            "timing {key} missing: {timings:?}"
        );
    }
    println!(
        "every-variant scene: {} objects, worker timings {timings:?}",
        spec.objects.len() - 1
    );
}
