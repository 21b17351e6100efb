//! The checks of a parsed recipe, one row per key, grouped by recipe section: every value in its
//! range, named by its key when it is not. Rows marked `with_default` are the keys of
//! `added_keys!` (they may be left out of a recipe).

use std::borrow::Cow;
use std::f64::consts::{FRAC_PI_2, PI};

use super::{Recipe, RecipeError, RenderRecipe};
use crate::checker::scene_spec::IMAGE_SIDE_PX;
use crate::checker::{Check, Rule, count, dist, first_violation, int, number, probability, range};

impl Recipe {
    pub(super) fn validate(&self, source_name: &str) -> Result<(), RecipeError> {
        first_violation(recipe_checks(self)).map_err(|v| RecipeError::Invalid {
            source_name: source_name.to_string(),
            key: v.key,
            allowed: v.allowed,
        })
    }
}

/// Every row of a recipe's check, section by section, in the order they are reported.
pub fn recipe_checks(r: &Recipe) -> Vec<Check<'_>> {
    let mut rows = vec![Check::new("name", Rule::folder_name(&r.name))];
    for section in [
        camera, render, placement, lights, sources, primitives, trees, holes, materials, categories,
    ] {
        rows.extend(section(r));
    }
    rows
}

fn camera(r: &Recipe) -> Vec<Check<'_>> {
    let c = &r.camera;
    let (side_min, side_max) = IMAGE_SIDE_PX;
    vec![
        int("camera.width", c.width, side_min, side_max),
        int("camera.height", c.height, side_min, side_max),
        dist("camera.focal_mm", &c.focal_mm, 1.0, 1000.0),
        number("camera.sensor_width_mm", c.sensor_width_mm, 1.0, 100.0),
        dist("camera.baseline_m", &c.baseline_m, 1e-4, 10.0),
        number("camera.clip_start_factor", c.clip_start_factor, 1e-6, 1.0).with_default(),
        // Past the wall, so the far clip never cuts it.
        number("camera.clip_end_factor", c.clip_end_factor, 1.001, 1e4).with_default(),
    ]
}

fn render(r: &Recipe) -> Vec<Check<'_>> {
    render_rows("render.", &r.render)
}

/// The rows of one set of render settings, keys under `prefix` (`render.`, or a category's
/// `categories[i].render.` for its settings with its own keys in place).
fn render_rows(prefix: &str, x: &RenderRecipe) -> Vec<Check<'static>> {
    let key = |k: &str| -> Cow<'static, str> { format!("{prefix}{k}").into() };
    vec![
        Check::new(
            key("samples"),
            Rule::Int {
                value: x.samples.into(),
                lo: 1,
                hi: 65536,
            },
        ),
        Check::new(
            key("max_bounces"),
            Rule::Int {
                value: x.max_bounces.into(),
                lo: 0,
                hi: 128,
            },
        ),
        Check::new(
            key("filter_width_px"),
            Rule::Number {
                value: x.filter_width_px,
                lo: 0.01,
                hi: 10.0,
            },
        ),
        Check::new(
            key("adaptive_threshold"),
            match x.adaptive_threshold {
                // Cycles reads 0 as "choose from the sample count": say it explicitly instead.
                Some(t) => Rule::Holds {
                    holds: t.is_finite() && t > 0.0 && t <= 1.0,
                    need: format!("need 0 < adaptive_threshold <= 1 (leave it out for no adaptive sampling), got {t}"),
                },
                None => Rule::AnyValue,
            },
        )
        .with_default(),
        Check::new(
            key("adaptive_min_samples"),
            Rule::Holds {
                holds: x.adaptive_min_samples <= x.samples,
                need: format!(
                    "need adaptive_min_samples <= samples ({}), got {}",
                    x.samples, x.adaptive_min_samples
                ),
            },
        )
        .with_default(),
        Check::new(key("denoise_prefilter"), Rule::AnyValue).with_default(),
        Check::new(key("denoise_passes"), Rule::AnyValue).with_default(),
        Check::new(key("denoise_quality"), Rule::AnyValue).with_default(),
        Check::new(key("light_tree"), Rule::AnyValue).with_default(),
        Check::new(
            key("outputs"),
            Rule::Holds {
                holds: x
                    .outputs
                    .iter()
                    .enumerate()
                    .all(|(i, o)| !x.outputs[..i].contains(o)),
                need: format!(
                    "need each of depth, normals, instance, semantic at most once, got [{}]",
                    x.outputs
                        .iter()
                        .map(|o| o.name())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            },
        )
        .with_default(),
    ]
}

