//! Turns (recipe, assets, seed, index) into a `SceneSpec`.
//!
//! Placement follows the paper's disparity law: each content object first gets a target
//! disparity from the recipe's law, its depth follows from the rig (Z = f·B/d), its image
//! position is drawn inside the part of the frustum both cameras see at that depth, and its world
//! size grows with Z so its image size stays in the recipe's range and near objects do not wall
//! off the view.

use std::collections::BTreeMap;
use std::f64::consts::PI;

use rand::Rng;
use rand::seq::IndexedRandom;

use super::assets::{AssetIndex, MeshAsset};
use super::backgrounds::{BackgroundKind, background_kind, dim_for_a_room, environment, room};
use super::photo_sizing::size_photo;
use super::recipe::{CategoryRecipe, LightKind, Recipe, ShapeSource, TreeRecipe};
use super::rig::StereoRig;
use super::rng::SeedTree;
use super::shapes::{net, primitive, wireframe};
use super::spec::{
    BaseColor, LightSpec, MaterialClass, MaterialSpec, Modifier, ObjectRole, ObjectSpec, Pattern,
    RenderSettings, SPEC_FORMAT_VERSION, SceneSpec, Shape, WorldSpec,
};
use super::tree::{TreeParams, grow};

/// The near clip never comes closer than this (metres), whatever the recipe says.
const MIN_CLIP_START_M: f64 = 1e-4;

/// Picks a key by weight; keys iterate in a fixed order, so the draw is reproducible.
pub fn pick_weighted<K: Copy + Ord, R: Rng>(rng: &mut R, weights: &BTreeMap<K, f64>) -> K {
    let total: f64 = weights.values().sum();
    let mut x = rng.random_range(0.0..total);
    let mut last = None;
    for (k, w) in weights {
        if *w > 0.0 {
            if x < *w {
                return *k;
            }
            x -= w;
            last = Some(*k);
        }
    }
    last.expect("validated: a positive weight exists")
}

fn random_color<R: Rng>(rng: &mut R) -> [f64; 3] {
    [
        rng.random::<f64>(),
        rng.random::<f64>(),
        rng.random::<f64>(),
    ]
}

/// The stable file stem of sample `index`.
pub fn sample_id(index: u64) -> String {
    format!("{index:07}")
}

/// The category scene `index` draws (needed before planning, e.g. to find its folder).
pub fn scene_category(recipe: &Recipe, seed: u64, index: u64) -> &CategoryRecipe {
    let mut rng = SeedTree::for_sample(seed, index).child("category").rng();
    let weights: BTreeMap<usize, f64> = recipe
        .categories
        .iter()
        .enumerate()
        .map(|(i, c)| (i, c.weight))
        .collect();
    &recipe.categories[pick_weighted(&mut rng, &weights)]
}

