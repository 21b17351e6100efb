//! A Weber–Penn style tree generator (the model behind Blender's Sapling add-on, which bpy 4.5
//! does not ship). Every random decision happens here, in Rust; Blender only turns the strands
//! and leaves into tubes and alpha-cut quads.
//!
//! A trunk grows up from the base; each branch level spawns children along its parent at a
//! down angle, spiralling around it by roughly the golden angle; branches curve as they grow and
//! taper; leaves hang on the last level. The result is normalised to the unit sphere with the
//! base at the bottom.

use std::f64::consts::PI;

use rand::Rng;

use super::recipe::TreeRecipe;
use super::spec::{Leaf, Strand};

type V3 = [f64; 3];

fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn mul(a: V3, s: f64) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
fn norm(a: V3) -> V3 {
    let l = dot(a, a).sqrt();
    if l > 0.0 {
        mul(a, 1.0 / l)
    } else {
        [0.0, 0.0, 1.0]
    }
}
/// Rodrigues rotation of `v` about unit `axis` by `angle`.
fn rotate(v: V3, axis: V3, angle: f64) -> V3 {
    let (s, c) = angle.sin_cos();
    add(
        add(mul(v, c), mul(cross(axis, v), s)),
        mul(axis, dot(axis, v) * (1.0 - c)),
    )
}
/// Some unit vector perpendicular to `d`.
fn perpendicular(d: V3) -> V3 {
    let helper = if d[2].abs() < 0.9 {
        [0.0, 0.0, 1.0]
    } else {
        [1.0, 0.0, 0.0]
    };
    norm(cross(d, helper))
}

/// Weber–Penn parameters of one tree, drawn from the recipe.
#[derive(Debug, Clone, PartialEq)]
pub struct TreeParams {
    pub levels: u32,
    pub branches: u32,
    pub length_ratio: f64,
    pub down_angle: f64,
    pub curve: f64,
    pub trunk_radius: f64,
    pub leaves_per_branch: u32,
    pub leaf_size: f64,
    /// Segments per branch polyline.
    pub segments: u32,
}

impl TreeParams {
    pub fn draw<R: Rng>(rng: &mut R, t: &TreeRecipe) -> Self {
        Self {
            levels: t.levels.sample(rng),
            branches: t.branches.sample(rng),
            length_ratio: t.length_ratio.sample(rng),
            down_angle: t.down_angle_deg.sample(rng).to_radians(),
            curve: t.curve_deg.sample(rng).to_radians(),
            trunk_radius: t.trunk_radius.sample(rng),
            leaves_per_branch: t.leaves_per_branch.sample(rng),
            leaf_size: t.leaf_size.sample(rng),
            segments: 6,
        }
    }
}

/// The grown tree: branch strands (level 0 = trunk) and leaves, in the unit sphere.
#[derive(Debug, Clone, PartialEq)]
pub struct Tree {
    pub strands: Vec<Strand>,
    pub strand_levels: Vec<u32>,
    pub leaves: Vec<Leaf>,
}

struct Branch {
    points: Vec<V3>,
    radii: Vec<f64>,
    level: u32,
}

/// Upper bound on branches, so no parameter draw can explode the geometry.
const MAX_BRANCHES: usize = 1500;

/// Where a branch starts growing: its base, direction, length, base radius and level.
struct Sprout {
    start: V3,
    dir: V3,
    length: f64,
    radius: f64,
    level: u32,
}

fn grow_branch<R: Rng>(rng: &mut R, sprout: Sprout, curve: f64, segments: u32) -> Branch {
    let Sprout {
        start,
        dir,
        length,
        radius: r0,
        level,
    } = sprout;
    let bend_axis = perpendicular(dir);
    let step = length / f64::from(segments);
    let mut points = vec![start];
    let mut radii = vec![r0];
    let mut d = dir;
    for i in 1..=segments {
        // Curve accumulates along the branch, with a little jitter per segment.
        let jitter = rng.random_range(-0.15..0.15);
        d = norm(rotate(d, bend_axis, curve / f64::from(segments) + jitter));
        let p = add(*points.last().unwrap(), mul(d, step));
        points.push(p);
        radii.push(r0 * (1.0 - 0.7 * f64::from(i) / f64::from(segments)));
    }
    Branch {
        points,
        radii,
        level,
    }
}

/// Point and direction at fraction `t` along a polyline.
fn along(b: &Branch, t: f64) -> (V3, V3, f64) {
    let n = b.points.len() - 1;
    let x = t.clamp(0.0, 1.0) * n as f64;
    let i = (x.floor() as usize).min(n - 1);
    let f = x - i as f64;
    let p = add(b.points[i], mul(sub(b.points[i + 1], b.points[i]), f));
    let r = b.radii[i] + (b.radii[i + 1] - b.radii[i]) * f;
    (p, norm(sub(b.points[i + 1], b.points[i])), r)
}

