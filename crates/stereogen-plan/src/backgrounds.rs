//! What fills the view behind the floating objects, by a category's `background` weights:
//!
//! - `wall`: the paper's textured wall at the background depth (the default, and what every
//!   preset before this drew);
//! - `room`: that wall as the back of a room — a floor, a ceiling and two side walls textured from
//!   the same photo pool, furniture-sized meshes standing on the floor, light from ceiling panels
//!   and a window — after the finding that realistic indoor backgrounds with floating objects
//!   train stereo networks best (WMGStereo, CVPR 2026);
//! - `environment`: no wall; a ground plane under a procedural sky (Blender's Hosek–Wilkie sky
//!   model) or inside one of the HDR environment maps Blender ships (CC0), which lights the
//!   scene. Pixels that see the sky have no surface and no disparity, as in outdoor stereo sets.
//!
//! The room is sized from the region both cameras see at the back wall's depth, so its surfaces
//! cover the frame's edges at depths between a fraction of the wall's and the wall's own: the
//! disparity law still places every content object, and what the room adds lies at the far end
//! of the disparity range. Every number is drawn here; Blender only builds it.

use std::f64::consts::{FRAC_PI_2, PI};

use rand::Rng;
use rand::seq::IndexedRandom;

use super::assets::{AssetIndex, MeshAsset};
use super::recipe::{CategoryRecipe, Recipe};
use super::rig::StereoRig;
use super::rng::SeedTree;
use super::sampler::{material, pick_weighted};
pub use super::spec::BackgroundKind;
use super::spec::{
    HdriSpec, LightSpec, Modifier, ObjectRole, ObjectSpec, STUDIO_HDRIS, Shape, SkySpec, WorldSpec,
};

/// The kind scene `root` draws: without a draw where the category names only `wall` (so every
/// recipe written before rooms plans as it did).
pub fn background_kind(category: &CategoryRecipe, root: SeedTree) -> BackgroundKind {
    let drawable: Vec<_> = category
        .background
        .iter()
        .filter(|(_, w)| **w > 0.0)
        .collect();
    match drawable.as_slice() {
        [] => BackgroundKind::Wall,
        [(kind, _)] => **kind,
        _ => pick_weighted(
            &mut root.child("background-kind").rng(),
            &category.background,
        ),
    }
}

/// The room's extent: the side walls at ±`half_width`, the floor `floor_drop` below the cameras,
/// the ceiling `ceiling_rise` above them, from `front` (behind the cameras) to the back wall at
/// `-depth`.
struct RoomBox {
    half_width: f64,
    floor_drop: f64,
    ceiling_rise: f64,
    front: f64,
    depth: f64,
}

impl RoomBox {
    fn draw<R: Rng>(rig: &StereoRig, depth: f64, rng: &mut R) -> Self {
        // The frame both cameras see at the back wall's depth.
        let f = rig.f_px();
        let half_w = f64::from(rig.width) / 2.0 / f * depth + rig.baseline_m / 2.0;
        let half_h = f64::from(rig.height) / 2.0 / f * depth;
        Self {
            // Side walls, floor and ceiling cut into the frame: each shows at the image's edge
            // from a depth of the fraction drawn times the wall's on.
            half_width: half_w * rng.random_range(0.55..0.95),
            floor_drop: half_h * rng.random_range(0.45..0.9),
            ceiling_rise: half_h * rng.random_range(0.6..1.05),
            front: 0.05 * depth,
            depth,
        }
    }

    fn length(&self) -> f64 {
        self.front + self.depth
    }

    fn mid_z(&self) -> f64 {
        (self.front - self.depth) / 2.0
    }
}

/// A textured plane of the room (a `Plane` is 2×2 facing +Z before its rotation and scale).
fn surface(
    name: &str,
    recipe: &Recipe,
    assets: &AssetIndex,
    location: [f64; 3],
    rotation: [f64; 3],
    scale: [f64; 2],
    node: SeedTree,
) -> ObjectSpec {
    let mut rng = node.rng();
    let class = pick_weighted(&mut rng, &recipe.materials.background);
    let mut m = material(recipe, assets, class, &mut rng);
    super::sampler::clamp_background_scale(recipe, &mut m);
    ObjectSpec {
        name: name.into(),
        role: ObjectRole::Background,
        source: "room".into(),
        shape: Shape::Plane,
        modifiers: Vec::new(),
        location,
        rotation,
        scale: [scale[0], scale[1], 1.0],
        material: m,
        target_disparity: None,
    }
}

