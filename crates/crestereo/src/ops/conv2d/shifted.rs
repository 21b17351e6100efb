//! Stride-1 convolutions as sums of shifted matrix products, without an unfolded input.
//!
//! Pad each input plane once to `hp × wp` and flatten it. For kernel tap `(a, c)` the input
//! pixels an output row needs are then the same flat array read from offset
//! `a·dil_y·wp + c·dil_x`: an ordinary strided matrix view. An output computed on the padded
//! width (`ho` rows of `wp` columns, of which the first `wo` are real) is therefore
//!
//! ```text
//! Y_wide = Σ_taps W_tap · Xpad[:, offset(tap) .. offset(tap) + span]     (C_out × span)
//! ```
//!
//! with `span = (ho − 1)·wp + wo`, and no column of the sum ever wraps into the next row (the
//! padding holds the zeros a wrap would need). The backward is the same trick twice:
//! `dW_tap = dY_wide · Xpad_tapᵀ` and `dXpad[:, offset(tap)..] += W_tapᵀ · dY_wide`, where
//! `dY_wide` has zeros in the `wp − wo` columns that are not real outputs.
//!
//! Compared with `im2col` this never writes the `C_in·kh·kw × P` unfolded matrix (for the
//! GRU's 1×5 and 5×1 gates at the paper's crop, 190 MB per call and the same again in the
//! backward); each tap is a GEMM with `K = C_in`, so it is used where `C_in` is large enough
//! to keep the kernel efficient.

use rayon::prelude::*;

use super::Geometry;
use super::scratch::Scratch;
use super::views::{Threads, View, matmul_into};

/// Below this many input channels each tap's product is too thin to beat one unfolded GEMM.
const MIN_CIN: usize = 16;

/// Whether `g` takes this path: stride 1, more than one tap, enough input channels.
pub(super) fn applies(g: &Geometry) -> bool {
    g.stride == [1, 1] && g.kh * g.kw > 1 && g.cin >= MIN_CIN && g.ho > 0 && g.wo > 0
}

/// Sizes of the padded, flattened planes.
struct Padded {
    hp: usize,
    wp: usize,
    /// Columns of a wide output row block that a product computes: `(ho − 1)·wp + wo`.
    span: usize,
}

impl Padded {
    fn new(g: &Geometry) -> Self {
        let (hp, wp) = (g.h + 2 * g.pad[0], g.w + 2 * g.pad[1]);
        Padded {
            hp,
            wp,
            span: (g.ho - 1) * wp + g.wo,
        }
    }

    /// Flat offset of tap `(a, c)` in a padded plane.
    fn offset(&self, g: &Geometry, a: usize, c: usize) -> usize {
        a * g.dil[0] * self.wp + c * g.dil[1]
    }

    fn plane(&self) -> usize {
        self.hp * self.wp
    }
}

/// A `rows × cols` window of every plane: planes of `plane` = (rows, cols) in their buffer,
/// the window's top-left corner at `at`.
#[derive(Clone, Copy)]
struct Window {
    plane: (usize, usize),
    at: (usize, usize),
}

/// The whole of a `rows × cols` plane.
fn whole(rows: usize, cols: usize) -> Window {
    Window {
        plane: (rows, cols),
        at: (0, 0),
    }
}

/// Copies the `rows × cols` window `from` of each plane of `src` onto the window `to` of the
/// same plane of `dst` (the rest of `dst` untouched): padding a map, or cutting it back out.
fn copy_windows(
    src: &[f32],
    from: Window,
    dst: &mut [f32],
    to: Window,
    (rows, cols): (usize, usize),
) {
    dst.par_chunks_mut(to.plane.0 * to.plane.1)
        .zip(src.par_chunks(from.plane.0 * from.plane.1))
        .for_each(|(d, s)| {
            for y in 0..rows {
                let si = (y + from.at.0) * from.plane.1 + from.at.1;
                let di = (y + to.at.0) * to.plane.1 + to.at.1;
                d[di..][..cols].copy_from_slice(&s[si..][..cols]);
            }
        });
}

/// Image `b` of `x` (N, C_in, H, W), zero-padded and flattened: (C_in, hp·wp).
fn padded_input(x: &[f32], g: &Geometry, p: &Padded, b: usize) -> Scratch {
    let mut xp = Scratch::new(g.cin * p.plane());
    xp.fill(0.0);
    let image = &x[b * g.cin * g.h * g.w..][..g.cin * g.h * g.w];
    let inside = Window {
        plane: (p.hp, p.wp),
        at: (g.pad[0], g.pad[1]),
    };
    copy_windows(image, whole(g.h, g.w), &mut xp, inside, (g.h, g.w));
    xp
}

