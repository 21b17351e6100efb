//! Hand-made scenes with known geometry for the exactness tests.

use stereogen::plan::recipe::RenderRecipe;
use stereogen::plan::spec::{PixelFilter, SPEC_FORMAT_VERSION};
use stereogen::plan::{
    BaseColor, LightSpec, MaterialClass, MaterialSpec, ObjectRole, ObjectSpec, Pattern,
    RenderSettings, SceneSpec, Shape, StereoRig, WorldSpec,
};

pub fn rig() -> StereoRig {
    StereoRig {
        width: 160,
        height: 120,
        focal_mm: 35.0,
        sensor_width_mm: 36.0,
        baseline_m: 0.1,
    }
}

fn textured() -> MaterialSpec {
    MaterialSpec {
        class: MaterialClass::Textured,
        base: BaseColor::Procedural {
            pattern: Pattern::Checker,
            scale: 8.0,
            color_a: [0.9, 0.8, 0.2],
            color_b: [0.1, 0.2, 0.6],
            detail: 2.0,
        },
        roughness: 0.5,
        metallic: 0.0,
        transmission: 0.0,
        ior: 1.45,
        pass_index: 0,
    }
}

/// A hand-made object (not placed by the disparity law).
pub fn object(
    name: &str,
    shape: Shape,
    location: [f64; 3],
    rotation: [f64; 3],
    scale: [f64; 3],
    material: MaterialSpec,
) -> ObjectSpec {
    ObjectSpec {
        name: name.into(),
        role: ObjectRole::Content,
        source: "test".into(),
        shape,
        modifiers: Vec::new(),
        location,
        rotation,
        scale,
        material,
        target_disparity: None,
    }
}

pub fn base(id: &str, objects: Vec<ObjectSpec>) -> SceneSpec {
    SceneSpec {
        format_version: SPEC_FORMAT_VERSION,
        id: id.into(),
        category: "analytic".into(),
        seed: 0,
        index: 0,
        rig: rig(),
        render: RenderSettings {
            recipe: RenderRecipe {
                samples: 2,
                denoise: false,
                max_bounces: 2,
                pixel_filter: PixelFilter::BlackmanHarris,
                filter_width_px: 1.5,
                adaptive_threshold: None,
                adaptive_min_samples: 0,
                denoise_prefilter: Default::default(),
                denoise_passes: Default::default(),
                denoise_quality: Default::default(),
                outputs: Vec::new(),
                light_tree: true,
            },
            cycles_seed: 1,
            clip_start: 0.01,
            clip_end: 100.0,
            cycles_seed_right: None,
        },
        world: WorldSpec {
            color: [0.8, 0.8, 0.8],
            strength: 0.5,
            sky: None,
            hdri: None,
        },
        objects,
        lights: vec![LightSpec::Point {
            location: [0.3, 0.5, 0.5],
            color: [1.0, 0.9, 0.8],
            power_w: 200.0,
            radius: 0.1,
        }],
    }
}

pub fn plane(name: &str, location: [f64; 3], rotation: [f64; 3], half: f64) -> ObjectSpec {
    object(
        name,
        Shape::Plane,
        location,
        rotation,
        [half, half, 1.0],
        textured(),
    )
}

/// A plane facing the rig at planar depth `z`, much larger than the view.
pub fn fronto_parallel(z: f64) -> SceneSpec {
    base(
        "fronto",
        vec![plane("wall", [0.0, 0.0, -z], [0.0; 3], 10.0 * z)],
    )
}

/// A plane tilted about X and Y, filling the view, centred at depth 2.5.
pub fn tilted_plane() -> SceneSpec {
    base(
        "tilted",
        vec![plane(
            "tilted",
            [0.05, -0.02, -2.5],
            [0.35, -0.5, 0.2],
            20.0,
        )],
    )
}

/// A finely triangulated UV sphere (explicit triangles, so the ray caster sees the same surface).
pub fn sphere_mesh(segments: u32, rings: u32) -> Shape {
    let mut vertices = vec![[0.0, 0.0, 1.0]];
    for r in 1..rings {
        let theta = std::f64::consts::PI * f64::from(r) / f64::from(rings);
        for s in 0..segments {
            let phi = 2.0 * std::f64::consts::PI * f64::from(s) / f64::from(segments);
            vertices.push([
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                theta.cos(),
            ]);
        }
    }
    vertices.push([0.0, 0.0, -1.0]);
    let south = (vertices.len() - 1) as u32;
    let ring = |r: u32, s: u32| 1 + (r - 1) * segments + (s % segments);
    let mut triangles = Vec::new();
    for s in 0..segments {
        triangles.push([0, ring(1, s), ring(1, s + 1)]);
        triangles.push([south, ring(rings - 1, s + 1), ring(rings - 1, s)]);
    }
    for r in 1..rings - 1 {
        for s in 0..segments {
            let (a, b, c, d) = (
                ring(r, s),
                ring(r, s + 1),
                ring(r + 1, s),
                ring(r + 1, s + 1),
            );
            triangles.push([a, c, d]);
            triangles.push([a, d, b]);
        }
    }
    Shape::Mesh {
        vertices,
        triangles,
    }
}

/// A sphere of radius 0.35 at depth 2 in front of a wall at depth 4.
pub fn sphere_before_wall() -> SceneSpec {
    let sphere = object(
        "sphere",
        sphere_mesh(96, 48),
        [0.05, 0.03, -2.0],
        [0.3, 0.2, 0.1],
        [0.35; 3],
        MaterialSpec::flat([0.7, 0.3, 0.3], 0.4),
    );
    base(
        "sphere",
        vec![plane("wall", [0.0, 0.0, -4.0], [0.0; 3], 40.0), sphere],
    )
}

/// The same sphere with nothing behind it: most rays escape to the world background.
pub fn sphere_alone() -> SceneSpec {
    let mut s = sphere_before_wall();
    s.id = "sphere_alone".into();
    s.objects.remove(0);
    s
}