fn placement(r: &Recipe) -> Vec<Check<'_>> {
    let p = &r.placement;
    let law_min = p.disparity_px.support().0;
    vec![
        // An object centre must fit in both views: its disparity must leave room in the width.
        // (4/5 as a division: `width * 0.8` prints as 76.80000000000001 for width 96.)
        dist(
            "placement.disparity_px",
            &p.disparity_px,
            0.01,
            f64::from(r.camera.width) * 4.0 / 5.0,
        ),
        dist("placement.angular_size", &p.angular_size, 1e-3, 3.0),
        Check::new(
            "placement.margin",
            Rule::BelowExclusive {
                value: p.margin,
                lo: 0.0,
                hi: 0.4,
            },
        ),
        Check::new(
            "placement.background_disparity_px",
            Rule::Holds {
                holds: p
                    .background_disparity_px
                    .validate(1e-3, law_min * 0.999)
                    .is_ok(),
                need: format!("must lie in (0, {law_min}) — below the disparity law's minimum"),
            },
        ),
        number(
            "placement.background_oversize",
            p.background_oversize,
            1.0,
            100.0,
        )
        .with_default(),
    ]
}

fn lights(r: &Recipe) -> Vec<Check<'_>> {
    let (l, p) = (&r.lights, &r.placement);
    // Depths are f·B/d, so the nearest law depth is below near_factor·f·B/d_max and the
    // nearest wall depth is far_factor·f·B/wall_max: the range must be open for every rig.
    let (d_max, wall_max) = (
        p.disparity_px.support().1,
        p.background_disparity_px.support().1,
    );
    vec![
        count("lights.count", &l.count, 0, 64),
        Check::new("lights.kinds", Rule::weights(&l.kinds)),
        dist("lights.power_w", &l.power_w, 0.0, 1e8),
        dist("lights.sun_strength", &l.sun_strength, 0.0, 1e3),
        probability("lights.blackbody_fraction", l.blackbody_fraction),
        dist("lights.temperature_k", &l.temperature_k, 800.0, 40000.0),
        dist("lights.world_strength", &l.world_strength, 0.0, 100.0),
        number("lights.near_factor", l.near_factor, 1e-3, 100.0).with_default(),
        number("lights.far_factor", l.far_factor, 1e-3, 1.0).with_default(),
        Check::new(
            "lights.near_factor",
            Rule::Holds {
                holds: l.near_factor / d_max < l.far_factor / wall_max,
                need: format!(
                    "near_factor / {d_max} px must be below far_factor / {wall_max} px (the wall), got {}",
                    l.near_factor
                ),
            },
        )
        .with_default(),
        range("lights.image_position", &l.image_position, -10.0, 10.0).with_default(),
        range("lights.color_channel", &l.color_channel, 0.0, 1.0).with_default(),
        number("lights.radius_factor", l.radius_factor, 0.0, 10.0).with_default(),
        range("lights.area_size_factor", &l.area_size_factor, 0.0, 10.0).with_default(),
        range("lights.spot_size_rad", &l.spot_size_rad, 0.0, PI).with_default(),
        range("lights.spot_blend", &l.spot_blend, 0.0, 1.0).with_default(),
        range("lights.tilt_rad", &l.tilt_rad, -PI, PI).with_default(),
        range("lights.world_grey", &l.world_grey, 0.0, 1.0).with_default(),
        range("lights.world_green_ratio", &l.world_green_ratio, 0.0, 10.0).with_default(),
        range("lights.world_blue_ratio", &l.world_blue_ratio, 0.0, 10.0).with_default(),
    ]
}

fn sources(r: &Recipe) -> Vec<Check<'_>> {
    let s = &r.sources;
    let blank_licence = s.exclude_licences.iter().find(|l| l.trim().is_empty());
    vec![
        int("sources.max_triangles", s.max_triangles, 1, 100_000_000),
        int("sources.mesh_candidates", s.mesh_candidates, 1, 64).with_default(),
        Check::new("sources.builtin_pack", Rule::AnyValue).with_default(),
        Check::new(
            "sources.exclude_licences",
            Rule::Holds {
                holds: blank_licence.is_none(),
                need: format!(
                    "need licence names, got {:?}",
                    blank_licence.map_or("", |l| l)
                ),
            },
        )
        .with_default(),
        number("sources.pack_mesh_share", s.pack_mesh_share, 0.0, 1.0).with_default(),
    ]
}

fn primitives(r: &Recipe) -> Vec<Check<'_>> {
    let p = &r.primitives;
    vec![
        dist("primitives.proportions", &p.proportions, 0.05, 20.0),
        probability("primitives.subdivide_probability", p.subdivide_probability),
        probability("primitives.displace_probability", p.displace_probability),
        dist(
            "primitives.displace_strength",
            &p.displace_strength,
            0.0,
            1.0,
        ),
        probability("primitives.boolean_probability", p.boolean_probability),
    ]
}