/// Plans sample `index` of a dataset made from `recipe` with `seed`.
pub fn plan_scene(recipe: &Recipe, assets: &AssetIndex, seed: u64, index: u64) -> SceneSpec {
    let root = SeedTree::for_sample(seed, index);
    let category = scene_category(recipe, seed, index);
    let rig = draw_rig(recipe, root);
    let mut bg_rng = root.child("background").rng();
    let background_depth =
        rig.depth_for_disparity(recipe.placement.background_disparity_px.sample(&mut bg_rng));
    let nearest_depth = rig.depth_for_disparity(recipe.placement.disparity_px.support().1);
    let render = render_settings(recipe, category, root, nearest_depth, background_depth);

    let kind = background_kind(category, root);
    let mut objects = Vec::new();
    let mut extra_lights = Vec::new();
    let mut backdrop = None;
    if kind == BackgroundKind::Environment {
        let (ground, drawn) = environment(
            recipe,
            assets,
            &rig,
            background_depth,
            render.clip_end,
            root.child("environment"),
        );
        objects.push(ground);
        backdrop = Some(drawn);
    } else {
        objects.push(background_wall(
            recipe,
            assets,
            &rig,
            background_depth,
            root.child("background"),
        ));
    }
    if kind == BackgroundKind::Room {
        let room = room(recipe, assets, &rig, background_depth, root.child("room"));
        objects.extend(room.objects);
        extra_lights = room.lights;
    }
    let n_objects = category
        .objects
        .sample(&mut root.child("object_count").rng());
    for i in 0..n_objects {
        objects.push(content_object(
            recipe,
            category,
            assets,
            &rig,
            root.child("objects").nth(u64::from(i)),
            i,
        ));
    }

    let mut light_rng = root.child("lights").rng();
    let n_lights = recipe.lights.count.sample(&mut light_rng);
    let mut lights: Vec<LightSpec> = (0..n_lights)
        .map(|i| {
            light(
                recipe,
                &rig,
                nearest_depth,
                background_depth,
                root.child("lights").nth(u64::from(i)),
            )
        })
        .collect();
    if kind == BackgroundKind::Room {
        for l in &mut lights {
            dim_for_a_room(l);
        }
    }
    lights.extend(extra_lights);
    let mut world = world(recipe, root);
    if let Some(backdrop) = backdrop {
        backdrop.apply(&mut world);
    }
    SceneSpec {
        format_version: SPEC_FORMAT_VERSION,
        id: sample_id(index),
        category: category.name.clone(),
        seed,
        index,
        rig,
        render,
        world,
        objects,
        lights,
    }
}

fn draw_rig(recipe: &Recipe, root: SeedTree) -> StereoRig {
    let mut rng = root.child("rig").rng();
    let cam = &recipe.camera;
    StereoRig {
        width: cam.width,
        height: cam.height,
        focal_mm: cam.focal_mm.sample(&mut rng),
        sensor_width_mm: cam.sensor_width_mm,
        baseline_m: cam.baseline_m.sample(&mut rng),
    }
}

fn render_settings(
    recipe: &Recipe,
    category: &CategoryRecipe,
    root: SeedTree,
    nearest_depth: f64,
    background_depth: f64,
) -> RenderSettings {
    let cam = &recipe.camera;
    RenderSettings {
        recipe: recipe.render_for(category),
        cycles_seed: root.child("cycles").small_seed(),
        clip_start: (nearest_depth * cam.clip_start_factor).max(MIN_CLIP_START_M),
        clip_end: background_depth * cam.clip_end_factor,
        cycles_seed_right: Some(root.child("cycles-right").small_seed()),
    }
}

/// The uniform world light: a slightly warm grey.
fn world(recipe: &Recipe, root: SeedTree) -> WorldSpec {
    let l = &recipe.lights;
    let mut rng = root.child("world").rng();
    let grey = l.world_grey.sample(&mut rng);
    WorldSpec {
        color: [
            grey,
            grey * l.world_green_ratio.sample(&mut rng),
            grey * l.world_blue_ratio.sample(&mut rng),
        ],
        strength: l.world_strength.sample(&mut rng),
        sky: None,
        hdri: None,
    }
}

/// A background surface is large: keep its texture from turning into noise by scaling repeats to
/// its size.
pub(crate) fn clamp_background_scale(recipe: &Recipe, material: &mut MaterialSpec) {
    if let BaseColor::Procedural { scale, .. } | BaseColor::Image { scale, .. } = &mut material.base
    {
        let [lo, hi] = recipe.materials.background_texture_scale;
        *scale = (*scale).clamp(lo, hi);
    }
}

