//! Checks of a parsed recipe: every value in its range, named by its key when it is not.

use std::collections::BTreeMap;

use super::{CountRange, Dist, Recipe, RecipeError, UniformRange};

fn folder_name_ok(name: &str) -> bool {
    !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
}

impl Recipe {
    pub(super) fn validate(&self, source_name: &str) -> Result<(), RecipeError> {
        let bad = |key: &str, allowed: String| RecipeError::Invalid {
            source_name: source_name.to_string(),
            key: key.to_string(),
            allowed,
        };
        let dist =
            |key: &str, d: &Dist, lo: f64, hi: f64| d.validate(lo, hi).map_err(|m| bad(key, m));
        let count = |key: &str, c: &CountRange, lo: u32, hi: u32| {
            c.validate(lo, hi).map_err(|m| bad(key, m))
        };
        let prob = |key: &str, p: f64| {
            if (0.0..=1.0).contains(&p) {
                Ok(())
            } else {
                Err(bad(key, format!("need a probability in 0..=1, got {p}")))
            }
        };
        fn weights<K: std::fmt::Debug>(w: &BTreeMap<K, f64>) -> Result<(), String> {
            if w.values().any(|v| !(v.is_finite() && *v >= 0.0)) || w.values().sum::<f64>() <= 0.0 {
                return Err(format!("need weights >= 0 with a positive sum, got {w:?}"));
            }
            Ok(())
        }

        if !folder_name_ok(&self.name) {
            return Err(bad(
                "name",
                format!("need letters, digits, '_' or '-', got {:?}", self.name),
            ));
        }
        let c = &self.camera;
        if !(16..=16384).contains(&c.width) {
            return Err(bad(
                "camera.width",
                format!("need 16..=16384, got {}", c.width),
            ));
        }
        if !(16..=16384).contains(&c.height) {
            return Err(bad(
                "camera.height",
                format!("need 16..=16384, got {}", c.height),
            ));
        }
        dist("camera.focal_mm", &c.focal_mm, 1.0, 1000.0)?;
        if !(c.sensor_width_mm.is_finite() && (1.0..=100.0).contains(&c.sensor_width_mm)) {
            return Err(bad(
                "camera.sensor_width_mm",
                format!("need 1..=100, got {}", c.sensor_width_mm),
            ));
        }
        dist("camera.baseline_m", &c.baseline_m, 1e-4, 10.0)?;

        let r = &self.render;
        if !(1..=65536).contains(&r.samples) {
            return Err(bad(
                "render.samples",
                format!("need 1..=65536, got {}", r.samples),
            ));
        }
        if r.max_bounces > 128 {
            return Err(bad(
                "render.max_bounces",
                format!("need 0..=128, got {}", r.max_bounces),
            ));
        }
        if !(0.01..=10.0).contains(&r.filter_width_px) {
            return Err(bad(
                "render.filter_width_px",
                format!("need 0.01..=10, got {}", r.filter_width_px),
            ));
        }

        let p = &self.placement;
        // An object centre must fit in both views: its disparity must leave room in the width.
        // (4/5 as a division: `width * 0.8` prints as 76.80000000000001 for width 96.)
        dist(
            "placement.disparity_px",
            &p.disparity_px,
            0.01,
            f64::from(c.width) * 4.0 / 5.0,
        )?;
        dist("placement.angular_size", &p.angular_size, 1e-3, 3.0)?;
        if !(0.0..0.4).contains(&p.margin) {
            return Err(bad(
                "placement.margin",
                format!("need 0 <= margin < 0.4, got {}", p.margin),
            ));
        }
        let law_min = p.disparity_px.support().0;
        dist(
            "placement.background_disparity_px",
            &p.background_disparity_px,
            1e-3,
            law_min * 0.999,
        )
        .map_err(|_| {
            bad(
                "placement.background_disparity_px",
                format!("must lie in (0, {law_min}) — below the disparity law's minimum"),
            )
        })?;

        let l = &self.lights;
        count("lights.count", &l.count, 0, 64)?;
        weights(&l.kinds).map_err(|m| bad("lights.kinds", m))?;
        dist("lights.power_w", &l.power_w, 0.0, 1e8)?;
        dist("lights.sun_strength", &l.sun_strength, 0.0, 1e3)?;
        prob("lights.blackbody_fraction", l.blackbody_fraction)?;
        dist("lights.temperature_k", &l.temperature_k, 800.0, 40000.0)?;
        dist("lights.world_strength", &l.world_strength, 0.0, 100.0)?;

        if !(1..=100_000_000).contains(&self.sources.max_triangles) {
            return Err(bad(
                "sources.max_triangles",
                format!("need 1..=100000000, got {}", self.sources.max_triangles),
            ));
        }
        let pr = &self.primitives;
        dist("primitives.proportions", &pr.proportions, 0.05, 20.0)?;
        prob("primitives.subdivide_probability", pr.subdivide_probability)?;
        prob("primitives.displace_probability", pr.displace_probability)?;
        dist(
            "primitives.displace_strength",
            &pr.displace_strength,
            0.0,
            1.0,
        )?;
        prob("primitives.boolean_probability", pr.boolean_probability)?;

        let t = &self.trees;
        count("trees.levels", &t.levels, 1, 3)?;
        count("trees.branches", &t.branches, 1, 40)?;
        dist("trees.length_ratio", &t.length_ratio, 0.05, 1.5)?;
        dist("trees.down_angle_deg", &t.down_angle_deg, 0.0, 170.0)?;
        dist("trees.curve_deg", &t.curve_deg, -180.0, 180.0)?;
        dist("trees.trunk_radius", &t.trunk_radius, 1e-3, 0.3)?;
        count("trees.leaves_per_branch", &t.leaves_per_branch, 0, 64)?;
        dist("trees.leaf_size", &t.leaf_size, 1e-3, 0.5)?;

        let h = &self.holes;
        dist("holes.wire_thickness", &h.wire_thickness, 1e-3, 0.5)?;
        count("holes.net_cells", &h.net_cells, 1, 64)?;
        dist("holes.net_strand", &h.net_strand, 1e-3, 0.45)?;

        let m = &self.materials;
        dist("materials.texture_scale", &m.texture_scale, 1e-3, 1e4)?;
        dist("materials.roughness", &m.roughness, 0.0, 1.0)?;
        dist("materials.ior", &m.ior, 1.0, 3.0)?;
        weights(&m.background).map_err(|e| bad("materials.background", e))?;

        if self.categories.is_empty() {
            return Err(bad(
                "categories",
                "need at least one [[categories]] table".into(),
            ));
        }
        let mut seen = std::collections::BTreeSet::new();
        for (i, cat) in self.categories.iter().enumerate() {
            let key = |k: &str| format!("categories[{i}].{k}");
            if !folder_name_ok(&cat.name) || !seen.insert(cat.name.clone()) {
                return Err(bad(
                    &key("name"),
                    format!("need a unique folder name, got {:?}", cat.name),
                ));
            }
            if !(cat.weight.is_finite() && cat.weight >= 0.0) {
                return Err(bad(
                    &key("weight"),
                    format!("need >= 0, got {}", cat.weight),
                ));
            }
            count(&key("objects"), &cat.objects, 0, 2000)?;
            weights(&cat.shapes).map_err(|m| bad(&key("shapes"), m))?;
            weights(&cat.materials).map_err(|m| bad(&key("materials"), m))?;
        }
        if self.categories.iter().map(|c| c.weight).sum::<f64>() <= 0.0 {
            return Err(bad("categories", "the category weights sum to 0".into()));
        }
        self.validate_added_keys(source_name)
    }