fn trees(r: &Recipe) -> Vec<Check<'_>> {
    let t = &r.trees;
    let mut rows = vec![
        count("trees.levels", &t.levels, 1, 3),
        count("trees.branches", &t.branches, 1, 40),
        dist("trees.length_ratio", &t.length_ratio, 0.05, 1.5),
        dist("trees.down_angle_deg", &t.down_angle_deg, 0.0, 170.0),
        dist("trees.curve_deg", &t.curve_deg, -180.0, 180.0),
        dist("trees.trunk_radius", &t.trunk_radius, 1e-3, 0.3),
        count("trees.leaves_per_branch", &t.leaves_per_branch, 0, 64),
        dist("trees.leaf_size", &t.leaf_size, 1e-3, 0.5),
    ];
    for (channel, r) in ["red", "green", "blue"].iter().zip(&t.leaf_rgb) {
        rows.push(range(format!("trees.leaf_rgb ({channel})"), r, 0.0, 1.0).with_default());
    }
    rows.extend([
        number("trees.leaf_roughness", t.leaf_roughness, 0.0, 1.0).with_default(),
        range("trees.lean_rad", &t.lean_rad, -FRAC_PI_2, FRAC_PI_2).with_default(),
    ]);
    rows
}

fn holes(r: &Recipe) -> Vec<Check<'_>> {
    let h = &r.holes;
    vec![
        dist("holes.wire_thickness", &h.wire_thickness, 1e-3, 0.5),
        count("holes.net_cells", &h.net_cells, 1, 64),
        dist("holes.net_strand", &h.net_strand, 1e-3, 0.45),
    ]
}

fn materials(r: &Recipe) -> Vec<Check<'_>> {
    let m = &r.materials;
    let mut rows = vec![
        dist("materials.texture_scale", &m.texture_scale, 1e-3, 1e4),
        dist("materials.roughness", &m.roughness, 0.0, 1.0),
        dist("materials.ior", &m.ior, 1.0, 3.0),
        Check::new("materials.background", Rule::weights(&m.background)),
        Check::new(
            "materials.background_texture_scale",
            Rule::PositivePair {
                pair: m.background_texture_scale,
                cap: None,
            },
        )
        .with_default(),
        range(
            "materials.procedural_detail",
            &m.procedural_detail,
            0.0,
            15.0,
        )
        .with_default(),
        number(
            "materials.glossy_textured_probability",
            m.glossy_textured_probability,
            0.0,
            1.0,
        )
        .with_default(),
        range("materials.glossy_roughness", &m.glossy_roughness, 0.0, 1.0).with_default(),
        range(
            "materials.metallic_roughness",
            &m.metallic_roughness,
            0.0,
            1.0,
        )
        .with_default(),
        range("materials.metallic_tint", &m.metallic_tint, 0.0, 1.0).with_default(),
        range("materials.glass_roughness", &m.glass_roughness, 0.0, 1.0).with_default(),
        range("materials.glass_tint", &m.glass_tint, 0.0, 1.0).with_default(),
        number("materials.procedural_share", m.procedural_share, 0.0, 1.0).with_default(),
    ];
    let texel = match m.photo_texel_px {
        Some(pair) => Rule::PositivePair {
            pair,
            cap: Some(64.0),
        },
        None => Rule::AnyValue,
    };
    rows.push(Check::new("materials.photo_texel_px", texel).with_default());
    rows
}

fn categories(r: &Recipe) -> Vec<Check<'_>> {
    let mut rows = vec![Check::new(
        "categories",
        Rule::Holds {
            holds: !r.categories.is_empty(),
            need: "need at least one [[categories]] table".into(),
        },
    )];
    let mut seen = std::collections::BTreeSet::new();
    for (i, cat) in r.categories.iter().enumerate() {
        let key = |k: &str| -> Cow<'static, str> { format!("categories[{i}].{k}").into() };
        let unique = seen.insert(cat.name.as_str());
        rows.extend([
            Check::new(
                key("name"),
                Rule::Holds {
                    holds: crate::checker::is_folder_name(&cat.name) && unique,
                    need: format!("need a unique folder name, got {:?}", cat.name),
                },
            ),
            Check::new(
                key("weight"),
                Rule::Holds {
                    holds: cat.weight.is_finite() && cat.weight >= 0.0,
                    need: format!("need >= 0, got {}", cat.weight),
                },
            ),
            count(key("objects"), &cat.objects, 0, 2000),
            Check::new(key("shapes"), Rule::weights(&cat.shapes)),
            Check::new(key("materials"), Rule::weights(&cat.materials)),
            Check::new(key("background"), Rule::weights(&cat.background)),
        ]);
        if cat.render.is_some() {
            rows.extend(render_rows(
                &format!("categories[{i}].render."),
                &r.render_for(cat),
            ));
        }
    }
    rows.push(Check::new(
        "categories",
        Rule::Holds {
            holds: r.categories.iter().map(|c| c.weight).sum::<f64>() > 0.0,
            need: "the category weights sum to 0".into(),
        },
    ));
    rows
}
