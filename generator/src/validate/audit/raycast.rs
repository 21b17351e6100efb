//! An independent ray caster in f64: triangles in world space, a [`Bvh`] over them, and the
//! ground-truth rules of the README. It shares nothing with the renderer but the geometry and the
//! rig's formulas.
//!
//! The rules: a camera ray stops at the **first surface** it meets, whatever its material (glass
//! is its front surface, a mirror the mirror), except where a surface is cut out by a mask (leaves:
//! an exact 0/1 disc in the quad's UV square), which the ray passes. Hits nearer than the camera's
//! clip start are not seen; a ray that meets nothing before the clip end sees the background.

use super::bvh::{Aabb, Bvh, V3};
use crate::plan::rig::View;
use crate::plan::{ObjectSpec, SceneSpec, Shape, StereoRig};

fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// A world-space triangle of object `object`. `cutout` indexes [`RayScene`]'s cut-out table
/// ([`NO_CUTOUT`]: the triangle is opaque everywhere).
#[derive(Debug, Clone, PartialEq)]
pub struct Triangle {
    pub v: [V3; 3],
    pub object: usize,
    pub cutout: u32,
}

impl Triangle {
    /// How far `p` lies from the triangle's plane; `None` for a degenerate triangle.
    pub fn plane_distance(&self, p: V3) -> Option<f64> {
        let n = normalise(cross(sub(self.v[1], self.v[0]), sub(self.v[2], self.v[0])))?;
        Some(dot(sub(p, self.v[0]), n).abs())
    }
}

/// [`Triangle::cutout`] of an opaque triangle.
pub const NO_CUTOUT: u32 = u32::MAX;

/// A mask that cuts a surface out: opaque inside the disc `(u - cu)² + (v - cv)² < r²` of the
/// surface's UV coordinates, transparent outside (Blender's leaf material, `LESS_THAN` node).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UvDisc {
    pub centre: [f64; 2],
    pub radius: f64,
}

/// A cut-out triangle: the UV of its corners and its mask.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CutoutUv {
    pub uv: [[f64; 2]; 3],
    pub mask: UvDisc,
}

impl CutoutUv {
    /// Whether the surface is there at barycentric coordinates (b1, b2) of corners 1 and 2.
    pub fn opaque_at(&self, b1: f64, b2: f64) -> bool {
        let b0 = 1.0 - b1 - b2;
        let at = |k: usize| b0 * self.uv[0][k] + b1 * self.uv[1][k] + b2 * self.uv[2][k];
        let (du, dv) = (at(0) - self.mask.centre[0], at(1) - self.mask.centre[1]);
        du * du + dv * dv < self.mask.radius * self.mask.radius
    }
}

/// What a ray met: the distance along its direction, the object, the triangle (index into
/// [`RayScene::triangles`]) and the barycentric coordinates of corners 1 and 2 there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    pub t: f64,
    pub object: usize,
    pub triangle: usize,
    pub bary: [f64; 2],
}

/// How Cycles shades one triangle: `smooth` interpolates the world-space unit `corners` normals,
/// otherwise the triangle's geometric normal is its normal. `mirrored`: the object's transform
/// mirrors, which turns the winding (and the geometric normal made from it) round.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShadingNormals {
    pub corners: [V3; 3],
    pub smooth: bool,
    pub mirrored: bool,
}

/// Triangles with their cut-outs and the hierarchy over them, and (from the worker's geometry)
/// their shading normals, one per triangle; without them every triangle is flat.
#[derive(Debug, Clone)]
pub struct RayScene {
    pub triangles: Vec<Triangle>,
    pub cutouts: Vec<CutoutUv>,
    pub shading: Vec<ShadingNormals>,
    bvh: Bvh,
}

fn normalise(a: V3) -> Option<V3> {
    let len = dot(a, a).sqrt();
    (len > 0.0 && len.is_finite()).then(|| a.map(|c| c / len))
}

/// Möller–Trumbore, two-sided: (t, b1, b2) of a hit with t in (t_min, t_max).
#[inline]
fn intersect(
    tri: &[V3; 3],
    origin: V3,
    dir: V3,
    t_min: f64,
    t_max: f64,
) -> Option<(f64, f64, f64)> {
    let e1 = sub(tri[1], tri[0]);
    let e2 = sub(tri[2], tri[0]);
    let p = cross(dir, e2);
    let det = dot(e1, p);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let inv = 1.0 / det;
    let s = sub(origin, tri[0]);
    let b1 = dot(s, p) * inv;
    if !(0.0..=1.0).contains(&b1) {
        return None;
    }
    let q = cross(s, e1);
    let b2 = dot(dir, q) * inv;
    if b2 < 0.0 || b1 + b2 > 1.0 {
        return None;
    }
    let t = dot(e2, q) * inv;
    (t > t_min && t < t_max).then_some((t, b1, b2))
}

impl RayScene {
    pub fn new(triangles: Vec<Triangle>, cutouts: Vec<CutoutUv>) -> Self {
        let boxes: Vec<Aabb> = triangles.iter().map(|t| Aabb::of_points(&t.v)).collect();
        Self {
            bvh: Bvh::build(&boxes),
            triangles,
            cutouts,
            shading: Vec::new(),
        }
    }