/// Image `b` of `dy` (N, C_out, ho, wo) on the padded width into `wide` (C_out, ho·wp), whose
/// extra columns stay zero.
fn widen_output_grad(dy: &[f32], g: &Geometry, p: &Padded, b: usize, wide: &mut [f32]) {
    let image = &dy[b * g.cout * g.ho * g.wo..][..g.cout * g.ho * g.wo];
    copy_windows(
        image,
        whole(g.ho, g.wo),
        wide,
        whole(g.ho, p.wp),
        (g.ho, g.wo),
    );
}

fn taps(g: &Geometry) -> impl Iterator<Item = (usize, usize)> + '_ {
    (0..g.kh).flat_map(move |a| (0..g.kw).map(move |c| (a, c)))
}

/// The weight's tap `(a, c)` as a (C_out × C_in) view of `w` (C_out, C_in, kh, kw).
fn weight_tap(g: &Geometry, a: usize, c: usize) -> View {
    View::new(a * g.kw + c, g.cin * g.kh * g.kw, g.kh * g.kw)
}

/// `Y` (N, C_out, ho, wo) of input `x` and weight `w`, both contiguous.
pub(super) fn forward(x: &[f32], w: &[f32], g: &Geometry) -> Vec<f32> {
    let p = Padded::new(g);
    let mut y = vec![0f32; g.n * g.cout * g.ho * g.wo];
    let mut wide = Scratch::new(g.cout * g.ho * p.wp);
    wide.fill(0.0);
    for b in 0..g.n {
        let xp = padded_input(x, g, &p, b);
        for (t, (a, c)) in taps(g).enumerate() {
            matmul_into(
                Threads::Pool,
                (g.cout, p.span, g.cin),
                &mut wide,
                View::new(0, g.ho * p.wp, 1),
                t > 0,
                w,
                weight_tap(g, a, c),
                &xp,
                View::new(p.offset(g, a, c), p.plane(), 1),
            );
        }
        let out = &mut y[b * g.cout * g.ho * g.wo..][..g.cout * g.ho * g.wo];
        copy_windows(
            &wide,
            whole(g.ho, p.wp),
            out,
            whole(g.ho, g.wo),
            (g.ho, g.wo),
        );
    }
    y
}

/// `dW` (C_out, C_in, kh, kw) = Σ_b Σ_taps dY_wide · Xpad_tapᵀ.
pub(super) fn weight_grad(x: &[f32], dy: &[f32], g: &Geometry) -> Vec<f32> {
    let p = Padded::new(g);
    let mut dw = vec![0f32; g.cout * g.cin * g.kh * g.kw];
    let mut dy_wide = Scratch::new(g.cout * g.ho * p.wp);
    dy_wide.fill(0.0);
    for b in 0..g.n {
        let xp = padded_input(x, g, &p, b);
        widen_output_grad(dy, g, &p, b, &mut dy_wide);
        for (a, c) in taps(g) {
            matmul_into(
                Threads::Pool,
                (g.cout, g.cin, p.span),
                &mut dw,
                weight_tap(g, a, c),
                b > 0,
                &dy_wide,
                View::new(0, g.ho * p.wp, 1),
                &xp,
                View::new(p.offset(g, a, c), 1, p.plane()),
            );
        }
    }
    dw
}

/// `dX` (N, C_in, H, W): per image, `dXpad[:, offset(tap)..] += W_tapᵀ · dY_wide`, then the
/// interior of `dXpad`.
pub(super) fn input_grad(w: &[f32], dy: &[f32], g: &Geometry) -> Vec<f32> {
    let p = Padded::new(g);
    let mut dx = vec![0f32; g.n * g.cin * g.h * g.w];
    let mut dy_wide = Scratch::new(g.cout * g.ho * p.wp);
    dy_wide.fill(0.0);
    let mut dxp = Scratch::new(g.cin * p.plane());
    dxp.fill(0.0);
    for b in 0..g.n {
        widen_output_grad(dy, g, &p, b, &mut dy_wide);
        dxp.fill(0.0);
        for (a, c) in taps(g) {
            let tap = weight_tap(g, a, c);
            matmul_into(
                Threads::Pool,
                (g.cin, p.span, g.cout),
                &mut dxp,
                View::new(p.offset(g, a, c), p.plane(), 1),
                true,
                w,
                View::new(tap.offset, tap.cs, tap.rs),
                &dy_wide,
                View::new(0, g.ho * p.wp, 1),
            );
        }
        let out = &mut dx[b * g.cin * g.h * g.w..][..g.cin * g.h * g.w];
        let inside = Window {
            plane: (p.hp, p.wp),
            at: (g.pad[0], g.pad[1]),
        };
        copy_windows(&dxp, inside, out, whole(g.h, g.w), (g.h, g.w));
    }
    dx
}