/// A textured wall at the far end, large enough to fill both cameras' views.
fn background_wall(
    recipe: &Recipe,
    assets: &AssetIndex,
    rig: &StereoRig,
    depth: f64,
    node: SeedTree,
) -> ObjectSpec {
    let f = rig.f_px();
    let oversize = recipe.placement.background_oversize;
    let half_w = (f64::from(rig.width) / 2.0 / f * depth + rig.baseline_m / 2.0) * oversize;
    let half_h = f64::from(rig.height) / 2.0 / f * depth * oversize;
    let mut rng = node.child("material").rng();
    let class = pick_weighted(&mut rng, &recipe.materials.background);
    let mut material = material(recipe, assets, class, &mut rng);
    clamp_background_scale(recipe, &mut material);
    let screen_px = 2.0 * half_w.max(half_h) * f / depth;
    fit_photo(
        recipe,
        assets,
        &mut material,
        screen_px,
        [half_w, half_h, half_w.min(half_h)],
    );
    ObjectSpec {
        name: "background".into(),
        role: ObjectRole::Background,
        source: "wall".into(),
        shape: Shape::Plane,
        modifiers: Vec::new(),
        location: [0.0, 0.0, -depth],
        rotation: [0.0, 0.0, 0.0],
        scale: [half_w, half_h, 1.0],
        material,
        target_disparity: None,
    }
}

/// A surface of the given class.
pub fn material<R: Rng>(
    recipe: &Recipe,
    assets: &AssetIndex,
    class: MaterialClass,
    rng: &mut R,
) -> MaterialSpec {
    let m = &recipe.materials;
    let textured_base = |rng: &mut R| {
        let scale = m.texture_scale.sample(rng);
        // Procedural textures stay one class among the photos (no draw when the share is 0, so
        // recipes without the key plan as before).
        let procedural = !assets.textures.is_empty()
            && m.procedural_share > 0.0
            && rng.random_bool(m.procedural_share);
        let photo = if procedural {
            None
        } else {
            assets.textures.choose(rng)
        };
        match photo {
            Some(photo) => BaseColor::Image {
                path: photo.path.clone(),
                scale,
                rotation: rng.random_range(0.0..2.0 * PI),
                fallback: random_color(rng),
                texture_px: None,
                stretch: None,
            },
            None => BaseColor::Procedural {
                pattern: *Pattern::ALL.choose(rng).expect("non-empty"),
                scale,
                color_a: random_color(rng),
                color_b: random_color(rng),
                detail: m.procedural_detail.sample(rng),
            },
        }
    };
    let (base, roughness, metallic, transmission) = match class {
        MaterialClass::Textured => (textured_base(rng), m.roughness.sample(rng), 0.0, 0.0),
        MaterialClass::Textureless => (
            BaseColor::Flat {
                color: random_color(rng),
            },
            m.roughness.sample(rng),
            0.0,
            0.0,
        ),
        MaterialClass::Glossy => {
            let base = if rng.random_bool(m.glossy_textured_probability) {
                textured_base(rng)
            } else {
                BaseColor::Flat {
                    color: random_color(rng),
                }
            };
            (base, m.glossy_roughness.sample(rng), 0.0, 0.0)
        }
        MaterialClass::Metallic => {
            let tint: [f64; 3] = std::array::from_fn(|_| m.metallic_tint.sample(rng));
            (
                BaseColor::Flat { color: tint },
                m.metallic_roughness.sample(rng),
                1.0,
                0.0,
            )
        }
        MaterialClass::Glass => {
            let tint: [f64; 3] = std::array::from_fn(|_| m.glass_tint.sample(rng));
            (
                BaseColor::Flat { color: tint },
                m.glass_roughness.sample(rng),
                0.0,
                1.0,
            )
        }
    };
    MaterialSpec {
        class,
        base,
        roughness,
        metallic,
        transmission,
        ior: m.ior.sample(rng),
        pass_index: class.pass_index(),
    }
}

