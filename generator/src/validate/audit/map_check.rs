//! The per-pixel maps beside the disparity (depth, normals, instance, semantic; `stereo_io::maps`
//! states their files) against the audit's own ray cast, at the audited pixels of both views:
//!
//! - depth: the planar depth of the first hit, within [`DEPTH_RELATIVE`] relative;
//! - normals: the hit triangle's shading normal as Cycles makes it (corner normals interpolated
//!   on smooth triangles, the geometric normal on flat ones, turned to face the ray; see
//!   [`RayScene::shading_normal`]) in the camera's frame, within [`NORMAL_DEGREES`];
//! - instance and semantic: the hit object's spec position + 1 and its class, exactly. A class is
//!   compared by name: the spec object's class (`ObjectSpec::semantic_class`) against the name
//!   the dataset's own table (`dataset.json`'s `semantic_classes`) gives the pixel's id, so a
//!   dataset written with another class table is judged by the table it states.
//!
//! A map records no surface (0) exactly where ray casting sees background. **Silhouettes** are
//! recognised as for the disparity: the centre ray and four rays 0.02 px right, left, above and
//! below it do not all meet the same object (or all see background). Depth and normals also
//! count a grazing surface (disparity changing faster than 10 px per px) as a silhouette, since
//! there the renderer's float32 ray arithmetic alone moves the value past the bound. Silhouette
//! pixels are counted apart, and must match one of the five rays' surfaces ("disagree"
//! otherwise), but the bars apply to the others. A normal pixel on a **crease** (the five rays
//! meet one object, but normals more than 0.5° apart: a flat-shaded edge a renderer's ray may
//! fall on either side of, or a very tight curve) stays checked, against the nearest of the
//! five rays' normals; creases are counted too.

use std::path::Path;

use stereo_io::MapKind;
use stereo_io::datasets::MapData;
use stereo_io::datasets::stereogen::{SemanticClass, VIEWS};

use super::bvh::V3;
use super::raycast::{Hit, RayScene};
use super::tally::{DEPTH_RELATIVE, MapIssue, MapTally, NORMAL_DEGREES};
use crate::dataset::{DatasetLayout, ManifestEntry};
use crate::plan::rig::View;
use crate::plan::{SEMANTIC_CLASSES, SceneSpec};

/// Worst pixels kept per map and sample.
pub const WORST_PER_MAP: usize = 5;
/// Share of a map's bound above which a sound pixel's error enters the worst list.
const WORST_FLOOR: f64 = 0.1;

/// One tally per map, in [`MapKind::ALL`]'s order.
pub type MapTallies = [MapTally; 4];

/// Adds `b` to `a`, map by map.
pub fn merge_tallies(a: &mut MapTallies, b: &MapTallies) {
    for (x, y) in a.iter_mut().zip(b) {
        x.merge(y);
    }
}

/// A sample's maps and what ray casting expects of the ids.
#[derive(Debug, Default)]
pub struct SampleMaps {
    maps: stereo_io::datasets::SampleMaps,
    /// Per object of the worker's geometry: (instance id, class id) of the spec object of the
    /// same name; `None` for an object the spec does not name (then no id can match).
    ids: Vec<Option<(u16, u16)>>,
}

/// The rays of one audited pixel: the centre first, then the four around it, with their hits.
pub struct PixelRays<'a> {
    pub view: View,
    pub x: usize,
    pub y: usize,
    pub dirs: [V3; 5],
    pub hits: [Option<Hit>; 5],
    /// The disparity changes faster than the grazing limit around the pixel.
    pub steep: bool,
    pub sample: &'a str,
    pub category: &'a str,
}

/// Position of `kind` in [`MapTallies`].
pub fn slot(kind: MapKind) -> usize {
    MapKind::ALL
        .iter()
        .position(|k| *k == kind)
        .expect("every kind is in ALL")
}

fn view_name(view: View) -> &'static str {
    if view == View::Left { "left" } else { "right" }
}

fn size_problem(path: &Path, w: usize, h: usize, spec: &SceneSpec) -> Option<String> {
    ((w, h) != (spec.rig.width as usize, spec.rig.height as usize)).then(|| {
        format!(
            "{}: {w}x{h}, the spec says {}x{}",
            path.display(),
            spec.rig.width,
            spec.rig.height
        )
    })
}

