//! Procedural shape sources: varied primitives, wireframe open-work, nets.

use rand::Rng;
use rand::seq::IndexedRandom;

use super::recipe::{HoleRecipe, PrimitiveRecipe};
use super::spec::{Cutter, Modifier, Shape, Strand};

fn random_primitive<R: Rng>(rng: &mut R, with_grid: bool) -> Shape {
    let mut kinds = vec![0, 1, 2, 3, 4, 5, 6];
    if with_grid {
        kinds.push(7);
    }
    match *kinds.choose(rng).expect("non-empty") {
        0 => Shape::Cube,
        1 => Shape::UvSphere {
            segments: rng.random_range(8..=32),
            rings: rng.random_range(4..=16),
        },
        2 => Shape::IcoSphere {
            subdivisions: rng.random_range(1..=3),
        },
        3 => Shape::Cylinder {
            vertices: rng.random_range(6..=32),
        },
        4 => Shape::Cone {
            vertices: rng.random_range(4..=32),
            top_ratio: if rng.random_bool(0.5) {
                0.0
            } else {
                rng.random_range(0.2..0.8)
            },
        },
        5 => Shape::Torus {
            major_segments: rng.random_range(12..=48),
            minor_segments: rng.random_range(6..=16),
            minor_ratio: rng.random_range(0.15..0.5),
        },
        6 => Shape::Monkey,
        _ => Shape::Grid {
            x_segments: rng.random_range(3..=12),
            y_segments: rng.random_range(3..=12),
        },
    }
}

/// A Blender primitive with random proportions, optionally subdivided, displaced and
/// boolean-cut. Returns the shape, its modifiers and per-axis proportions.
pub fn primitive<R: Rng>(p: &PrimitiveRecipe, rng: &mut R) -> (Shape, Vec<Modifier>, [f64; 3]) {
    let shape = random_primitive(rng, false);
    let proportions: [f64; 3] = std::array::from_fn(|_| p.proportions.sample(rng));
    // Keep the largest axis at 1 so the object still fits its planned size.
    let m = proportions.iter().copied().fold(1e-9, f64::max);
    let proportions = proportions.map(|x| x / m);
    let mut modifiers = Vec::new();
    if rng.random_bool(p.boolean_probability) {
        let cutter = if rng.random_bool(0.5) {
            Cutter::Cube
        } else {
            Cutter::Sphere
        };
        let dir: [f64; 3] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
        let size = rng.random_range(0.3..0.7);
        modifiers.push(Modifier::BooleanCut {
            cutter,
            location: dir.map(|c| c * 0.8),
            rotation: std::array::from_fn(|_| rng.random_range(0.0..std::f64::consts::TAU)),
            scale: [size; 3],
        });
    }
    if rng.random_bool(p.subdivide_probability) {
        modifiers.push(Modifier::Subdivide {
            levels: rng.random_range(1..=2),
        });
    }
    if rng.random_bool(p.displace_probability) {
        // Displacement needs vertices to move: subdivide first.
        modifiers.push(Modifier::Subdivide { levels: 3 });
        modifiers.push(Modifier::Displace {
            strength: p.displace_strength.sample(rng),
            noise_scale: rng.random_range(0.2..1.2),
            offset: std::array::from_fn(|_| rng.random_range(-10.0..10.0)),
        });
    }
    (shape, modifiers, proportions)
}

/// A primitive reduced to its edges: holes and open-work.
pub fn wireframe<R: Rng>(h: &HoleRecipe, rng: &mut R) -> (Shape, Vec<Modifier>) {
    let shape = random_primitive(rng, true);
    let mut modifiers = Vec::new();
    // Low-poly shapes would keep only a few bars; a simple subdivision adds finer lattices.
    if matches!(
        shape,
        Shape::Cube | Shape::Cylinder { .. } | Shape::Cone { .. }
    ) && rng.random_bool(0.6)
    {
        modifiers.push(Modifier::Subdivide { levels: 1 });
    }
    modifiers.push(Modifier::Wireframe {
        thickness: h.wire_thickness.sample(rng),
    });
    (shape, modifiers)
}

/// A net, lattice or fence of thin strands in the XY plane, possibly bent into an arc.
pub fn net<R: Rng>(h: &HoleRecipe, rng: &mut R) -> Shape {
    let cells = h.net_cells.sample(rng).max(1);
    let half = std::f64::consts::FRAC_1_SQRT_2;
    let cell = 2.0 * half / f64::from(cells);
    let radius = h.net_strand.sample(rng) * cell;
    let diagonal = rng.random_bool(0.4);
    let bend = if rng.random_bool(0.3) {
        rng.random_range(0.3..1.2)
    } else {
        0.0
    };
    // Strands sampled densely enough that a bend stays smooth.
    let samples = 16;
    let warp = |x: f64, y: f64| -> [f64; 3] {
        let (x, y) = if diagonal {
            (
                (x - y) * std::f64::consts::FRAC_1_SQRT_2,
                (x + y) * std::f64::consts::FRAC_1_SQRT_2,
            )
        } else {
            (x, y)
        };
        if bend == 0.0 {
            [x, y, 0.0]
        } else {
            // Wrap x around a cylinder of curvature `bend`.
            let r = 1.0 / bend;
            [r * (x / r).sin(), y, r * (1.0 - (x / r).cos())]
        }
    };
    let mut strands = Vec::new();
    for i in 0..=cells {
        let c = -half + f64::from(i) * cell;
        for along_x in [true, false] {
            let points: Vec<[f64; 3]> = (0..=samples)
                .map(|k| {
                    let t = -half + 2.0 * half * f64::from(k) / f64::from(samples);
                    if along_x { warp(t, c) } else { warp(c, t) }
                })
                .collect();
            strands.push(Strand {
                radii: vec![radius; points.len()],
                points,
            });
        }
    }
    Shape::net(strands)
}