fn content_object(
    recipe: &Recipe,
    category: &CategoryRecipe,
    assets: &AssetIndex,
    rig: &StereoRig,
    node: SeedTree,
    i: u32,
) -> ObjectSpec {
    let p = &recipe.placement;
    let mut rng = node.child("placement").rng();
    let d = p.disparity_px.sample(&mut rng);
    let z = rig.depth_for_disparity(d);
    let (w, h) = (f64::from(rig.width), f64::from(rig.height));
    // The centre must project into both images: u_left in [d, W] keeps u_right = u_left - d >= 0.
    let (mu, mv) = (p.margin * w, p.margin * h);
    let u_lo = (mu + d).min(w - mu);
    let u = rng.random_range(u_lo..=(w - mu));
    let v = rng.random_range(mv..=(h - mv));
    let location = rig.unproject_left(u, v, z);
    // Diameter `angular_size * W` pixels at depth z: the world radius grows linearly with z.
    let radius = p.angular_size.sample(&mut rng) * w / 2.0 * z / rig.f_px();
    let rotation: [f64; 3] = std::array::from_fn(|_| rng.random_range(0.0..2.0 * PI));

    let mut shape_rng = node.child("shape").rng();
    let source = pick_weighted(&mut shape_rng, &category.shapes);
    let drawn_from = shape_pool(recipe, assets, source, &mut shape_rng);
    let mut mat_rng = node.child("material").rng();
    let class = pick_weighted(&mut mat_rng, &category.materials);
    let mut material = material(recipe, assets, class, &mut mat_rng);
    let drawn = draw_shape(recipe, drawn_from, &mut shape_rng);
    fit_photo(
        recipe,
        assets,
        &mut material,
        2.0 * radius * rig.f_px() / z,
        drawn.proportions,
    );

    ObjectSpec {
        name: format!("object_{i:03}"),
        role: ObjectRole::Content,
        source: drawn_from.name(),
        shape: drawn.shape,
        modifiers: drawn.modifiers,
        location,
        rotation: drawn.rotation.unwrap_or(rotation),
        scale: drawn.proportions.map(|q| q * radius),
        material,
        target_disparity: Some(d),
    }
}

/// Applies the recipe's photo sizing (`materials.photo_texel_px`) to a photo of known size.
fn fit_photo(
    recipe: &Recipe,
    assets: &AssetIndex,
    material: &mut MaterialSpec,
    screen_px: f64,
    axes: [f64; 3],
) {
    let (Some(texel_px), BaseColor::Image { path, .. }) =
        (recipe.materials.photo_texel_px, &material.base)
    else {
        return;
    };
    if let Some(size) = assets.texture_size(path) {
        size_photo(&mut material.base, size, screen_px, axes, texel_px);
    }
}

/// Where an object's shape comes from once the folders are known.
#[derive(Clone, Copy)]
enum DrawnFrom<'a> {
    /// A procedural source (or primitives standing in for a mesh source without files).
    Procedural(ShapeSource),
    /// A mesh source with its pool of files.
    Files(ShapeSource, &'a [MeshAsset]),
    /// The built-in pack's meshes, standing in for a mesh source without files.
    Pack(&'a [MeshAsset]),
}

impl DrawnFrom<'_> {
    /// The `source` an object records.
    fn name(self) -> String {
        match self {
            DrawnFrom::Procedural(s) | DrawnFrom::Files(s, _) => serde_json::to_value(s)
                .ok()
                .and_then(|v| v.as_str().map(String::from))
                .unwrap_or_default(),
            DrawnFrom::Pack(_) => "pack".into(),
        }
    }
}

/// The folder a draw of a mesh source takes its files from. `meshes` reads the mesh folder.
/// `shapenet` (what the presets' object categories draw) reads the ShapeNet folder, or the mesh
/// folder when only that is given; with both, each draw takes one of the two with equal chance,
/// so a small folder of one's own is not drowned by ShapeNet's tens of thousands of models.
/// The coin is tossed only when both folders have files, so other plans do not move.
fn mesh_folder<'a, R: Rng>(
    assets: &'a AssetIndex,
    source: ShapeSource,
    rng: &mut R,
) -> (ShapeSource, &'a [MeshAsset]) {
    let shapenet = (ShapeSource::Shapenet, assets.shapenet.as_slice());
    let meshes = (ShapeSource::Meshes, assets.meshes.as_slice());
    match source {
        ShapeSource::Shapenet if assets.shapenet.is_empty() => meshes,
        ShapeSource::Shapenet if !assets.meshes.is_empty() && rng.random_bool(0.5) => meshes,
        ShapeSource::Shapenet => shapenet,
        _ => meshes,
    }
}

