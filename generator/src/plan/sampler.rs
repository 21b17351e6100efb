//! Turns (recipe, seed, index) into a `SceneSpec`.
//!
//! Placement follows the paper's disparity law: each object first gets a target disparity, its
//! depth follows from the rig (Z = f·B/d), its image position is drawn inside the part of the
//! frustum both cameras see at that depth, and its world size grows with Z so its image size
//! stays in the recipe's range and near objects do not wall off the view.

use std::f64::consts::PI;

use rand::Rng;
use rand::seq::IndexedRandom;
use rand_distr::{Distribution, Uniform};

use super::recipe::{PrimitiveKind, Range, Recipe};
use super::rig::StereoRig;
use super::rng::SeedTree;
use super::spec::{
    LightSpec, MaterialSpec, ObjectSpec, Pattern, RenderSettings, SceneSpec, Shape, WorldSpec, SPEC_FORMAT_VERSION,
};

/// Fraction of the image kept free at each border when placing object centres.
const PLACEMENT_MARGIN: f64 = 0.05;

fn uniform<R: Rng>(rng: &mut R, r: Range) -> f64 {
    if r.min == r.max { r.min } else { Uniform::new_inclusive(r.min, r.max).expect("validated range").sample(rng) }
}

fn log_uniform<R: Rng>(rng: &mut R, r: Range) -> f64 {
    uniform(rng, Range { min: r.min.ln(), max: r.max.ln() }).exp()
}

fn count<R: Rng>(rng: &mut R, min: u32, max: u32) -> u32 {
    rng.random_range(min..=max)
}

fn random_color<R: Rng>(rng: &mut R) -> [f64; 3] {
    [rng.random::<f64>(), rng.random::<f64>(), rng.random::<f64>()]
}

/// The stable file stem of sample `index`.
pub fn sample_id(index: u64) -> String {
    format!("{index:07}")
}

/// Plans sample `index` of a dataset made from `recipe` with `seed`.
pub fn plan_scene(recipe: &Recipe, seed: u64, index: u64) -> SceneSpec {
    let root = SeedTree::for_sample(seed, index);
    let mut rig_rng = root.child("rig").rng();
    let cam = &recipe.camera;
    let rig = StereoRig {
        width: cam.width,
        height: cam.height,
        focal_mm: uniform(&mut rig_rng, cam.focal_mm),
        sensor_width_mm: cam.sensor_width_mm,
        baseline_m: uniform(&mut rig_rng, cam.baseline_m),
    };

    let background_depth = rig.depth_for_disparity(recipe.background.disparity_px);
    let nearest_depth = rig.depth_for_disparity(recipe.objects.disparity_px.max);
    let render = RenderSettings {
        samples: recipe.render.samples,
        denoise: recipe.render.denoise,
        cycles_seed: root.child("cycles").small_seed(),
        max_bounces: recipe.render.max_bounces,
        pixel_filter: recipe.render.pixel_filter,
        filter_width_px: recipe.render.filter_width_px,
        clip_start: (nearest_depth * 0.01).max(1e-4),
        clip_end: background_depth * 2.0,
    };

    let mut objects = vec![background_wall(&rig, background_depth, root.child("background"))];
    let mut count_rng = root.child("object_count").rng();
    let n_objects = count(&mut count_rng, recipe.objects.count.min, recipe.objects.count.max);
    for i in 0..n_objects {
        objects.push(place_object(recipe, &rig, root.child("objects").nth(u64::from(i)), i));
    }

    let mut light_rng = root.child("lights").rng();
    let n_lights = count(&mut light_rng, recipe.lights.count.min, recipe.lights.count.max);
    let lights = (0..n_lights)
        .map(|i| point_light(recipe, &rig, nearest_depth, background_depth, root.child("lights").nth(u64::from(i))))
        .collect();
    let mut world_rng = root.child("world").rng();
    let grey = world_rng.random_range(0.6..1.0);
    let world = WorldSpec {
        color: [grey, grey * world_rng.random_range(0.9..1.0), grey * world_rng.random_range(0.85..1.0)],
        strength: uniform(&mut world_rng, recipe.lights.world_strength),
    };

    SceneSpec {
        format_version: SPEC_FORMAT_VERSION,
        id: sample_id(index),
        category: recipe.name.clone(),
        seed,
        index,
        rig,
        render,
        world,
        objects,
        lights,
    }
}