/// Floor, ceiling and side walls (the back wall is the scene's wall).
fn room_surfaces(
    recipe: &Recipe,
    assets: &AssetIndex,
    room: &RoomBox,
    node: SeedTree,
) -> Vec<ObjectSpec> {
    let (w, len, z) = (room.half_width, room.length(), room.mid_z());
    let height = room.floor_drop + room.ceiling_rise;
    let mid_y = (room.ceiling_rise - room.floor_drop) / 2.0;
    vec![
        // Turned −90° about X: facing up (+Y), its local y along −Z.
        surface(
            "room_floor",
            recipe,
            assets,
            [0.0, -room.floor_drop, z],
            [-FRAC_PI_2, 0.0, 0.0],
            [w, len / 2.0],
            node.child("floor"),
        ),
        surface(
            "room_ceiling",
            recipe,
            assets,
            [0.0, room.ceiling_rise, z],
            [FRAC_PI_2, 0.0, 0.0],
            [w, len / 2.0],
            node.child("ceiling"),
        ),
        // Turned ±90° about Y: facing +X (left wall) or −X (right wall), local x along Z.
        surface(
            "room_wall_left",
            recipe,
            assets,
            [-w, mid_y, z],
            [0.0, FRAC_PI_2, 0.0],
            [len / 2.0, height / 2.0],
            node.child("left"),
        ),
        surface(
            "room_wall_right",
            recipe,
            assets,
            [w, mid_y, z],
            [0.0, -FRAC_PI_2, 0.0],
            [len / 2.0, height / 2.0],
            node.child("right"),
        ),
    ]
}

/// Furniture-sized things standing on the floor in the back half of the room: meshes from the
/// mesh pool (the mesh folder, ShapeNet, or the content pack) or boxes and cylinders without one.
/// A shape fits the unit sphere before its scale: it is placed where its sphere touches the
/// floor, and the worker lowers it until its lowest point does ([`Modifier::RestOnFloor`]).
fn furniture(
    recipe: &Recipe,
    assets: &AssetIndex,
    room: &RoomBox,
    node: SeedTree,
) -> Vec<ObjectSpec> {
    let mut rng = node.child("count").rng();
    let count = rng.random_range(1..=4u32);
    // Borrowed, not copied: a ShapeNet index holds tens of thousands of entries.
    let pool: &[MeshAsset] = [&assets.meshes, &assets.shapenet, &assets.pack_meshes]
        .into_iter()
        .find(|p| !p.is_empty())
        .map_or(&[], |p| p.as_slice());
    (0..count)
        .map(|i| {
            let mut rng = node.nth(u64::from(i)).rng();
            let height = room.floor_drop + room.ceiling_rise;
            let radius = height * rng.random_range(0.12..0.3);
            let x_room = (room.half_width - radius).max(0.0);
            let z_far = -room.depth + radius;
            let z_near = (-0.45 * room.depth).min(z_far);
            let shape = if pool.is_empty() {
                if rng.random_bool(0.5) {
                    Shape::Cube
                } else {
                    Shape::Cylinder { vertices: 32 }
                }
            } else {
                let n = (recipe.sources.mesh_candidates as usize).min(pool.len());
                Shape::MeshFile {
                    candidates: (0..n)
                        .map(|_| pool.choose(&mut rng).expect("non-empty").path.clone())
                        .collect(),
                    max_triangles: recipe.sources.max_triangles,
                }
            };
            let class = pick_weighted(&mut rng, &recipe.materials.background);
            let mut m = material(recipe, assets, class, &mut rng);
            super::sampler::clamp_background_scale(recipe, &mut m);
            // Standing: a shape's up is its +Z (importers turn Y-up files so), the rig's is +Y;
            // then a turn about the vertical only.
            ObjectSpec {
                name: format!("furniture_{i:02}"),
                role: ObjectRole::Background,
                source: "furniture".into(),
                shape,
                modifiers: vec![Modifier::RestOnFloor {
                    y: -room.floor_drop,
                }],
                location: [
                    rng.random_range(-x_room..=x_room),
                    -room.floor_drop + radius,
                    rng.random_range(z_far..=z_near),
                ],
                rotation: [-FRAC_PI_2, rng.random_range(0.0..2.0 * PI), 0.0],
                scale: [radius; 3],
                material: m,
                target_disparity: None,
            }
        })
        .collect()
}

/// The share of its power a recipe light keeps inside a room. A closed room sends back the light
/// an open scene lets escape past the wall. Measured on 8 scenes of `wmgstereo` at 480×270 (seed
/// 2026), each rendered before its wall and in its room: with the recipe's lights at full power,
/// ceiling panels at 0.25 and the window at 0.5 of a free light's, the rooms' mean level was 153
/// of 255 against the walls' 118, with 32% of pixels clipped against 16%; with this share and
/// panels at 0.1, the window at 0.2: 127 and 21% (most clipping in both is the tree scenes').
pub const ROOM_LIGHT_SHARE: f64 = 0.5;

/// Dims one of the recipe's lights to [`ROOM_LIGHT_SHARE`] of its power (a sun, blocked by the
/// ceiling and walls, keeps its strength).
pub fn dim_for_a_room(light: &mut LightSpec) {
    match light {
        LightSpec::Point { power_w, .. }
        | LightSpec::Spot { power_w, .. }
        | LightSpec::Area { power_w, .. } => *power_w *= ROOM_LIGHT_SHARE,
        LightSpec::Sun { .. } => {}
    }
}