/// A mesh source without files falls back to the pack's meshes (a `pack_mesh_share` of the
/// time, when the index has them) and to the built-in procedural primitives otherwise.
fn shape_pool<'a, R: Rng>(
    recipe: &Recipe,
    assets: &'a AssetIndex,
    source: ShapeSource,
    rng: &mut R,
) -> DrawnFrom<'a> {
    if !matches!(source, ShapeSource::Shapenet | ShapeSource::Meshes) {
        return DrawnFrom::Procedural(source);
    }
    let (folder, files) = mesh_folder(assets, source, rng);
    if !files.is_empty() {
        return DrawnFrom::Files(folder, files);
    }
    // The draw is taken only when the pack is there, so plans without it do not move.
    if !assets.pack_meshes.is_empty() && rng.random_bool(recipe.sources.pack_mesh_share) {
        return DrawnFrom::Pack(&assets.pack_meshes);
    }
    DrawnFrom::Procedural(ShapeSource::Primitive)
}

/// A shape drawn from one source, in object space.
struct DrawnShape {
    shape: Shape,
    modifiers: Vec<Modifier>,
    /// Per-axis proportions (the largest 1).
    proportions: [f64; 3],
    /// An orientation the source imposes (trees stand up), instead of a random one.
    rotation: Option<[f64; 3]>,
}

fn draw_shape<R: Rng>(recipe: &Recipe, from: DrawnFrom<'_>, rng: &mut R) -> DrawnShape {
    let plain = |shape, modifiers| DrawnShape {
        shape,
        modifiers,
        proportions: [1.0; 3],
        rotation: None,
    };
    let source = match from {
        DrawnFrom::Files(_, pool) | DrawnFrom::Pack(pool) => {
            let n = (recipe.sources.mesh_candidates as usize).min(pool.len());
            let candidates = (0..n)
                .map(|_| pool.choose(rng).expect("non-empty").path.clone())
                .collect();
            return plain(
                Shape::MeshFile {
                    candidates,
                    max_triangles: recipe.sources.max_triangles,
                },
                Vec::new(),
            );
        }
        DrawnFrom::Procedural(source) => source,
    };
    match source {
        ShapeSource::Primitive => {
            let (shape, modifiers, proportions) = primitive(&recipe.primitives, rng);
            DrawnShape {
                shape,
                modifiers,
                proportions,
                rotation: None,
            }
        }
        ShapeSource::Wireframe => {
            let (shape, modifiers) = wireframe(&recipe.holes, rng);
            plain(shape, modifiers)
        }
        ShapeSource::Net => plain(net(&recipe.holes, rng), Vec::new()),
        // Mesh sources arrive as `Files`, `Pack` or primitives (see `shape_pool`).
        ShapeSource::Shapenet | ShapeSource::Meshes => {
            unreachable!("mesh sources are resolved by shape_pool")
        }
        ShapeSource::Tree => tree(&recipe.trees, rng),
    }
}

