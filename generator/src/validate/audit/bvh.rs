//! A bounding volume hierarchy over axis-aligned boxes, in f64: what makes casting millions of
//! rays through scenes of a million triangles affordable. It knows boxes, not triangles; the
//! caller tests the primitives of the leaves a ray reaches ([`Bvh::nearest`]).

pub type V3 = [f64; 3];

/// Primitives per leaf, at most.
const LEAF_SIZE: usize = 4;

/// An axis-aligned box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    pub lo: V3,
    pub hi: V3,
}

impl Aabb {
    pub const EMPTY: Aabb = Aabb {
        lo: [f64::INFINITY; 3],
        hi: [f64::NEG_INFINITY; 3],
    };

    pub fn of_points(points: &[V3]) -> Self {
        points.iter().fold(Self::EMPTY, |b, p| b.grow(*p))
    }

    pub fn grow(self, p: V3) -> Self {
        Aabb {
            lo: std::array::from_fn(|i| self.lo[i].min(p[i])),
            hi: std::array::from_fn(|i| self.hi[i].max(p[i])),
        }
    }

    pub fn union(self, o: Aabb) -> Self {
        Aabb {
            lo: std::array::from_fn(|i| self.lo[i].min(o.lo[i])),
            hi: std::array::from_fn(|i| self.hi[i].max(o.hi[i])),
        }
    }

    fn centre(&self) -> V3 {
        std::array::from_fn(|i| 0.5 * (self.lo[i] + self.hi[i]))
    }

    fn longest_axis(&self) -> usize {
        let e: V3 = std::array::from_fn(|i| self.hi[i] - self.lo[i]);
        if e[0] >= e[1] && e[0] >= e[2] {
            0
        } else if e[1] >= e[2] {
            1
        } else {
            2
        }
    }

    /// Entry distance of the ray into the box, if it meets it within `(t_min, t_max)`. The box is
    /// widened by a relative 1e-12 so that rays along a face of a flat box (a wall) still enter.
    #[inline]
    fn entry(&self, origin: V3, inv_dir: V3, t_min: f64, t_max: f64) -> Option<f64> {
        let (mut t0, mut t1) = (t_min, t_max);
        for i in 0..3 {
            let pad = 1e-12 * (self.hi[i] - self.lo[i]).abs().max(1.0);
            let a = (self.lo[i] - pad - origin[i]) * inv_dir[i];
            let b = (self.hi[i] + pad - origin[i]) * inv_dir[i];
            let (near, far) = if a <= b { (a, b) } else { (b, a) };
            // NaN (0 · inf for a ray in the slab's plane) keeps the current bounds.
            if near > t0 {
                t0 = near;
            }
            if far < t1 {
                t1 = far;
            }
            if t0 > t1 {
                return None;
            }
        }
        Some(t0)
    }
}

#[derive(Debug, Clone)]
struct Node {
    bounds: Aabb,
    /// Leaf: first index into `order`; inner node: index of the second child (the first follows).
    first: u32,
    /// Primitives of a leaf; 0 for an inner node.
    count: u32,
}

/// The hierarchy: nodes in depth-first order and the primitive order its leaves index.
#[derive(Debug, Clone)]
pub struct Bvh {
    nodes: Vec<Node>,
    order: Vec<u32>,
}

impl Bvh {
    /// Builds over the boxes of the primitives (median split of centroids on the longest axis).
    pub fn build(boxes: &[Aabb]) -> Self {
        let mut order: Vec<u32> = (0..boxes.len() as u32).collect();
        let centres: Vec<V3> = boxes.iter().map(Aabb::centre).collect();
        let mut nodes = Vec::with_capacity(2 * boxes.len() / LEAF_SIZE + 1);
        if !boxes.is_empty() {
            build_node(&mut nodes, &mut order, 0, boxes, &centres);
        }
        Self { nodes, order }
    }

