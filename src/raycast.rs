//! An independent ray caster over the triangles of a SceneSpec, in f64, to check the disparity
//! Blender writes. It shares nothing with the renderer but the spec and the rig formulas.

use stereogen::plan::rig::View;
use stereogen::plan::{ObjectSpec, SceneSpec, Shape, StereoRig};

type V3 = [f64; 3];

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

/// Blender's XYZ Euler: rotate about X, then Y, then Z (R = Rz·Ry·Rx).
fn rotate_xyz(p: V3, r: V3) -> V3 {
    let (sx, cx) = r[0].sin_cos();
    let (sy, cy) = r[1].sin_cos();
    let (sz, cz) = r[2].sin_cos();
    let p = [p[0], cx * p[1] - sx * p[2], sx * p[1] + cx * p[2]];
    let p = [cy * p[0] + sy * p[2], p[1], -sy * p[0] + cy * p[2]];
    [cz * p[0] - sz * p[1], sz * p[0] + cz * p[1], p[2]]
}

/// Object-space triangles of the shapes the analytic scenes use.
fn local_triangles(shape: &Shape) -> Vec<[V3; 3]> {
    match shape {
        Shape::Plane => {
            let q = [
                [-1.0, -1.0, 0.0],
                [1.0, -1.0, 0.0],
                [1.0, 1.0, 0.0],
                [-1.0, 1.0, 0.0],
            ];
            vec![[q[0], q[1], q[2]], [q[0], q[2], q[3]]]
        }
        Shape::Mesh {
            vertices,
            triangles,
        } => triangles
            .iter()
            .map(|t| {
                [
                    vertices[t[0] as usize],
                    vertices[t[1] as usize],
                    vertices[t[2] as usize],
                ]
            })
            .collect(),
        other => panic!("the test ray caster does not model {other:?}"),
    }
}

pub struct Triangle {
    pub v: [V3; 3],
    pub object: usize,
}

/// World-space triangles of a scene.
pub fn scene_triangles(spec: &SceneSpec) -> Vec<Triangle> {
    let mut out = Vec::new();
    for (i, o) in spec.objects.iter().enumerate() {
        for t in local_triangles(&o.shape) {
            out.push(Triangle {
                v: t.map(|p| to_world(o, p)),
                object: i,
            });
        }
    }
    out
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

/// Nearest hit along `origin + t·dir` (t > 0): (t, object index). Möller–Trumbore, two-sided.
pub fn cast(tris: &[Triangle], origin: V3, dir: V3) -> Option<(f64, usize)> {
    let mut best: Option<(f64, usize)> = None;
    for tri in tris {
        let e1 = sub(tri.v[1], tri.v[0]);
        let e2 = sub(tri.v[2], tri.v[0]);
        let p = cross(dir, e2);
        let det = dot(e1, p);
        if det.abs() < 1e-14 {
            continue;
        }
        let inv = 1.0 / det;
        let s = sub(origin, tri.v[0]);
        let u = dot(s, p) * inv;
        if !(0.0..=1.0).contains(&u) {
            continue;
        }
        let q = cross(s, e1);
        let v = dot(dir, q) * inv;
        if v < 0.0 || u + v > 1.0 {
            continue;
        }
        let t = dot(e2, q) * inv;
        if t > 1e-9 && best.is_none_or(|(bt, _)| t < bt) {
            best = Some((t, tri.object));
        }
    }
    best
}

/// Ground truth for pixel position (u, v) of a view: (disparity, object) or None for background.
/// The ray direction has z = −1, so the hit parameter t is the planar depth itself.
pub fn disparity_at(
    rig: &StereoRig,
    tris: &[Triangle],
    view: View,
    u: f64,
    v: f64,
) -> Option<(f64, usize)> {
    let origin = [rig.camera_x(view), 0.0, 0.0];
    cast(tris, origin, rig.ray_direction(u, v)).map(|(z, obj)| (rig.disparity_at_depth(z), obj))
}

/// Whether the 3-D point seen by the left pixel (u, v) at disparity `d` is visible from the right camera.
pub fn visible_in_right(rig: &StereoRig, tris: &[Triangle], u: f64, v: f64, d: f64) -> bool {
    let z = rig.depth_for_disparity(d);
    let p = rig.unproject_left(u, v, z);
    let origin = [rig.camera_x(View::Right), 0.0, 0.0];
    let dir = sub(p, origin);
    match cast(tris, origin, dir) {
        Some((t, _)) => t > 1.0 - 1e-7,
        None => true,
    }
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
}