/// A textured wall at the far end, large enough to fill both cameras' views.
fn background_wall(rig: &StereoRig, depth: f64, node: SeedTree) -> ObjectSpec {
    let f = rig.f_px();
    let half_w = (f64::from(rig.width) / 2.0 / f * depth + rig.baseline_m / 2.0) * 1.15;
    let half_h = f64::from(rig.height) / 2.0 / f * depth * 1.15;
    let mut rng = node.rng();
    let material = procedural_material(&mut rng, 4.0, 40.0);
    ObjectSpec {
        name: "background".into(),
        shape: Shape::Plane,
        location: [0.0, 0.0, -depth],
        rotation: [0.0, 0.0, 0.0],
        scale: [half_w, half_h, 1.0],
        material,
        target_disparity: None,
    }
}

fn procedural_material<R: Rng>(rng: &mut R, min_scale: f64, max_scale: f64) -> MaterialSpec {
    MaterialSpec::Procedural {
        pattern: *Pattern::ALL.choose(rng).expect("non-empty"),
        scale: log_uniform(rng, Range { min: min_scale, max: max_scale }),
        color_a: random_color(rng),
        color_b: random_color(rng),
        roughness: rng.random_range(0.1..0.9),
        detail: rng.random_range(0.0..8.0),
    }
}

fn place_object(recipe: &Recipe, rig: &StereoRig, node: SeedTree, i: u32) -> ObjectSpec {
    let o = &recipe.objects;
    let mut rng = node.child("placement").rng();
    let d = uniform(&mut rng, o.disparity_px);
    let z = rig.depth_for_disparity(d);
    let (w, h) = (f64::from(rig.width), f64::from(rig.height));
    // The centre must project into both images: u_left in [d, W] keeps u_right = u_left - d >= 0.
    let (mu, mv) = (PLACEMENT_MARGIN * w, PLACEMENT_MARGIN * h);
    let u_lo = (mu + d).min(w - mu);
    let u = rng.random_range(u_lo..=(w - mu));
    let v = rng.random_range(mv..=(h - mv));
    let location = rig.unproject_left(u, v, z);
    // Diameter `angular_size * W` pixels at depth z: the world radius grows linearly with z.
    let angular = uniform(&mut rng, o.angular_size);
    let radius = angular * w / 2.0 * z / rig.f_px();
    let proportions: [f64; 3] = std::array::from_fn(|_| rng.random_range(0.7..1.3));
    let rotation: [f64; 3] = std::array::from_fn(|_| rng.random_range(0.0..2.0 * PI));

    let mut shape_rng = node.child("shape").rng();
    let shape = match *o.shapes.choose(&mut shape_rng).expect("validated non-empty") {
        PrimitiveKind::Cube => Shape::Cube,
        PrimitiveKind::UvSphere => Shape::UvSphere { segments: 32, rings: 16 },
        PrimitiveKind::IcoSphere => Shape::IcoSphere { subdivisions: shape_rng.random_range(1..=3) },
        PrimitiveKind::Cylinder => Shape::Cylinder { vertices: 32 },
        PrimitiveKind::Torus => {
            Shape::Torus { major_segments: 48, minor_segments: 16, minor_ratio: shape_rng.random_range(0.15..0.5) }
        }
    };

    let mut mat_rng = node.child("material").rng();
    let material = if mat_rng.random_bool(o.textured_fraction) {
        procedural_material(&mut mat_rng, 1.0, 20.0)
    } else {
        MaterialSpec::Flat { color: random_color(&mut mat_rng), roughness: mat_rng.random_range(0.1..0.9) }
    };

    ObjectSpec {
        name: format!("object_{i:03}"),
        shape,
        location,
        rotation,
        scale: proportions.map(|p| p * radius),
        material,
        target_disparity: Some(d),
    }
}