impl SampleMaps {
    /// Reads the maps the manifest lists for `entry`; a map that cannot be read (or has the
    /// wrong size) is left out and named in the returned problems. `objects` are the names of
    /// the worker's geometry objects, in its order; `classes` the dataset's class table.
    pub fn read(
        layout: &DatasetLayout,
        entry: &ManifestEntry,
        spec: &SceneSpec,
        objects: &[&str],
        classes: &[SemanticClass],
    ) -> (Self, Vec<String>) {
        let mut out = Self::default();
        let mut problems = Vec::new();
        for view in VIEWS {
            for kind in MapKind::ALL {
                let Some(rel) = entry.files.map(kind, view) else {
                    continue;
                };
                let path = layout.abs(rel);
                // A map that cannot be read, or has the wrong size, is not compared.
                let read = MapData::read(kind, &path)
                    .map_err(|e| e.to_string())
                    .and_then(|m| {
                        let (w, h) = m.size();
                        match size_problem(&path, w, h, spec) {
                            Some(p) => Err(p),
                            None => out
                                .maps
                                .set(kind, view, m, &path)
                                .map_err(|e| e.to_string()),
                        }
                    });
                if let Err(p) = read {
                    problems.push(p);
                }
            }
        }
        // The id the dataset's table gives a class name (0, matching no pixel, when it has none).
        let class_id = |name: &str| classes.iter().find(|c| c.name == name).map_or(0, |c| c.id);
        out.ids = objects
            .iter()
            .map(|name| {
                let i = spec.objects.iter().position(|o| o.name == *name)?;
                let class = SEMANTIC_CLASSES[spec.objects[i].semantic_class() as usize - 1];
                Some((i as u16 + 1, class_id(class)))
            })
            .collect();
        if out.has(MapKind::Instance) || out.has(MapKind::Semantic) {
            for (name, id) in objects.iter().zip(&out.ids) {
                if id.is_none() {
                    problems.push(format!(
                        "the rebuilt scene has an object {name:?} the spec does not name, so its instance id is unknown"
                    ));
                }
            }
        }
        (out, problems)
    }

    /// Whether either view has map `kind`.
    pub fn has(&self, kind: MapKind) -> bool {
        self.maps.has(kind)
    }

    pub fn is_empty(&self) -> bool {
        self.maps.is_empty()
    }

    /// Checks every map of the pixel's view; adds to `tallies` and `issues`.
    pub fn check(
        &self,
        scene: &RayScene,
        px: &PixelRays,
        tallies: &mut MapTallies,
        issues: &mut Vec<MapIssue>,
    ) {
        let maps = self.maps.view(view_name(px.view));
        let objects = px.hits.map(|h| h.map(|h| h.object));
        let object_edge = objects.iter().any(|o| *o != objects[0]);
        let edge = object_edge || px.steep;
        let mut judge = |kind: MapKind, j: Judged| {
            let t = &mut tallies[slot(kind)];
            t.pixels += 1;
            match j.class {
                Class::Edge { matched } => {
                    t.silhouette += 1;
                    t.edge_disagree += u64::from(!matched);
                }
                Class::Checked { validity, error } => {
                    t.checked += 1;
                    t.crease += u64::from(j.crease);
                    t.validity_mismatch += u64::from(validity);
                    let ok = !validity && error <= j.bound;
                    t.in_bounds += u64::from(ok);
                    if !validity {
                        t.max_error = t.max_error.max(error);
                    }
                    // Errors above a tenth of the bound are candidates for the worst list, so
                    // it names the largest errors of a sound dataset too; the many smaller ones
                    // (float32 rounding) would only cost time, and `max_error` has the largest.
                    if !ok || error > WORST_FLOOR * j.bound {
                        issues.push(MapIssue {
                            map: kind.name().to_string(),
                            sample: px.sample.to_string(),
                            category: px.category.to_string(),
                            view: view_name(px.view).to_string(),
                            x: px.x,
                            y: px.y,
                            rendered: j.rendered,
                            expected: j.expected,
                            error: if validity { 1.0 } else { error },
                            out_of_bounds: !ok,
                        });
                    }
                }
            }
        };
        if let Some(m) = &maps.depth {
            let value = Some(f64::from(m.data[px.y * m.width + px.x])).filter(|d| *d > 0.0);
            let expect = px.hits.map(|h| h.map(|h| h.t));
            let relative = |a: f64, e: f64| (a - e).abs() / e;
            judge(
                MapKind::Depth,
                judged(
                    value.map(|v| vec![v]),
                    expect.map(|e| e.map(|e| vec![e])),
                    edge,
                    false,
                    DEPTH_RELATIVE,
                    |a, e| relative(a[0], e[0]),
                ),
            );
        }
        if let Some(m) = &maps.normals {
            let n = m.data[px.y * m.width + px.x].map(f64::from);
            let value = (n != [0.0; 3]).then(|| n.to_vec());
            let expect: [Option<Vec<f64>>; 5] = std::array::from_fn(|k| {
                px.hits[k].map(|h| camera_frame(scene.shading_normal(&h, px.dirs[k])).to_vec())
            });
            // One object under all five rays, yet normals more than the bound apart: a crease.
            let crease = !edge
                && expect[0].as_ref().is_some_and(|c| {
                    expect[1..]
                        .iter()
                        .flatten()
                        .any(|a| degrees(a, c) > NORMAL_DEGREES)
                });
            judge(
                MapKind::Normals,
                judged(value, expect, edge, crease, NORMAL_DEGREES, degrees),
            );
        }
        for (kind, map, pick) in [
            (MapKind::Instance, &maps.instance, 0usize),
            (MapKind::Semantic, &maps.semantic, 1),
        ] {
            let Some(m) = map else { continue };
            let value = Some(f64::from(m.data[px.y * m.width + px.x])).filter(|v| *v > 0.0);
            let expect = objects.map(|o| {
                o.map(|o| {
                    let id = self.ids.get(o).copied().flatten();
                    vec![id.map_or(0.0, |ids| f64::from([ids.0, ids.1][pick]))]
                })
            });
            // Ids: only a change of object makes an edge; a grazing surface is still one object.
            judge(
                kind,
                judged(
                    value.map(|v| vec![v]),
                    expect,
                    object_edge,
                    false,
                    0.0,
                    |a, e| f64::from(u8::from(a[0] != e[0])),
                ),
            );
        }
    }
}

