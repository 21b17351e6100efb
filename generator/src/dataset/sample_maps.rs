//! The maps a recipe's `outputs` ask for beside colour and disparity ([`stereo_io::maps`] states
//! their files), made from the worker's depth-pass EXR: every pass there was written by Cycles at
//! the same first surface as the Z pass the disparity comes from, so a map's pixel is valid
//! exactly where the disparity's is.

use anyhow::{Context, bail};
use stereo_io::datasets::ViewMaps;
use stereo_io::datasets::stereogen::InstanceRecord;
use stereo_io::{DepthMap, DisparityMap, IdMap, MapKind, NormalMap, RenderPasses};

use crate::plan::{ObjectRole, OutputMap, SceneSpec, Shape};

/// The stereo-io map of a recipe's output.
pub fn map_kind(output: OutputMap) -> MapKind {
    match output {
        OutputMap::Depth => MapKind::Depth,
        OutputMap::Normals => MapKind::Normals,
        OutputMap::Instance => MapKind::Instance,
        OutputMap::Semantic => MapKind::Semantic,
    }
}

/// The maps `spec` asks for, in [`MapKind::ALL`]'s order, each once.
pub fn requested_maps(spec: &SceneSpec) -> Vec<MapKind> {
    let asked: Vec<MapKind> = spec
        .render
        .recipe
        .outputs
        .iter()
        .map(|&o| map_kind(o))
        .collect();
    MapKind::ALL
        .into_iter()
        .filter(|k| asked.contains(k))
        .collect()
}

/// The maps `maps` of one view from its render passes; `disparity` is the view's disparity made
/// from the same passes (its validity is every map's).
pub fn view_maps(
    maps: &[MapKind],
    passes: &RenderPasses,
    disparity: &DisparityMap,
    spec: &SceneSpec,
    what: &str,
) -> anyhow::Result<ViewMaps> {
    let mut out = ViewMaps::default();
    let valid = &disparity.valid;
    let (w, h) = (passes.width, passes.height);
    if maps.contains(&MapKind::Depth) {
        // The Z pass as Cycles wrote it: `disparity == (f·B / depth) as f32` by construction.
        let data = passes
            .depth
            .iter()
            .zip(valid)
            .map(|(&z, &v)| if v { z } else { 0.0 })
            .collect();
        out.depth = Some(DepthMap {
            width: w,
            height: h,
            data,
        });
    }
    if maps.contains(&MapKind::Normals) {
        let normal = passes.normal.as_ref().with_context(|| {
            format!("{what}: the worker wrote no normal pass, yet the recipe asks for normals")
        })?;
        out.normals = Some(camera_normals(normal, valid, w, h, what)?);
    }
    if maps.contains(&MapKind::Instance) || maps.contains(&MapKind::Semantic) {
        let index = passes.object_index.as_ref().with_context(|| {
            format!(
                "{what}: the worker wrote no object-index pass, yet the recipe asks for instance or semantic maps"
            )
        })?;
        let instance = instance_ids(index, valid, w, h, spec.objects.len(), what)?;
        if maps.contains(&MapKind::Semantic) {
            let classes: Vec<u16> = spec.objects.iter().map(|o| o.semantic_class()).collect();
            let data = instance
                .data
                .iter()
                .map(|&id| if id == 0 { 0 } else { classes[id as usize - 1] })
                .collect();
            out.semantic = Some(IdMap {
                width: w,
                height: h,
                data,
            });
        }
        if maps.contains(&MapKind::Instance) {
            out.instance = Some(instance);
        }
    }
    Ok(out)
}

/// Cycles' world-space normals in the camera's frame (x right, y down, z forward), normalised in
/// f64; (0, 0, 0) where Cycles wrote none. The rig's cameras are never rotated (Blender: looking down −Z, +Y up, the world's axes),
/// so the frame change is a flip of y and z.
fn camera_normals(
    world: &[Vec<f32>; 3],
    valid: &[bool],
    width: usize,
    height: usize,
    what: &str,
) -> anyhow::Result<NormalMap> {
    let mut data = Vec::with_capacity(valid.len());
    for (i, &v) in valid.iter().enumerate() {
        if !v {
            data.push([0.0; 3]);
            continue;
        }
        let n = [
            f64::from(world[0][i]),
            -f64::from(world[1][i]),
            -f64::from(world[2][i]),
        ];
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        // Cycles writes no normal (0, 0, 0) where a surface has no shading normal: seen on one
        // pixel of a displaced, subdivided cube whose folded faces leave a vertex normal undefined.
        // The pixel keeps its depth and ids; its normal says "none".
        if len == 0.0 {
            data.push([0.0; 3]);
            continue;
        }
        if !(len.is_finite() && len > 0.5) {
            bail!(
                "{what}: the normal pass at pixel ({}, {}) is {n:?}, not a direction",
                i % width.max(1),
                i / width.max(1)
            );
        }
        data.push(n.map(|c| (c / len) as f32));
    }
    Ok(NormalMap {
        width,
        height,
        data,
    })
}

/// The object-index pass as instance ids (0 where no surface); an id that names no object of
/// the spec is an error.
fn instance_ids(
    index: &[f32],
    valid: &[bool],
    width: usize,
    height: usize,
    objects: usize,
    what: &str,
) -> anyhow::Result<IdMap> {
    let mut data = Vec::with_capacity(valid.len());
    for (i, (&x, &v)) in index.iter().zip(valid).enumerate() {
        if !v {
            data.push(0);
            continue;
        }
        let id = x.round();
        if !((1.0..=65535.0).contains(&id) && id as usize <= objects && (x - id).abs() < 1e-3) {
            bail!(
                "{what}: the object index at pixel ({}, {}) is {x}, not one of the spec's {objects} objects",
                i % width.max(1),
                i / width.max(1)
            );
        }
        data.push(id as u16);
    }
    Ok(IdMap {
        width,
        height,
        data,
    })
}

/// The sample's instance table: one record per object the worker built (an object it dropped,
/// its notes say so, has no pixels and no record). `notes` are the worker's; "NAME uses PATH"
/// names the mesh file an object was made from.
pub fn instance_table(spec: &SceneSpec, notes: &[String]) -> Vec<InstanceRecord> {
    let mut out = Vec::new();
    for (i, obj) in spec.objects.iter().enumerate() {
        if notes
            .iter()
            .any(|n| n.starts_with(&format!("{} dropped:", obj.name)))
        {
            continue;
        }
        let used = notes
            .iter()
            .find_map(|n| n.strip_prefix(&format!("{} uses ", obj.name)))
            .map(str::to_string);
        let mesh = used.or_else(|| match &obj.shape {
            Shape::MeshFile { candidates, .. } => {
                candidates.first().map(|p| p.display().to_string())
            }
            _ => None,
        });
        let class = serde_json::to_value(obj.material.class)
            .ok()
            .and_then(|v| v.as_str().map(str::to_string))
            .unwrap_or_default();
        out.push(InstanceRecord {
            id: i as u16 + 1,
            name: obj.name.clone(),
            role: match obj.role {
                ObjectRole::Background => "background",
                ObjectRole::Content => "content",
            }
            .to_string(),
            source: obj.source.clone(),
            mesh,
            material: class,
            semantic: obj.semantic_class(),
        });
    }
    out
}
