//! The geometry a scene spec asks Blender to build, bounded before Blender starts: a hand-written
//! or hostile spec (`stereogen render --spec`) could otherwise ask for a sphere of four billion
//! segments, eight subdivision levels or a mesh whose triangles name vertices it lacks, and the
//! worker would run out of memory or time instead of the command failing with a message. The
//! caps sit far above anything the planner makes (its largest primitive is a 48×16 torus, its
//! deepest subdivision 3 levels, its thickest tube 8 sides), so every planned spec passes.

use super::{Check, Rule};
use crate::spec::{Modifier, ObjectSpec, SceneSpec, Shape};

/// Objects in one scene: a recipe category allows 2000 content objects, plus the background.
pub const MAX_OBJECTS: u64 = 4096;
/// Lights in one scene (a recipe allows 64).
pub const MAX_LIGHTS: u64 = 64;
/// Any one segment, ring, vertex or side count of a built-in shape.
pub const MAX_SHAPE_COUNT: u64 = 1024;
/// Ico-sphere subdivisions (each multiplies the faces by 4).
pub const MAX_ICO_SUBDIVISIONS: u64 = 8;
/// Levels of a subdivision modifier (each multiplies the faces by 4).
pub const MAX_SUBDIVIDE_LEVELS: u64 = 4;
/// Triangles Blender builds for one object (mesh files count with what they hold, which the
/// worker checks against their `max_triangles` when it imports them).
pub const MAX_OBJECT_TRIANGLES: f64 = 16e6;
/// Triangles Blender builds for the whole scene, mesh files left out as above.
pub const MAX_SCENE_TRIANGLES: f64 = 64e6;
/// The largest `max_triangles` a spec may give a mesh file (the recipe's own cap).
pub const MAX_MESH_FILE_TRIANGLES: u64 = 100_000_000;

/// The rows of the geometry check: counts, then each object's shape, then the scene's total.
pub fn geometry_checks(spec: &SceneSpec) -> Vec<Check<'static>> {
    let count = |key: &'static str, n: usize, hi: u64| {
        Check::new(
            key,
            Rule::Int {
                value: n as u64,
                lo: 0,
                hi,
            },
        )
    };
    let mut rows = vec![
        count("objects", spec.objects.len(), MAX_OBJECTS),
        count("lights", spec.lights.len(), MAX_LIGHTS),
    ];
    let mut total = 0.0;
    for (i, o) in spec.objects.iter().enumerate() {
        let (holds, need) = match object_triangles(o) {
            Ok(t) if t <= MAX_OBJECT_TRIANGLES => {
                total += t;
                (true, String::new())
            }
            Ok(t) => (
                false,
                format!(
                    "need at most {MAX_OBJECT_TRIANGLES:e} triangles an object, this shape makes {t:e}"
                ),
            ),
            Err(why) => (false, why),
        };
        rows.push(Check::new(
            format!("objects[{i}].shape"),
            Rule::Holds { holds, need },
        ));
    }
    rows.push(Check::new(
        "objects",
        Rule::Holds {
            holds: total <= MAX_SCENE_TRIANGLES,
            need: format!(
                "need at most {MAX_SCENE_TRIANGLES:e} triangles in the scene, its objects make {total:e}"
            ),
        },
    ));
    rows
}

/// The triangles Blender builds for `o` (estimated from the counts, as `f64` so no count can
/// overflow), or why its shape cannot be built.
fn object_triangles(o: &ObjectSpec) -> Result<f64, String> {
    let count = |what: &str, n: u32| {
        if (1..=MAX_SHAPE_COUNT).contains(&u64::from(n)) {
            Ok(f64::from(n))
        } else {
            Err(format!("need {what} in 1..={MAX_SHAPE_COUNT}, got {n}"))
        }
    };
    let base = match &o.shape {
        Shape::Plane => 2.0,
        Shape::Cube => 12.0,
        Shape::Monkey => 968.0,
        Shape::UvSphere { segments, rings } => {
            2.0 * count("segments", *segments)? * count("rings", *rings)?
        }
        Shape::IcoSphere { subdivisions } => {
            if u64::from(*subdivisions) > MAX_ICO_SUBDIVISIONS {
                return Err(format!(
                    "need subdivisions in 0..={MAX_ICO_SUBDIVISIONS}, got {subdivisions}"
                ));
            }
            20.0 * 4f64.powi(*subdivisions as i32)
        }
        Shape::Cylinder { vertices } | Shape::Cone { vertices, .. } => {
            4.0 * count("vertices", *vertices)?
        }
        Shape::Torus {
            major_segments,
            minor_segments,
            ..
        } => {
            2.0 * count("major_segments", *major_segments)?
                * count("minor_segments", *minor_segments)?
        }
        Shape::Grid {
            x_segments,
            y_segments,
        } => 2.0 * count("x_segments", *x_segments)? * count("y_segments", *y_segments)?,
        Shape::Mesh {
            vertices,
            triangles,
        } => {
            let n = vertices.len();
            if let Some(t) = triangles
                .iter()
                .find(|t| t.iter().any(|&v| v as usize >= n))
            {
                return Err(format!(
                    "a triangle {t:?} names a vertex the mesh lacks (it has {n})"
                ));
            }
            triangles.len() as f64
        }
        Shape::MeshFile {
            candidates,
            max_triangles,
        } => {
            if candidates.is_empty()
                || *max_triangles == 0
                || *max_triangles > MAX_MESH_FILE_TRIANGLES
            {
                return Err(format!(
                    "need one candidate or more and max_triangles in 1..={MAX_MESH_FILE_TRIANGLES}, got {} and {max_triangles}",
                    candidates.len()
                ));
            }
            0.0
        }
        Shape::Skeleton {
            strands,
            strand_levels,
            sides,
            leaves,
            ..
        } => {
            let sides = count("sides", *sides)?;
            if !strand_levels.is_empty() && strand_levels.len() != strands.len() {
                return Err(format!(
                    "need a level for each of the {} strands or none, got {}",
                    strands.len(),
                    strand_levels.len()
                ));
            }
            if let Some(s) = strands
                .iter()
                .find(|s| s.points.len() < 2 || s.points.len() != s.radii.len())
            {
                return Err(format!(
                    "need two points or more per strand and a radius for each, got {} points and {} radii",
                    s.points.len(),
                    s.radii.len()
                ));
            }
            let rings: f64 = strands.iter().map(|s| s.points.len() as f64).sum();
            2.0 * rings * sides + 2.0 * leaves.len() as f64
        }
    };
    let mut factor = 1.0;
    for m in &o.modifiers {
        if let Modifier::Subdivide { levels } = m {
            if u64::from(*levels) > MAX_SUBDIVIDE_LEVELS {
                return Err(format!(
                    "need subdivision levels in 0..={MAX_SUBDIVIDE_LEVELS}, got {levels}"
                ));
            }
            factor *= 4f64.powi(*levels as i32);
        }
    }
    Ok(base * factor)
}