/// Blender's world (x right, y up, z back) to the camera frame of the maps (x right, y down,
/// z forward): the rig's cameras are never rotated.
fn camera_frame(n: V3) -> V3 {
    [n[0], -n[1], -n[2]]
}

/// Angle in degrees between two directions (either length), by atan2: exact at small angles.
fn degrees(a: &[f64], b: &[f64]) -> f64 {
    let c = [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ];
    let cross = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
    let dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    cross.atan2(dot).to_degrees()
}

/// How one pixel of one map is judged.
enum Class {
    /// A silhouette pixel: `matched` when the value fits one of the five rays.
    Edge { matched: bool },
    /// A pixel the bar applies to.
    Checked { validity: bool, error: f64 },
}

struct Judged {
    class: Class,
    /// A checked pixel on a crease.
    crease: bool,
    bound: f64,
    rendered: Vec<f64>,
    expected: Vec<f64>,
}

/// Judges a map's `value` against the five rays' expectations (`None`: no surface): at an
/// `edge` (silhouette) against any of them, on a `crease` by the nearest, else the centre's.
fn judged(
    value: Option<Vec<f64>>,
    expect: [Option<Vec<f64>>; 5],
    edge: bool,
    crease: bool,
    bound: f64,
    error: impl Fn(&[f64], &[f64]) -> f64,
) -> Judged {
    let fits = |e: &Option<Vec<f64>>| match (&value, e) {
        (Some(v), Some(e)) => error(v, e) <= bound,
        (None, None) => true,
        _ => false,
    };
    let class = if edge {
        Class::Edge {
            matched: expect.iter().any(fits),
        }
    } else {
        match (&value, &expect[0]) {
            (Some(v), Some(e)) if crease => Class::Checked {
                validity: false,
                error: expect
                    .iter()
                    .flatten()
                    .map(|e| error(v, e))
                    .fold(f64::INFINITY, f64::min),
            },
            (Some(v), Some(e)) => Class::Checked {
                validity: false,
                error: error(v, e),
            },
            (None, None) => Class::Checked {
                validity: false,
                error: 0.0,
            },
            _ => Class::Checked {
                validity: true,
                error: 0.0,
            },
        }
    };
    let [centre, ..] = expect;
    Judged {
        crease: crease && !edge,
        class,
        bound,
        rendered: value.unwrap_or_default(),
        expected: centre.unwrap_or_default(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angles_are_exact_at_small_and_large_angles() {
        let a = [0.0, 0.0, 1.0];
        let tiny = 1e-7f64;
        assert!((degrees(&a, &[tiny.sin(), 0.0, tiny.cos()]) - tiny.to_degrees()).abs() < 1e-15);
        assert!((degrees(&a, &[0.0, 2.0, 0.0]) - 90.0).abs() < 1e-12);
        assert!((degrees(&a, &[0.0, 0.0, -1.0]) - 180.0).abs() < 1e-12);
    }

    #[test]
    fn edges_count_apart_and_match_any_ray() {
        let depth = |v: f64| Some(vec![v]);
        let rel = |a: &[f64], e: &[f64]| (a[0] - e[0]).abs() / e[0];
        let around = [depth(2.0), depth(2.0), depth(5.0), None, depth(2.0)];
        // At a silhouette the value may be either surface, or background.
        for v in [depth(2.0), depth(5.0), None] {
            let j = judged(v, around.clone(), true, false, 1e-4, rel);
            assert!(matches!(j.class, Class::Edge { matched: true, .. }));
        }
        let j = judged(depth(3.5), around.clone(), true, false, 1e-4, rel);
        assert!(matches!(j.class, Class::Edge { matched: false, .. }));
        // Inside a surface: the relative error, and validity.
        let inside = [depth(2.0), depth(2.0), depth(2.0), depth(2.0), depth(2.0)];
        match judged(depth(2.0002), inside.clone(), false, false, 1e-4, rel).class {
            Class::Checked { validity, error } => {
                assert!(!validity && (error - 1e-4).abs() < 1e-12)
            }
            _ => panic!("an interior pixel"),
        }
        assert!(matches!(
            judged(None, inside, false, false, 1e-4, rel).class,
            Class::Checked { validity: true, .. }
        ));
        // On a crease the nearest of the five rays counts, and the pixel stays checked.
        let crease = [depth(2.0), depth(2.0), depth(3.0), depth(2.0), depth(2.0)];
        let j = judged(depth(3.0), crease, false, true, 1e-4, rel);
        assert!(j.crease);
        assert!(matches!(j.class, Class::Checked { validity: false, error } if error == 0.0));
    }
}
