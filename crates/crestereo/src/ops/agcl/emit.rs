//! The AGCL ops as ONNX nodes, in the order of operations of [`super::composed`]. Bilinear
//! sampling with zeros outside is ONNX `GridSample` (align_corners, the convention of the
//! model's pixel coordinates: −1 and 1 are the centres of the border pixels), so the graph
//! needs no gather and no custom op.

use super::CorrSpec;
use crate::export::onnx::{Graph, Value};

/// Column and row coordinates of every pixel as constants (1, 1, H, W).
fn pixel_grid(g: &mut Graph, h: usize, w: usize) -> (Value, Value) {
    let shape = [1, 1, h, w];
    (
        g.shared_constant("grid_x", &shape, || {
            (0..h * w).map(|i| (i % w) as f32).collect()
        }),
        g.shared_constant("grid_y", &shape, || {
            (0..h * w).map(|i| (i / w) as f32).collect()
        }),
    )
}

/// Pixel coordinates `x`, `y` of the same shape (N, A, H, W) as a GridSample grid
/// (N, A·H, W, 2) normalised for an image of `size` = (height, width).
fn normalised_grid(g: &mut Graph, x: &Value, y: &Value, size: [usize; 2]) -> Value {
    let [n, a, h, w] = x.dims();
    let mut normalise = |v: &Value, extent: usize| {
        assert!(
            extent >= 2,
            "GridSample with align_corners needs 2 or more pixels per axis (this level has {extent})"
        );
        let v = g.mul_scalar(v, 2.0 / (extent - 1) as f32);
        let v = g.sub_scalar(&v, 1.0);
        g.reshape(&v, &[n, a * h, w, 1])
    };
    let xn = normalise(x, size[1]);
    let yn = normalise(y, size[0]);
    g.concat(&[&xn, &yn], 3)
}

/// Offset correlation (shapes as in [`super::AgclOps`]).
pub fn emit_offset_corr(
    g: &mut Graph,
    left: &Value,
    right: &Value,
    flow: &Value,
    offset: &Value,
    spec: CorrSpec,
) -> Value {
    let [n, c, h, w] = left.dims();
    let (k, groups) = (spec.candidates(), spec.groups);
    let (gx, gy) = pixel_grid(g, h, w);
    let (dx, dy): (Vec<f32>, Vec<f32>) = (0..k)
        .map(|i| {
            let (dx, dy) = spec.window_offset(i);
            (dx as f32, dy as f32)
        })
        .unzip();
    let key = format!("window_{}x{}", 2 * spec.ry + 1, 2 * spec.rx + 1);
    let dx = g.shared_constant(&format!("{key}_dx"), &[1, k, 1, 1], || dx);
    let dy = g.shared_constant(&format!("{key}_dy"), &[1, k, 1, 1], || dy);
    let offset = g.reshape(offset, &[n, k, 2, h, w]);
    let ox = g.narrow(&offset, 2, 0, 1);
    let ox = g.reshape(&ox, &[n, k, h, w]);
    let oy = g.narrow(&offset, 2, 1, 1);
    let oy = g.reshape(&oy, &[n, k, h, w]);
    let fx = g.narrow(flow, 1, 0, 1);
    let fy = g.narrow(flow, 1, 1, 1);
    let x = g.add(&gx, &fx);
    let x = g.add(&x, &dx);
    let x = g.add(&x, &ox);
    let y = g.add(&gy, &fy);
    let y = g.add(&y, &dy);
    let y = g.add(&y, &oy);
    let grid = normalised_grid(g, &x, &y, [h, w]);
    let sampled = g.grid_sample(right, &grid); // (n, c, k·h, w)
    let sampled = g.reshape(&sampled, &[n, groups, c / groups, k, h * w]);
    let left = g.reshape(left, &[n, groups, c / groups, 1, h * w]);
    let product = g.mul(&left, &sampled);
    let corr = g.mean_dim(&product, 2);
    g.reshape(&corr, &[n, groups * k, h, w])
}