/// A grown tree standing up: object +Z becomes world +Y, with a random yaw and a slight lean.
fn tree<R: Rng>(t: &TreeRecipe, rng: &mut R) -> DrawnShape {
    let params = TreeParams::draw(rng, t);
    let tree = grow(&params, rng);
    let rotation = [
        -PI / 2.0 + t.lean_rad.sample(rng),
        rng.random_range(0.0..2.0 * PI),
        t.lean_rad.sample(rng),
    ];
    let leaf_color = t.leaf_rgb.map(|c| c.sample(rng));
    let leaf = MaterialSpec {
        class: MaterialClass::Textureless,
        base: BaseColor::Flat { color: leaf_color },
        roughness: t.leaf_roughness,
        metallic: 0.0,
        transmission: 0.0,
        ior: 1.45,
        pass_index: 0,
    };
    let shape = Shape::Skeleton {
        strands: tree.strands,
        strand_levels: tree.strand_levels,
        sides: 8,
        leaves: tree.leaves,
        leaf_material: Some(Box::new(leaf)),
    };
    DrawnShape {
        shape,
        modifiers: Vec::new(),
        proportions: [1.0; 3],
        rotation: Some(rotation),
    }
}

/// Approximate linear-RGB colour of a blackbody at `kelvin` (Tanner Helland's fit of the
/// Planckian locus in sRGB, then linearised), normalised so its brightest channel is 1.
pub fn blackbody_rgb(kelvin: f64) -> [f64; 3] {
    let t = kelvin / 100.0;
    let r = if t <= 66.0 {
        255.0
    } else {
        329.698_727_446 * (t - 60.0).powf(-0.133_204_759_2)
    };
    let g = if t <= 66.0 {
        99.470_802_586_1 * t.ln() - 161.119_568_166_1
    } else {
        288.122_169_528_3 * (t - 60.0).powf(-0.075_514_849_2)
    };
    let b = if t >= 66.0 {
        255.0
    } else if t <= 19.0 {
        0.0
    } else {
        138.517_731_223_1 * (t - 10.0).ln() - 305.044_792_730_7
    };
    let lin = |c: f64| {
        let c = (c / 255.0).clamp(0.0, 1.0);
        if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        }
    };
    let rgb = [lin(r), lin(g), lin(b)];
    let m = rgb.iter().copied().fold(1e-9, f64::max);
    rgb.map(|c| c / m)
}

/// A light at a random place inside the scene volume (between the nearest objects and the wall).
fn light(recipe: &Recipe, rig: &StereoRig, near: f64, far: f64, node: SeedTree) -> LightSpec {
    let l = &recipe.lights;
    let mut rng = node.rng();
    let kind = pick_weighted(&mut rng, &l.kinds);
    let color = if rng.random_bool(l.blackbody_fraction) {
        blackbody_rgb(l.temperature_k.sample(&mut rng))
    } else {
        std::array::from_fn(|_| l.color_channel.sample(&mut rng))
    };
    let z = rng.random_range((near * l.near_factor)..(far * l.far_factor));
    // Lights may sit a little outside the view so that they light it from the side.
    let u = l.image_position.sample(&mut rng) * f64::from(rig.width);
    let v = l.image_position.sample(&mut rng) * f64::from(rig.height);
    let location = rig.unproject_left(u, v, z);
    // Power scales with depth squared so a light deep in a large scene still reaches it.
    let power_w = l.power_w.sample(&mut rng) * z * z;
    // Aim lights roughly into the scene (−Z), with some spread.
    let rotation = [
        l.tilt_rad.sample(&mut rng),
        l.tilt_rad.sample(&mut rng),
        rng.random_range(0.0..2.0 * PI),
    ];
    let radius = l.radius_factor * z;
    match kind {
        LightKind::Point => LightSpec::Point {
            location,
            color,
            power_w,
            radius,
        },
        LightKind::Spot => LightSpec::Spot {
            location,
            rotation,
            color,
            power_w,
            radius,
            spot_size: l.spot_size_rad.sample(&mut rng),
            blend: l.spot_blend.sample(&mut rng),
        },
        LightKind::Area => LightSpec::Area {
            location,
            rotation,
            color,
            power_w,
            size: l.area_size_factor.sample(&mut rng) * z,
        },
        LightKind::Sun => LightSpec::Sun {
            rotation,
            color,
            strength: l.sun_strength.sample(&mut rng),
        },
    }
}