fn point_light(recipe: &Recipe, rig: &StereoRig, near: f64, far: f64, node: SeedTree) -> LightSpec {
    let mut rng = node.rng();
    let z = rng.random_range((near * 0.5)..(far * 0.9));
    let u = rng.random_range(0.0..f64::from(rig.width));
    let v = rng.random_range(0.0..f64::from(rig.height));
    // Power scales with depth squared so a light deep in a large scene still reaches it.
    let power_w = log_uniform(&mut rng, recipe.lights.power_w) * z * z;
    let hue: [f64; 3] = std::array::from_fn(|_| rng.random_range(0.3..1.0));
    LightSpec::Point { location: rig.unproject_left(u, v, z), color: hue, power_w, radius: 0.05 * z }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::rig::View;

    #[test]
    fn planning_is_a_pure_function_of_seed_and_index() {
        let r = Recipe::builtin_default();
        assert_eq!(plan_scene(&r, 7, 11).to_json(), plan_scene(&r, 7, 11).to_json());
        assert_ne!(plan_scene(&r, 7, 11).to_json(), plan_scene(&r, 7, 12).to_json());
        assert_ne!(plan_scene(&r, 7, 11).to_json(), plan_scene(&r, 8, 11).to_json());
    }

    #[test]
    fn objects_hit_their_disparity_inside_both_views_and_scale_with_depth() {
        let r = Recipe::builtin_default();
        for index in 0..300 {
            let spec = plan_scene(&r, 1, index);
            let rig = &spec.rig;
            for o in spec.objects.iter().filter(|o| o.target_disparity.is_some()) {
                let d = o.target_disparity.unwrap();
                assert!(d >= r.objects.disparity_px.min && d <= r.objects.disparity_px.max);
                let (ul, vl) = rig.project(View::Left, o.location).unwrap();
                let (ur, vr) = rig.project(View::Right, o.location).unwrap();
                assert!((ul - ur - d).abs() < 1e-9, "projected disparity {} != target {d}", ul - ur);
                assert!((vl - vr).abs() < 1e-12);
                for u in [ul, ur] {
                    assert!((0.0..=f64::from(rig.width)).contains(&u), "centre outside a view: {u}");
                }
                assert!((0.0..=f64::from(rig.height)).contains(&vl));
                // Angular size: mean radius / depth is inside the recipe's range (proportions 0.7..1.3).
                let z = -o.location[2];
                let mean_radius = o.scale.iter().sum::<f64>() / 3.0;
                let angular = 2.0 * mean_radius * rig.f_px() / z / f64::from(rig.width);
                assert!(angular >= r.objects.angular_size.min * 0.7 - 1e-9);
                assert!(angular <= r.objects.angular_size.max * 1.3 + 1e-9);
            }
        }
    }

    #[test]
    fn background_fills_both_views_behind_every_object() {
        let r = Recipe::builtin_default();
        let spec = plan_scene(&r, 3, 0);
        let bg = &spec.objects[0];
        let z_bg = -bg.location[2];
        let rig = &spec.rig;
        for view in [View::Left, View::Right] {
            for corner in [[-1.0, -1.0], [1.0, 1.0], [-1.0, 1.0], [1.0, -1.0]] {
                let p = [bg.location[0] + corner[0] * bg.scale[0], bg.location[1] + corner[1] * bg.scale[1], -z_bg];
                let (u, v) = rig.project(view, p).unwrap();
                assert!(u < 0.0 || u > f64::from(rig.width));
                assert!(v < 0.0 || v > f64::from(rig.height));
            }
        }
        for o in &spec.objects[1..] {
            assert!(-o.location[2] < z_bg);
        }
    }
}