    /// The scene with shading normals, one per triangle.
    pub fn with_shading(mut self, shading: Vec<ShadingNormals>) -> Self {
        assert_eq!(
            shading.len(),
            self.triangles.len(),
            "one shading per triangle"
        );
        self.shading = shading;
        self
    }

    /// The unit shading normal Cycles records for `hit` of a ray along `dir` (world space): on a
    /// smooth triangle the corner normals interpolated at the hit and normalised, on a flat one
    /// the geometric normal; both turned round when the ray meets the triangle's back, which
    /// Cycles decides by the geometric normal (`shader_setup_from_ray`), so near a smooth
    /// triangle's silhouette the shading normal may still lean away from the camera.
    pub fn shading_normal(&self, hit: &Hit, dir: V3) -> V3 {
        let tri = &self.triangles[hit.triangle];
        let shading = self.shading.get(hit.triangle);
        let mut ng = cross(sub(tri.v[1], tri.v[0]), sub(tri.v[2], tri.v[0]));
        if shading.is_some_and(|s| s.mirrored) {
            ng = ng.map(|c| -c);
        }
        let ng = normalise(ng).unwrap_or([0.0, 0.0, 1.0]);
        let [b1, b2] = hit.bary;
        let n = match shading {
            Some(s) if s.smooth => {
                let w = [1.0 - b1 - b2, b1, b2];
                let c = &s.corners;
                normalise(std::array::from_fn(|i| {
                    w[0] * c[0][i] + w[1] * c[1][i] + w[2] * c[2][i]
                }))
                .unwrap_or(ng)
            }
            _ => ng,
        };
        if dot(ng, dir) > 0.0 { n.map(|c| -c) } else { n }
    }

    /// The first surface along `origin + t·dir` with t in (t_min, t_max), passing cut-outs.
    pub fn first_hit(&self, origin: V3, dir: V3, t_min: f64, t_max: f64) -> Option<Hit> {
        self.bvh
            .nearest(origin, dir, t_min, t_max, |p, limit| {
                let tri = &self.triangles[p];
                let (t, b1, b2) = intersect(&tri.v, origin, dir, t_min, limit)?;
                if tri.cutout != NO_CUTOUT && !self.cutouts[tri.cutout as usize].opaque_at(b1, b2) {
                    return None;
                }
                Some(t)
            })
            .map(|(t, p)| {
                // The winner's barycentrics: the same arithmetic as the test that chose it.
                let (_, b1, b2) =
                    intersect(&self.triangles[p].v, origin, dir, t_min, f64::INFINITY)
                        .expect("the nearest triangle is hit");
                Hit {
                    t,
                    object: self.triangles[p].object,
                    triangle: p,
                    bary: [b1, b2],
                }
            })
    }
}

/// Blender's XYZ Euler: rotate about X, then Y, then Z (R = Rz·Ry·Rx).
fn rotate_xyz(p: V3, r: V3) -> V3 {
    let (sx, cx) = r[0].sin_cos();
    let (sy, cy) = r[1].sin_cos();
    let (sz, cz) = r[2].sin_cos();
    let p = [p[0], cx * p[1] - sx * p[2], sx * p[1] + cx * p[2]];
    let p = [cy * p[0] + sy * p[2], p[1], -sy * p[0] + cy * p[2]];
    [cz * p[0] - sz * p[1], sz * p[0] + cz * p[1], p[2]]
}

fn to_world(o: &ObjectSpec, p: V3) -> V3 {
    let s = [p[0] * o.scale[0], p[1] * o.scale[1], p[2] * o.scale[2]];
    let r = rotate_xyz(s, o.rotation);
    [
        r[0] + o.location[0],
        r[1] + o.location[1],
        r[2] + o.location[2],
    ]
}