    /// The nearest primitive the ray accepts: `test(primitive, t_max)` returns the hit distance
    /// of a primitive the ray meets (and that counts as a hit) nearer than `t_max`.
    pub fn nearest(
        &self,
        origin: V3,
        dir: V3,
        t_min: f64,
        t_max: f64,
        mut test: impl FnMut(usize, f64) -> Option<f64>,
    ) -> Option<(f64, usize)> {
        if self.nodes.is_empty() {
            return None;
        }
        let inv_dir: V3 = std::array::from_fn(|i| 1.0 / dir[i]);
        let mut best: Option<(f64, usize)> = None;
        let mut limit = t_max;
        let mut stack: Vec<u32> = Vec::with_capacity(64);
        stack.push(0);
        while let Some(i) = stack.pop() {
            let node = &self.nodes[i as usize];
            if node.bounds.entry(origin, inv_dir, t_min, limit).is_none() {
                continue;
            }
            if node.count > 0 {
                for &p in &self.order[node.first as usize..(node.first + node.count) as usize] {
                    if let Some(t) = test(p as usize, limit)
                        && t < limit
                    {
                        limit = t;
                        best = Some((t, p as usize));
                    }
                }
                continue;
            }
            // Visit the nearer child first: its hits shorten the ray for the other.
            let (a, b) = (i + 1, node.first);
            let ta = self.nodes[a as usize]
                .bounds
                .entry(origin, inv_dir, t_min, limit);
            let tb = self.nodes[b as usize]
                .bounds
                .entry(origin, inv_dir, t_min, limit);
            match (ta, tb) {
                (Some(x), Some(y)) if x <= y => stack.extend([b, a]),
                (Some(_), Some(_)) => stack.extend([a, b]),
                (Some(_), None) => stack.push(a),
                (None, Some(_)) => stack.push(b),
                (None, None) => {}
            }
        }
        best
    }
}

fn build_node(
    nodes: &mut Vec<Node>,
    order: &mut [u32],
    offset: usize,
    boxes: &[Aabb],
    centres: &[V3],
) -> usize {
    let bounds = order
        .iter()
        .fold(Aabb::EMPTY, |b, &p| b.union(boxes[p as usize]));
    let index = nodes.len();
    nodes.push(Node {
        bounds,
        first: offset as u32,
        count: order.len() as u32,
    });
    if order.len() <= LEAF_SIZE {
        return index;
    }
    let centre_bounds = order
        .iter()
        .fold(Aabb::EMPTY, |b, &p| b.grow(centres[p as usize]));
    let axis = centre_bounds.longest_axis();
    let mid = order.len() / 2;
    order.select_nth_unstable_by(mid, |&a, &b| {
        centres[a as usize][axis].total_cmp(&centres[b as usize][axis])
    });
    let (left, right) = order.split_at_mut(mid);
    build_node(nodes, left, offset, boxes, centres);
    let second = build_node(nodes, right, offset + mid, boxes, centres);
    nodes[index].first = second as u32;
    nodes[index].count = 0;
    index
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Spheres as primitives: the nearest hit through the hierarchy equals the brute-force one.
    #[test]
    fn nearest_equals_brute_force() {
        let mut state = 12345u64;
        let mut rnd = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let spheres: Vec<(V3, f64)> = (0..500)
            .map(|_| {
                (
                    [rnd() * 10.0 - 5.0, rnd() * 10.0 - 5.0, -2.0 - rnd() * 10.0],
                    0.05 + rnd() * 0.4,
                )
            })
            .collect();
        let boxes: Vec<Aabb> = spheres
            .iter()
            .map(|(c, r)| Aabb {
                lo: c.map(|x| x - r),
                hi: c.map(|x| x + r),
            })
            .collect();
        let bvh = Bvh::build(&boxes);
        let hit = |p: usize, origin: V3, dir: V3| -> Option<f64> {
            let (c, r) = spheres[p];
            let oc: V3 = std::array::from_fn(|i| origin[i] - c[i]);
            let a: f64 = dir.iter().map(|d| d * d).sum();
            let b: f64 = 2.0 * (0..3).map(|i| oc[i] * dir[i]).sum::<f64>();
            let cc: f64 = oc.iter().map(|x| x * x).sum::<f64>() - r * r;
            let disc = b * b - 4.0 * a * cc;
            (disc >= 0.0)
                .then(|| (-b - disc.sqrt()) / (2.0 * a))
                .filter(|t| *t > 1e-9)
        };
        let mut hits = 0;
        for _ in 0..2000 {
            let origin = [rnd() - 0.5, rnd() - 0.5, 0.0];
            let dir = [rnd() - 0.5, rnd() - 0.5, -1.0];
            let brute = (0..spheres.len())
                .filter_map(|p| hit(p, origin, dir).map(|t| (t, p)))
                .min_by(|a, b| a.0.total_cmp(&b.0));
            let fast = bvh.nearest(origin, dir, 1e-9, f64::INFINITY, |p, _| hit(p, origin, dir));
            assert_eq!(brute, fast);
            hits += usize::from(brute.is_some());
        }
        assert!(hits > 200, "the test rays must hit something ({hits})");
    }

    #[test]
    fn an_empty_hierarchy_hits_nothing() {
        assert_eq!(
            Bvh::build(&[]).nearest([0.0; 3], [0.0, 0.0, -1.0], 0.0, 1.0, |_, _| Some(0.5)),
            None
        );
    }
}
