//! The card's lines for the maps a sample may carry beside its disparity (`depth_left.exr`,
//! `normals_left.exr`, `instance_left.png`, `semantic_left.png` and the right view's).

use std::fmt::Write as _;

use stereo_io::datasets::stereogen::SemanticClass;

/// What a map member (`depth_left.exr`, ...) is, and what `datasets` makes of it; blanks for a
/// member that is none.
pub(super) fn map_member_row(member: &str) -> (&'static str, &'static str) {
    let Some((key, _)) = member.split_once('.') else {
        return ("", "");
    };
    let (kind, view) = key.rsplit_once('_').unwrap_or((key, ""));
    let what = match (kind, view) {
        ("depth", "left") => {
            "left view's depth, float32 EXR channel `Y`: metres along the optical axis (the Z pass the disparity comes from: `disp = f_px · baseline_m / depth`), 0 = no surface"
        }
        ("depth", "right") => "right view's depth, same format",
        ("normals", "left") => {
            "left view's unit surface normals in the camera frame (x right, y down, z forward), float32 EXR channels `R`, `G`, `B`; 0, 0, 0 = no surface"
        }
        ("normals", "right") => "right view's normals, same format",
        ("instance", "left") => {
            "left view's instance ids, 16-bit grey PNG: the object of each pixel (the `instances` table of the manifest line in `json`), 0 = no surface"
        }
        ("instance", "right") => "right view's instance ids, same format",
        ("semantic", "left") => {
            "left view's class ids, 16-bit grey PNG (the classes listed below), 0 = no surface"
        }
        ("semantic", "right") => "right view's class ids, same format",
        _ => return ("", ""),
    };
    let gives = if kind == "depth" || kind == "normals" {
        "bytes (not decoded: see below)"
    } else {
        "a PIL image (16-bit)"
    };
    (what, gives)
}

/// Where the samples carry maps beside the disparity: how they relate, and the semantic classes.
pub(super) fn maps_section(s: &mut String, members: &[String], classes: &[SemanticClass]) {
    let has = |kind: &str| members.iter().any(|m| m.starts_with(&format!("{kind}_")));
    if !["depth", "normals", "instance", "semantic"]
        .iter()
        .any(|k| has(k))
    {
        return;
    }
    *s += "
## Maps beside the disparity

Every map lies on the disparity's pixel grid and records the same first surface: where the disparity is valid the depth is positive, the normal has unit length and the ids are non-zero. `stereogen.decode_sample` (and `stereogen.open_dataset(...)[i]`) gives them as `depth_left` (float32 H×W), `normals_left` (float32 H×W×3), `instance_left`, `semantic_left` (uint16 H×W), the right view's alike, and the instance table as `instances`; `stereogen.torch` passes them on as tensors.
";
    if has("semantic") && !classes.is_empty() {
        *s += "
| class id | class |
|---:|---|
";
        for c in classes {
            let _ = writeln!(s, "| {} | {} |", c.id, c.name);
        }
    }
}