/// `right` sampled at `x + flow`, zeros outside.
pub fn emit_warp(g: &mut Graph, right: &Value, flow: &Value) -> Value {
    let [n, c, h, w] = right.dims();
    let (gx, gy) = pixel_grid(g, h, w);
    let fx = g.narrow(flow, 1, 0, 1);
    let fy = g.narrow(flow, 1, 1, 1);
    let x = g.add(&gx, &fx);
    let y = g.add(&gy, &fy);
    let grid = normalised_grid(g, &x, &y, [h, w]);
    let warped = g.grid_sample(right, &grid);
    g.reshape(&warped, &[n, c, h, w])
}

/// Replicate padding made of slices (as the composed op's): `r` copies of the first and last
/// index along `axis` on either side.
fn pad_edge(g: &mut Graph, x: &Value, axis: usize, r: usize) -> Value {
    if r == 0 {
        return x.clone();
    }
    let last = x.shape[axis] - 1;
    let first = g.narrow(x, axis, 0, 1);
    let end = g.narrow(x, axis, last, 1);
    let mut parts = vec![&first; r];
    parts.push(x);
    parts.extend(std::iter::repeat_n(&end, r));
    g.concat(&parts, axis)
}

/// The 1/4 level's shifted correlation: edge pad, one crop per candidate, products and group
/// means.
pub fn emit_shift_corr(g: &mut Graph, left: &Value, warped: &Value, spec: CorrSpec) -> Value {
    let [n, c, h, w] = left.dims();
    let (rx, ry, groups) = (spec.rx, spec.ry, spec.groups);
    let padded = pad_edge(g, warped, 3, rx);
    let padded = pad_edge(g, &padded, 2, ry);
    let corrs: Vec<Value> = (0..spec.candidates())
        .map(|k| {
            let (dx, dy) = spec.window_offset(k);
            let oy = (dy + ry as i64) as usize;
            let ox = (dx + rx as i64) as usize;
            let crop = g.crop(&padded, oy..oy + h, ox..ox + w);
            let product = g.mul(left, &crop);
            let product = g.reshape(&product, &[n, groups, c / groups, h, w]);
            g.mean_dim(&product, 2)
        })
        .collect();
    let corr = g.concat(&corrs.iter().collect::<Vec<_>>(), 2);
    g.reshape(&corr, &[n, groups * spec.candidates(), h, w])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::onnx::eval::{assert_emit_matches, run_emitted};
    use crate::ops::agcl::{SearchWindow, offset_corr, shift_corr, warp};
    use crate::test_util::uniform;

    /// The three AGCL ops as graph nodes against the kernels `forward` runs, for both search
    /// windows (1×9 row, 3×3 square), with flows and offsets that reach past the borders.
    #[test]
    fn emitted_agcl_ops_match_the_kernels() {
        let (n, c, h, w) = (2, 8, 6, 9);
        let left = uniform([n, c, h, w], -1.0, 1.0);
        let right = uniform([n, c, h, w], -1.0, 1.0);
        let flow = uniform([n, 2, h, w], -3.0, 3.0);
        let offset = uniform([n, 18, h, w], -1.5, 1.5);
        for index in 0..2 {
            let spec = CorrSpec::new(SearchWindow::for_iteration(index), 4);
            let inputs = [&left, &right, &flow, &offset].map(|t| t.to_data());
            let out = run_emitted(&inputs, |g, x| {
                let warped = emit_warp(g, &x[1], &x[2]);
                vec![
                    emit_offset_corr(g, &x[0], &x[1], &x[2], &x[3], spec),
                    emit_shift_corr(g, &x[0], &warped, spec),
                    warped,
                ]
            });
            let warped = warp(right.clone(), flow.clone());
            let expected = [
                offset_corr(
                    left.clone(),
                    right.clone(),
                    flow.clone(),
                    offset.clone(),
                    spec,
                ),
                shift_corr(left.clone(), warped.clone(), spec),
                warped,
            ];
            for ((label, emitted), forward) in ["offset corr", "shift corr", "warp"]
                .iter()
                .zip(&out)
                .zip(expected)
            {
                assert_emit_matches(label, emitted, forward.into_data(), 1e-5);
            }
        }
    }
}