/// Ceiling panels and a window on a side wall, facing into the room.
fn room_lights(recipe: &Recipe, room: &RoomBox, node: SeedTree) -> Vec<LightSpec> {
    let mut rng = node.rng();
    let l = &recipe.lights;
    let height = room.floor_drop + room.ceiling_rise;
    let mut lights = Vec::new();
    for _ in 0..rng.random_range(1..=2u32) {
        let z = rng.random_range(-room.depth * 0.9..-room.depth * 0.2);
        // A closed room keeps the light in (walls and ceiling bounce it back): a tenth of a
        // free light's power (see ROOM_LIGHT_SHARE for the measurement).
        let power_w = 0.1 * l.power_w.sample(&mut rng) * z * z;
        lights.push(LightSpec::Area {
            // Just under the ceiling; an area light shines along its local −Z, turned to −Y.
            location: [
                rng.random_range(-0.5..0.5) * room.half_width,
                room.ceiling_rise * 0.98,
                z,
            ],
            rotation: [-FRAC_PI_2, 0.0, 0.0],
            color: [
                1.0,
                rng.random_range(0.85..1.0),
                rng.random_range(0.7..0.95),
            ],
            power_w,
            size: height * rng.random_range(0.15..0.35),
        });
    }
    // A window: daylight through one side wall, shining across the room.
    let side = if rng.random_bool(0.5) { -1.0 } else { 1.0 };
    let z = rng.random_range(-room.depth * 0.8..-room.depth * 0.3);
    let power_w = 0.2 * l.power_w.sample(&mut rng) * z * z;
    lights.push(LightSpec::Area {
        location: [side * room.half_width * 0.98, 0.0, z],
        rotation: [0.0, -side * FRAC_PI_2, 0.0],
        color: [rng.random_range(0.8..0.95), rng.random_range(0.9..1.0), 1.0],
        power_w,
        size: height * rng.random_range(0.3..0.5),
    });
    lights
}

/// What a `room` background adds beside the back wall.
pub struct Room {
    pub objects: Vec<ObjectSpec>,
    pub lights: Vec<LightSpec>,
}

/// The room around the back wall at `depth`.
pub fn room(
    recipe: &Recipe,
    assets: &AssetIndex,
    rig: &StereoRig,
    depth: f64,
    node: SeedTree,
) -> Room {
    let room = RoomBox::draw(rig, depth, &mut node.child("box").rng());
    let mut objects = room_surfaces(recipe, assets, &room, node.child("surfaces"));
    objects.extend(furniture(recipe, assets, &room, node.child("furniture")));
    Room {
        objects,
        lights: room_lights(recipe, &room, node.child("lights")),
    }
}

/// The share of `environment` backgrounds lit by one of Blender's HDR environment maps (the rest
/// by the procedural sky).
pub const HDRI_SHARE: f64 = 0.5;

/// What surrounds an `environment` background's ground: the procedural sky or an HDR map.
#[derive(Debug, Clone, PartialEq)]
pub enum Backdrop {
    Sky(SkySpec),
    Hdri(HdriSpec),
}

impl Backdrop {
    /// Puts it in the world (which keeps its uniform colour for nothing: both replace it).
    pub fn apply(self, world: &mut WorldSpec) {
        match self {
            Backdrop::Sky(sky) => world.sky = Some(sky),
            Backdrop::Hdri(hdri) => world.hdri = Some(hdri),
        }
    }
}

/// What an `environment` background has: a ground plane reaching the far clip, and the sky or an
/// HDR map around it.
pub fn environment(
    recipe: &Recipe,
    assets: &AssetIndex,
    rig: &StereoRig,
    depth: f64,
    clip_end: f64,
    node: SeedTree,
) -> (ObjectSpec, Backdrop) {
    let room = RoomBox::draw(rig, depth, &mut node.child("box").rng());
    // Ground to 95% of the far clip, wide enough to fill the frame there.
    let far = 0.95 * clip_end;
    let half_w = (f64::from(rig.width) / 2.0 / rig.f_px() * far + rig.baseline_m) * 1.1;
    let mut ground = surface(
        "ground",
        recipe,
        assets,
        [0.0, -room.floor_drop, -far / 2.0],
        [-FRAC_PI_2, 0.0, 0.0],
        [half_w, far / 2.0],
        node.child("ground"),
    );
    ground.source = "ground".into();
    let backdrop = if node.child("backdrop").rng().random_bool(HDRI_SHARE) {
        let mut rng = node.child("hdri").rng();
        Backdrop::Hdri(HdriSpec {
            name: STUDIO_HDRIS
                .choose(&mut rng)
                .expect("non-empty")
                .to_string(),
            rotation: rng.random_range(0.0..2.0 * PI),
            // At strength 1 the eight maps gave a test scene mean levels of 136–188 of 255, above
            // the walls' ~118: scaled down, with a spread for exposure variety.
            strength: rng.random_range(0.3..1.0),
        })
    } else {
        let mut rng = node.child("sky").rng();
        Backdrop::Sky(SkySpec {
            sun_elevation: rng.random_range(0.05..1.2),
            sun_rotation: rng.random_range(0.0..2.0 * PI),
            turbidity: rng.random_range(2.0..8.0),
            ground_albedo: rng.random_range(0.1..0.5),
        })
    };
    (ground, backdrop)
}
