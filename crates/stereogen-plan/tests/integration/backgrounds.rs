//! Backgrounds (a category's `background` weights), planned without Blender: the kinds come in
//! their weights' shares, a room closes the view around the back wall with furniture standing on
//! its floor, an environment has a ground under a sky and no wall, and recipes that name only the
//! wall plan exactly as before.

use stereogen_plan::rig::View;
use stereogen_plan::{
    AssetIndex, BackgroundKind, LightSpec, Modifier, ObjectRole, Recipe, STUDIO_HDRIS, SceneSpec,
    plan_scene,
};

/// Where the ray through image position (u, v) of the left view meets the plane `axis = value`,
/// as a depth in front of the camera (None when it never does).
fn depth_on_plane(spec: &SceneSpec, u: f64, v: f64, axis: usize, value: f64) -> Option<f64> {
    let d = spec.rig.ray_direction(u, v);
    let origin = [spec.rig.camera_x(View::Left), 0.0, 0.0];
    let t = (value - origin[axis]) / d[axis];
    (t > 0.0).then(|| -t * d[2])
}

#[test]
fn backgrounds_come_in_their_weights_and_rooms_close_the_view() {
    let recipe = Recipe::preset("wmgstereo").unwrap();
    let assets = AssetIndex::default();
    let n = 300;
    let mut counts = [0usize; 3];
    // Environments under the procedural sky, inside an HDR map.
    let mut backdrops = [0usize; 2];
    for index in 0..n {
        let spec = plan_scene(&recipe, &assets, 7, index);
        let kind = spec.background_kind();
        counts[kind as usize] += 1;
        let content = spec
            .objects
            .iter()
            .filter(|o| o.role == ObjectRole::Content)
            .count();
        assert!(content > 0, "{index}: no floating objects");
        // The background objects come first, the content after them.
        let first_content = spec
            .objects
            .iter()
            .position(|o| o.role == ObjectRole::Content)
            .unwrap();
        assert!(
            spec.objects[first_content..]
                .iter()
                .all(|o| o.role == ObjectRole::Content)
        );
        let wall = spec.objects.iter().find(|o| o.source == "wall");
        match kind {
            BackgroundKind::Environment => {
                assert!(wall.is_none(), "{index}: an environment has no wall");
                // A sky or one of Blender's HDR maps, never both.
                match (&spec.world.sky, &spec.world.hdri) {
                    (Some(_), None) => backdrops[0] += 1,
                    (None, Some(h)) => {
                        assert!(STUDIO_HDRIS.contains(&h.name.as_str()), "{}", h.name);
                        assert!((0.3..1.0).contains(&h.strength));
                        backdrops[1] += 1;
                    }
                    other => panic!("{index}: {other:?}"),
                }
                let ground = spec.objects.iter().find(|o| o.source == "ground").unwrap();
                // The ground lies under the cameras and reaches towards the far clip.
                assert!(ground.location[1] < 0.0);
                assert!(2.0 * ground.scale[1] >= 0.9 * spec.render.clip_end);
            }
            BackgroundKind::Room => {
                let depth = -wall.unwrap().location[2];
                let surface = |name: &str| spec.objects.iter().find(|o| o.name == name).unwrap();
                let floor_y = surface("room_floor").location[1];
                let ceiling_y = surface("room_ceiling").location[1];
                let left_x = surface("room_wall_left").location[0];
                let right_x = surface("room_wall_right").location[0];
                assert!(floor_y < 0.0 && ceiling_y > 0.0 && left_x < 0.0 && right_x > 0.0);
                // Every image corner's ray meets a room surface before the back wall: the room
                // closes the view (the side walls and floor reach the frame's edges).
                let (w, h) = (f64::from(spec.rig.width), f64::from(spec.rig.height));
                for (u, v) in [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)] {
                    let nearest = [(1, floor_y), (1, ceiling_y), (0, left_x), (0, right_x)]
                        .iter()
                        .filter_map(|&(axis, value)| depth_on_plane(&spec, u, v, axis, value))
                        .fold(f64::INFINITY, f64::min);
                    assert!(
                        nearest < depth,
                        "{index}: corner ({u}, {v}) sees past the room"
                    );
                }
                // Furniture inside the room, placed where its unit sphere touches the floor and
                // dropped onto it by the worker.
                let furniture: Vec<_> = spec
                    .objects
                    .iter()
                    .filter(|o| o.source == "furniture")
                    .collect();
                assert!((1..=4).contains(&furniture.len()));
                for f in furniture {
                    assert!((f.location[1] - f.scale[1] - floor_y).abs() < 1e-9 * depth);
                    assert_eq!(f.modifiers, [Modifier::RestOnFloor { y: floor_y }]);
                    assert!(f.location[0].abs() + f.scale[0] <= right_x + 1e-9 * depth);
                    assert!(-f.location[2] + f.scale[2] <= depth * (1.0 + 1e-9));
                }
                // Ceiling panels and a window, beside the recipe's lights.
                let area = spec
                    .lights
                    .iter()
                    .filter(|l| matches!(l, LightSpec::Area { .. }))
                    .count();
                assert!(area >= 2);
            }
            BackgroundKind::Wall => assert!(wall.is_some()),
        }
    }
    // Weights 0.2 / 0.7 / 0.1: within 4.5 standard deviations of a binomial draw.
    for (count, p) in counts.iter().zip([0.2, 0.7, 0.1]) {
        let (mean, sd) = (p * n as f64, (p * (1.0 - p) * n as f64).sqrt());
        assert!(
            (*count as f64 - mean).abs() < 4.5 * sd,
            "counts {counts:?} against weights 0.2/0.7/0.1"
        );
    }
    // About 30 environments, half of them in an HDR map.
    assert!(
        backdrops.iter().all(|n| *n >= 5),
        "sky / HDR map: {backdrops:?}"
    );
}