    /// The keys of `added_keys!`.
    fn validate_added_keys(&self, source_name: &str) -> Result<(), RecipeError> {
        let bad = |key: &str, allowed: String| RecipeError::Invalid {
            source_name: source_name.to_string(),
            key: key.to_string(),
            allowed,
        };
        let range = |key: &str, r: &UniformRange, lo: f64, hi: f64| {
            r.validate(lo, hi).map_err(|m| bad(key, m))
        };
        let number = |key: &str, v: f64, lo: f64, hi: f64| {
            if v.is_finite() && (lo..=hi).contains(&v) {
                Ok(())
            } else {
                Err(bad(key, format!("need {lo}..={hi}, got {v}")))
            }
        };
        let (c, p, l) = (&self.camera, &self.placement, &self.lights);
        number("camera.clip_start_factor", c.clip_start_factor, 1e-6, 1.0)?;
        // Past the wall, so the far clip never cuts it.
        number("camera.clip_end_factor", c.clip_end_factor, 1.001, 1e4)?;
        number(
            "placement.background_oversize",
            p.background_oversize,
            1.0,
            100.0,
        )?;
        if !(1..=64).contains(&self.sources.mesh_candidates) {
            return Err(bad(
                "sources.mesh_candidates",
                format!("need 1..=64, got {}", self.sources.mesh_candidates),
            ));
        }
        number("lights.near_factor", l.near_factor, 1e-3, 100.0)?;
        number("lights.far_factor", l.far_factor, 1e-3, 1.0)?;
        // Depths are f·B/d, so the nearest law depth is below near_factor·f·B/d_max and the
        // nearest wall depth is far_factor·f·B/wall_max: the range must be open for every rig.
        let (d_max, wall_max) = (
            p.disparity_px.support().1,
            p.background_disparity_px.support().1,
        );
        if l.near_factor / d_max >= l.far_factor / wall_max {
            return Err(bad(
                "lights.near_factor",
                format!(
                    "near_factor / {d_max} px must be below far_factor / {wall_max} px (the wall), got {}",
                    l.near_factor
                ),
            ));
        }
        range("lights.image_position", &l.image_position, -10.0, 10.0)?;
        range("lights.color_channel", &l.color_channel, 0.0, 1.0)?;
        number("lights.radius_factor", l.radius_factor, 0.0, 10.0)?;
        range("lights.area_size_factor", &l.area_size_factor, 0.0, 10.0)?;
        range(
            "lights.spot_size_rad",
            &l.spot_size_rad,
            0.0,
            std::f64::consts::PI,
        )?;
        range("lights.spot_blend", &l.spot_blend, 0.0, 1.0)?;
        range(
            "lights.tilt_rad",
            &l.tilt_rad,
            -std::f64::consts::PI,
            std::f64::consts::PI,
        )?;
        range("lights.world_grey", &l.world_grey, 0.0, 1.0)?;
        range("lights.world_green_ratio", &l.world_green_ratio, 0.0, 10.0)?;
        range("lights.world_blue_ratio", &l.world_blue_ratio, 0.0, 10.0)?;
        let t = &self.trees;
        for (channel, r) in ["red", "green", "blue"].iter().zip(&t.leaf_rgb) {
            range(&format!("trees.leaf_rgb ({channel})"), r, 0.0, 1.0)?;
        }
        number("trees.leaf_roughness", t.leaf_roughness, 0.0, 1.0)?;
        range(
            "trees.lean_rad",
            &t.lean_rad,
            -std::f64::consts::FRAC_PI_2,
            std::f64::consts::FRAC_PI_2,
        )?;
        let m = &self.materials;
        let [lo, hi] = m.background_texture_scale;
        if !(lo.is_finite() && hi.is_finite() && 0.0 < lo && lo <= hi) {
            return Err(bad(
                "materials.background_texture_scale",
                format!("need 0 < min <= max, got [{lo}, {hi}]"),
            ));
        }
        range(
            "materials.procedural_detail",
            &m.procedural_detail,
            0.0,
            15.0,
        )?;
        number(
            "materials.glossy_textured_probability",
            m.glossy_textured_probability,
            0.0,
            1.0,
        )?;
        range("materials.glossy_roughness", &m.glossy_roughness, 0.0, 1.0)?;
        range(
            "materials.metallic_roughness",
            &m.metallic_roughness,
            0.0,
            1.0,
        )?;
        range("materials.metallic_tint", &m.metallic_tint, 0.0, 1.0)?;
        range("materials.glass_roughness", &m.glass_roughness, 0.0, 1.0)?;
        range("materials.glass_tint", &m.glass_tint, 0.0, 1.0)?;
        number("materials.procedural_share", m.procedural_share, 0.0, 1.0)?;
        if let Some([lo, hi]) = m.photo_texel_px
            && !(lo.is_finite() && hi.is_finite() && 0.0 < lo && lo <= hi && hi <= 64.0)
        {
            return Err(bad(
                "materials.photo_texel_px",
                format!("need 0 < min <= max <= 64, got [{lo}, {hi}]"),
            ));
        }
        number(
            "sources.pack_mesh_share",
            self.sources.pack_mesh_share,
            0.0,
            1.0,
        )?;
        if let Some(l) = self
            .sources
            .exclude_licences
            .iter()
            .find(|l| l.trim().is_empty())
        {
            return Err(bad(
                "sources.exclude_licences",
                format!("need licence names, got {l:?}"),
            ));
        }
        Ok(())
    }
}
