//! The check of a scene spec before Blender renders it (`stereogen render --spec` reads specs a
//! person may have written): an id and category that make file names inside the output folder,
//! an image size it can make, a rig and clipping range whose numbers stay finite through every
//! derived quantity, and geometry of a bounded size ([`super::geometry`]). Specs the planner writes always pass: the
//! recipe's own bounds are the same or narrower.

use super::{Check, Rule, Violation, first_violation, int};
use crate::spec::SceneSpec;

/// The image sides (px) a recipe may ask for and a scene spec may carry. One limit for both, so
/// every spec `render` accepts is one a recipe could have planned (a hand-written 8-px spec is
/// refused as the recipe would refuse it, rather than rendered into a dataset no recipe makes).
pub const IMAGE_SIDE_PX: (u64, u64) = (16, 16384);

/// The rows of a scene spec's check, in the order they are reported.
pub fn scene_spec_checks(spec: &SceneSpec) -> Vec<Check<'_>> {
    let (rig, render) = (&spec.rig, &spec.render);
    let (side_min, side_max) = IMAGE_SIDE_PX;
    let positive = |key, value, max| Check::new(key, Rule::Positive { value, max });
    let mut rows = vec![
        // The sample's files are named `<category>/<id>_left.png`: neither may climb out of the
        // output folder.
        Check::new("id", Rule::folder_name(&spec.id)),
        Check::new("category", Rule::folder_name(&spec.category)),
        int("rig.width", rig.width, side_min, side_max),
        int("rig.height", rig.height, side_min, side_max),
        positive("rig.focal_mm", rig.focal_mm, 1e4),
        positive("rig.sensor_width_mm", rig.sensor_width_mm, 1e3),
        positive("rig.baseline_m", rig.baseline_m, 1e3),
        positive("render.clip_start", render.clip_start, 1e6),
        positive("render.clip_end", render.clip_end, 1e9),
        Check::new(
            "render.clip_end",
            Rule::Holds {
                holds: render.clip_end > render.clip_start,
                need: format!(
                    "it must lie beyond render.clip_start = {}, got {}",
                    render.clip_start, render.clip_end
                ),
            },
        ),
        int("render.samples", render.recipe.samples, 1, 65536),
        positive(
            "render.filter_width_px",
            render.recipe.filter_width_px,
            10.0,
        ),
        Check::new(
            "render.adaptive_threshold",
            match render.recipe.adaptive_threshold {
                Some(t) => Rule::Positive { value: t, max: 1.0 },
                None => Rule::AnyValue,
            },
        ),
    ];
    if let Some(hdri) = &spec.world.hdri {
        // The name picks a file inside Blender's own folder: only the maps it ships.
        rows.push(Check::new(
            "world.hdri.name",
            Rule::Holds {
                holds: crate::spec::STUDIO_HDRIS.contains(&hdri.name.as_str()),
                need: format!(
                    "need one of {:?}, got {:?}",
                    crate::spec::STUDIO_HDRIS,
                    hdri.name
                ),
            },
        ));
        rows.push(positive("world.hdri.strength", hdri.strength, 1e3));
        rows.push(Check::new(
            "world.hdri.rotation",
            Rule::Holds {
                holds: hdri.rotation.is_finite(),
                need: format!("need a finite angle, got {}", hdri.rotation),
            },
        ));
        rows.push(Check::new(
            "world.hdri",
            Rule::Holds {
                holds: spec.world.sky.is_none(),
                need: "a world has a sky or an HDR map, not both".into(),
            },
        ));
    }
    rows.extend(super::geometry::geometry_checks(spec));
    rows
}

/// Checks what Blender would otherwise be asked to render; the error names the key and the value.
pub fn check_scene_spec(spec: &SceneSpec) -> Result<(), Violation> {
    first_violation(scene_spec_checks(spec))
}