#[test]
fn a_wall_only_category_plans_as_before_and_weights_are_checked() {
    // The same recipe with the weights set to the wall alone plans the crestereo preset's scenes.
    let crestereo = Recipe::preset("crestereo").unwrap();
    let mut walls = Recipe::preset("wmgstereo").unwrap();
    walls.name = crestereo.name.clone();
    for c in &mut walls.categories {
        c.background = [(stereogen_plan::BackgroundKind::Wall, 1.0)].into();
    }
    assert_eq!(
        walls, crestereo,
        "wmgstereo differs from crestereo beyond its backgrounds"
    );
    assert_eq!(walls.fingerprint(), crestereo.fingerprint());
    let assets = AssetIndex::default();
    for index in 0..20 {
        assert_eq!(
            plan_scene(&walls, &assets, 3, index),
            plan_scene(&crestereo, &assets, 3, index)
        );
    }
    let text = stereogen_plan::recipe::PRESETS
        .iter()
        .find(|(n, _)| *n == "wmgstereo")
        .unwrap()
        .1
        .replacen("room = 0.7", "room = -1.0", 1);
    let e = Recipe::from_toml_str(&text, "x.toml")
        .unwrap_err()
        .to_string();
    assert!(e.contains("categories[0].background"), "{e}");
}

/// The same scenes planned as rooms and before the wall: a room keeps the recipe's lights with
/// half their power (a sun keeps its strength), adds its own after them, and changes nothing else
/// of them.
#[test]
fn a_room_dims_the_recipe_lights_to_half() {
    let with = |kind| {
        let mut r = Recipe::preset("wmgstereo").unwrap();
        for c in &mut r.categories {
            c.background = [(kind, 1.0)].into();
        }
        r
    };
    let (rooms, walls) = (with(BackgroundKind::Room), with(BackgroundKind::Wall));
    let assets = AssetIndex::default();
    let share = stereogen_plan::backgrounds::ROOM_LIGHT_SHARE;
    let mut dimmed = 0;
    for index in 0..20 {
        let room = plan_scene(&rooms, &assets, 4, index);
        let wall = plan_scene(&walls, &assets, 4, index);
        assert!(
            room.lights.len() > wall.lights.len(),
            "{index}: no room lights"
        );
        for (r, w) in room.lights.iter().zip(&wall.lights) {
            let mut expected = w.clone();
            match &mut expected {
                LightSpec::Point { power_w, .. }
                | LightSpec::Spot { power_w, .. }
                | LightSpec::Area { power_w, .. } => {
                    *power_w *= share;
                    dimmed += 1;
                }
                LightSpec::Sun { .. } => {}
            }
            assert_eq!(*r, expected, "{index}");
        }
    }
    assert!(dimmed > 20, "{dimmed} lights dimmed");
}