/// Object-space triangles of the shapes whose geometry a SceneSpec states exactly (planes and
/// explicit meshes); `None` for shapes Blender builds (primitives, files, trees).
fn spec_triangles(shape: &Shape) -> Option<Vec<[V3; 3]>> {
    match shape {
        Shape::Plane => {
            let q = [
                [-1.0, -1.0, 0.0],
                [1.0, -1.0, 0.0],
                [1.0, 1.0, 0.0],
                [-1.0, 1.0, 0.0],
            ];
            Some(vec![[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        }
        Shape::Mesh {
            vertices,
            triangles,
        } => Some(
            triangles
                .iter()
                .map(|t| {
                    [
                        vertices[t[0] as usize],
                        vertices[t[1] as usize],
                        vertices[t[2] as usize],
                    ]
                })
                .collect(),
        ),
        _ => None,
    }
}

/// The scene of a spec whose objects are all planes or explicit meshes without modifiers (the
/// analytic test scenes), built from the spec alone. Panics on any other object: a generated
/// scene's geometry comes from the worker ([`super::geometry`]).
pub fn scene_triangles(spec: &SceneSpec) -> RayScene {
    let mut out = Vec::new();
    for (i, o) in spec.objects.iter().enumerate() {
        assert!(
            o.modifiers.is_empty(),
            "{}: modifiers need Blender's evaluated geometry",
            o.name
        );
        let local = spec_triangles(&o.shape).unwrap_or_else(|| {
            panic!(
                "{}: the spec does not state the triangles of {:?}",
                o.name, o.shape
            )
        });
        out.extend(local.into_iter().map(|t| Triangle {
            v: t.map(|p| to_world(o, p)),
            object: i,
            cutout: NO_CUTOUT,
        }));
    }
    RayScene::new(out, Vec::new())
}

/// Ground truth for pixel position (u, v) of a view: (disparity, object), `None` for background.
/// The ray direction has z = −1, so the hit distance is the planar depth itself.
pub fn disparity_at(
    rig: &StereoRig,
    scene: &RayScene,
    view: View,
    u: f64,
    v: f64,
) -> Option<(f64, usize)> {
    let origin = [rig.camera_x(view), 0.0, 0.0];
    scene
        .first_hit(origin, rig.ray_direction(u, v), 1e-9, f64::INFINITY)
        .map(|h| (rig.disparity_at_depth(h.t), h.object))
}

/// Whether the point seen by the left pixel (u, v) at disparity `d` is visible from the right camera.
pub fn visible_in_right(rig: &StereoRig, scene: &RayScene, u: f64, v: f64, d: f64) -> bool {
    let z = rig.depth_for_disparity(d);
    visible_from(rig, scene, View::Right, rig.unproject_left(u, v, z))
}

/// Whether nothing opaque lies between the camera of `view` and the point `p`.
pub fn visible_from(rig: &StereoRig, scene: &RayScene, view: View, p: V3) -> bool {
    let origin = [rig.camera_x(view), 0.0, 0.0];
    scene
        .first_hit(origin, sub(p, origin), 1e-9, 1.0 - 1e-7)
        .is_none()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_matches_blender_xyz_order() {
        // 90° about X takes +Y to +Z; then 90° about Z takes +X to +Y.
        let p = rotate_xyz([0.0, 1.0, 0.0], [std::f64::consts::FRAC_PI_2, 0.0, 0.0]);
        assert!((p[2] - 1.0).abs() < 1e-12);
        let q = rotate_xyz(
            [1.0, 0.0, 0.0],
            [
                std::f64::consts::FRAC_PI_2,
                0.0,
                std::f64::consts::FRAC_PI_2,
            ],
        );
        assert!((q[1] - 1.0).abs() < 1e-12);
    }

    fn quad(z: f64, half: f64, object: usize, cutout: u32) -> [Triangle; 2] {
        let q = [
            [-half, -half, z],
            [half, -half, z],
            [half, half, z],
            [-half, half, z],
        ];
        [
            Triangle {
                v: [q[0], q[1], q[2]],
                object,
                cutout,
            },
            Triangle {
                v: [q[0], q[2], q[3]],
                object,
                cutout,
            },
        ]
    }

    #[test]
    fn cut_outs_let_the_ray_through_to_the_next_surface() {
        // A leaf quad at z = -1 (UV square over [-1, 1]²) in front of a wall at z = -3.
        let uv = |t: &Triangle| t.v.map(|p| [(p[0] + 1.0) / 2.0, (p[1] + 1.0) / 2.0]);
        let mask = UvDisc {
            centre: [0.5, 0.5],
            radius: 0.5,
        };
        let leaf = quad(-1.0, 1.0, 1, 0);
        let cutouts = vec![
            CutoutUv {
                uv: uv(&leaf[0]),
                mask,
            },
            CutoutUv {
                uv: uv(&leaf[1]),
                mask,
            },
        ];
        let leaf = [
            Triangle {
                cutout: 0,
                ..leaf[0].clone()
            },
            Triangle {
                cutout: 1,
                ..leaf[1].clone()
            },
        ];
        let mut tris = quad(-3.0, 10.0, 0, NO_CUTOUT).to_vec();
        tris.extend(leaf);
        let scene = RayScene::new(tris, cutouts);
        let at = |x: f64, y: f64| {
            scene
                .first_hit([0.0; 3], [x, y, -1.0], 1e-9, f64::INFINITY)
                .map(|h| (h.t, h.object))
        };
        assert_eq!(at(0.0, 0.0), Some((1.0, 1)), "the disc's centre is leaf");
        // UV (0.8, 0.8): 0.3² + 0.3² < 0.5², inside the disc.
        assert_eq!(at(0.6, 0.6), Some((1.0, 1)));
        // UV (0.95, 0.95): outside the disc but on the quad, cut out: the wall at t = 3.
        assert_eq!(at(0.9, 0.9), Some((3.0, 0)));
        // Clip: a leaf nearer than t_min is not seen.
        assert_eq!(
            scene
                .first_hit([0.0; 3], [0.0, 0.0, -1.0], 1.5, f64::INFINITY)
                .map(|h| h.object),
            Some(0)
        );
        assert_eq!(scene.first_hit([0.0; 3], [0.0, 0.0, -1.0], 1e-9, 0.5), None);
    }
}