pub fn grow<R: Rng>(p: &TreeParams, rng: &mut R) -> Tree {
    let trunk_len = 2.0;
    let lean = [
        rng.random_range(-0.08..0.08),
        rng.random_range(-0.08..0.08),
        1.0,
    ];
    let trunk = Sprout {
        start: [0.0, 0.0, 0.0],
        dir: lean,
        length: trunk_len,
        radius: p.trunk_radius * trunk_len,
        level: 0,
    };
    let trunk = grow_branch(rng, trunk, p.curve * 0.3, p.segments);
    let mut all = vec![trunk];
    let mut frontier = vec![0usize];
    for level in 1..=p.levels {
        let mut next = Vec::new();
        let count = if level == 1 {
            p.branches
        } else {
            ((f64::from(p.branches) * 0.6).round() as u32).max(1)
        };
        for &parent in &frontier {
            let parent_len: f64 = all[parent]
                .points
                .windows(2)
                .map(|w| dot(sub(w[1], w[0]), sub(w[1], w[0])).sqrt())
                .sum();
            let mut phase = rng.random_range(0.0..2.0 * PI);
            for k in 0..count {
                if all.len() >= MAX_BRANCHES {
                    break;
                }
                // Trunk children start a third of the way up; later levels anywhere past the base.
                let lo = if level == 1 { 0.3 } else { 0.15 };
                let t = lo
                    + (1.0 - lo) * (f64::from(k) + rng.random_range(0.0..1.0)) / f64::from(count);
                let (at, pdir, pr) = along(&all[parent], t);
                phase += 137.5f64.to_radians() + rng.random_range(-0.3..0.3);
                let side = rotate(perpendicular(pdir), pdir, phase);
                let down = p.down_angle + rng.random_range(-0.2..0.2);
                let dir = norm(add(mul(pdir, down.cos()), mul(side, down.sin())));
                // Weber–Penn's conical shape: children near the top are shorter.
                let length =
                    parent_len * p.length_ratio * (1.0 - 0.55 * t) * rng.random_range(0.8..1.2);
                let sprout = Sprout {
                    start: at,
                    dir,
                    length,
                    radius: pr * 0.6,
                    level,
                };
                let child = grow_branch(
                    rng,
                    sprout,
                    p.curve,
                    p.segments.saturating_sub(level).max(3),
                );
                all.push(child);
                next.push(all.len() - 1);
            }
        }
        frontier = next;
    }

    let mut leaves = Vec::new();
    for &b in &frontier {
        for _ in 0..p.leaves_per_branch {
            let (at, _, _) = along(&all[b], rng.random_range(0.2..1.0));
            let size = p.leaf_size * trunk_len;
            let normal = norm([
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            ]);
            let v = norm(cross(normal, perpendicular(normal)));
            let v = rotate(v, normal, rng.random_range(0.0..2.0 * PI));
            let u = norm(cross(normal, v));
            // The leaf hangs off the twig: its base touches the branch.
            let center = add(at, mul(v, size * 0.5));
            leaves.push(Leaf {
                center,
                u: mul(u, size * 0.25),
                v: mul(v, size * 0.5),
            });
        }
    }

    // Normalise: centre of the bounding box at the origin, farthest point at radius 1.
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    let mut extend = |q: V3| {
        for i in 0..3 {
            lo[i] = lo[i].min(q[i]);
            hi[i] = hi[i].max(q[i]);
        }
    };
    all.iter()
        .flat_map(|b| b.points.iter())
        .for_each(|&q| extend(q));
    leaves.iter().for_each(|l| extend(add(l.center, l.v)));
    let centre = mul(add(lo, hi), 0.5);
    let radius = all
        .iter()
        .flat_map(|b| b.points.iter().copied())
        .chain(leaves.iter().flat_map(|l| {
            [
                add(l.center, l.v),
                sub(l.center, l.v),
                add(l.center, l.u),
                sub(l.center, l.u),
            ]
        }))
        .map(|q| dot(sub(q, centre), sub(q, centre)).sqrt())
        .fold(1e-9, f64::max);
    let s = 1.0 / radius;
    let fit = |q: V3| mul(sub(q, centre), s);
    Tree {
        strand_levels: all.iter().map(|b| b.level).collect(),
        strands: all
            .iter()
            .map(|b| Strand {
                points: b.points.iter().map(|&q| fit(q)).collect(),
                radii: b.radii.iter().map(|r| r * s).collect(),
            })
            .collect(),
        leaves: leaves
            .iter()
            .map(|l| Leaf {
                center: fit(l.center),
                u: mul(l.u, s),
                v: mul(l.v, s),
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn params(levels: u32) -> TreeParams {
        TreeParams {
            levels,
            branches: 6,
            length_ratio: 0.5,
            down_angle: 0.8,
            curve: 0.3,
            trunk_radius: 0.03,
            leaves_per_branch: 5,
            leaf_size: 0.05,
            segments: 6,
        }
    }

    #[test]
    fn trees_have_the_requested_levels_and_leaves_and_fit_the_unit_sphere() {
        for levels in 1..=3 {
            let tree = grow(
                &params(levels),
                &mut rand_chacha::ChaCha8Rng::seed_from_u64(levels.into()),
            );
            assert_eq!(*tree.strand_levels.iter().max().unwrap(), levels);
            let last = tree.strand_levels.iter().filter(|&&l| l == levels).count();
            assert_eq!(tree.leaves.len(), last * 5);
            for q in tree.strands.iter().flat_map(|s| s.points.iter()) {
                assert!(dot(*q, *q).sqrt() <= 1.0 + 1e-9);
            }
            assert!(
                tree.strands
                    .iter()
                    .all(|s| s.points.len() == s.radii.len() && s.radii.iter().all(|r| *r > 0.0))
            );
        }
    }

    #[test]
    fn growth_is_deterministic() {
        let a = grow(&params(3), &mut rand_chacha::ChaCha8Rng::seed_from_u64(9));
        let b = grow(&params(3), &mut rand_chacha::ChaCha8Rng::seed_from_u64(9));
        assert_eq!(a, b);
    }
}
