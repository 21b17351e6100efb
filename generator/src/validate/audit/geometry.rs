//! Reads the geometry file the worker writes for the audit (`blender_scripts/export_geometry.py`
//! describes the layout) into a [`RayScene`], keeping what the file says about each object and
//! the cameras Blender built. Objects carry the names the SceneSpec gave them (the worker names
//! each Blender object after its spec entry), which is how the audit finds a hit's instance id.

use std::path::Path;

use anyhow::{Context, bail};
use serde::Deserialize;

use super::raycast::{CutoutUv, NO_CUTOUT, RayScene, ShadingNormals, Triangle, UvDisc};

const MAGIC: &[u8; 8] = b"STGEOM01";
/// The format version of `export_geometry.py` this reader understands (2: shading normals).
pub const FORMAT_VERSION: u32 = 2;

/// Where one array lies in the payload.
#[derive(Debug, Clone, Deserialize)]
struct ArrayRef {
    offset: usize,
    bytes: usize,
}

/// A mask that cuts a material's surface out, as the worker states it.
#[derive(Debug, Clone, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
enum CutoutDef {
    UvDisc { centre: [f64; 2], radius: f64 },
}

#[derive(Debug, Clone, Deserialize)]
pub struct MaterialInfo {
    pub name: Option<String>,
    #[serde(default)]
    cutout: Option<CutoutDef>,
}

impl MaterialInfo {
    pub fn has_cutout(&self) -> bool {
        self.cutout.is_some()
    }
}

#[derive(Debug, Clone, Deserialize)]
struct ObjectHeader {
    name: String,
    vertex_count: usize,
    triangle_count: usize,
    materials: Vec<MaterialInfo>,
    vertices: ArrayRef,
    triangles: ArrayRef,
    triangle_material: ArrayRef,
    uv: Option<ArrayRef>,
    /// World-space unit normal at each triangle corner, (m, 3, 3).
    normals: ArrayRef,
    /// 1 where Cycles shades the triangle smooth, (m,).
    triangle_smooth: ArrayRef,
    /// The object's transform mirrors.
    negative_scale: bool,
}

/// A camera as Blender built it (for a consistency check with the spec's rig).
#[derive(Debug, Clone, Deserialize)]
pub struct BlenderCameraInfo {
    pub matrix_world: [[f64; 4]; 4],
    pub lens_mm: f64,
    pub sensor_width_mm: f64,
    pub sensor_fit: String,
    pub shift_x: f64,
    pub shift_y: f64,
    pub clip_start: f64,
    pub clip_end: f64,
}

#[derive(Debug, Clone, Deserialize)]
pub struct Cameras {
    pub left: BlenderCameraInfo,
    pub right: BlenderCameraInfo,
}

#[derive(Debug, Clone, Deserialize)]
struct Header {
    format_version: u32,
    blender: String,
    cameras: Cameras,
    objects: Vec<ObjectHeader>,
}

/// What the file says about one object.
#[derive(Debug, Clone)]
pub struct ObjectSummary {
    pub name: String,
    pub triangles: usize,
    pub materials: Vec<MaterialInfo>,
}

/// The evaluated scene of one sample.
#[derive(Debug, Clone)]
pub struct SceneGeometry {
    pub blender: String,
    pub cameras: Cameras,
    pub objects: Vec<ObjectSummary>,
    pub scene: RayScene,
}

/// A little-endian array of `n` records of `width` values each.
fn values<const W: usize, T: Copy + Default>(
    payload: &[u8],
    r: &ArrayRef,
    n: usize,
    decode: impl Fn(&[u8]) -> T,
    what: &str,
) -> anyhow::Result<Vec<[T; W]>> {
    let size = std::mem::size_of::<T>();
    if r.bytes != n * W * size {
        bail!(
            "{what}: {} bytes, expected {} for {n} records",
            r.bytes,
            n * W * size
        );
    }
    let bytes = payload
        .get(r.offset..r.offset + r.bytes)
        .with_context(|| format!("{what}: lies beyond the end of the file"))?;
    Ok(bytes
        .chunks_exact(W * size)
        .map(|rec| std::array::from_fn(|k| decode(&rec[k * size..(k + 1) * size])))
        .collect())
}

fn f64_le(b: &[u8]) -> f64 {
    f64::from_le_bytes(b.try_into().expect("8 bytes"))
}

fn u32_le(b: &[u8]) -> u32 {
    u32::from_le_bytes(b.try_into().expect("4 bytes"))
}

/// Splits the file into its header and payload.
fn split(bytes: &[u8]) -> anyhow::Result<(Header, &[u8])> {
    if bytes.len() < 16 || &bytes[..8] != MAGIC {
        bail!(
            "not a stereogen geometry file (no {:?} magic)",
            std::str::from_utf8(MAGIC).unwrap_or_default()
        );
    }
    let len = u64::from_le_bytes(bytes[8..16].try_into().expect("8 bytes")) as usize;
    let head = bytes.get(16..16 + len).context("the header is cut short")?;
    let header: Header = serde_json::from_slice(head).context("unreadable header")?;
    if header.format_version != FORMAT_VERSION {
        bail!(
            "format version {}, this stereogen reads {FORMAT_VERSION}",
            header.format_version
        );
    }
    Ok((header, &bytes[16 + len..]))
}

/// The triangles of a scene as they accumulate, with their cut-outs and shading normals.
#[derive(Default)]
struct Collected {
    tris: Vec<Triangle>,
    cutouts: Vec<CutoutUv>,
    shading: Vec<ShadingNormals>,
}

/// The shading normals of one object's triangles.
fn shading(o: &ObjectHeader, payload: &[u8]) -> anyhow::Result<Vec<ShadingNormals>> {
    let name = &o.name;
    let normals = values::<9, f64>(
        payload,
        &o.normals,
        o.triangle_count,
        f64_le,
        &format!("{name}: normals"),
    )?;
    let smooth = values::<1, u32>(
        payload,
        &o.triangle_smooth,
        o.triangle_count,
        u32_le,
        &format!("{name}: smooth flags"),
    )?;
    normals
        .iter()
        .zip(&smooth)
        .enumerate()
        .map(|(k, (n, s))| {
            let corners = [[n[0], n[1], n[2]], [n[3], n[4], n[5]], [n[6], n[7], n[8]]];
            if s[0] == 1 && corners.iter().flatten().any(|x| !x.is_finite()) {
                bail!("{name}: triangle {k} has a corner normal that is not finite");
            }
            Ok(ShadingNormals {
                corners,
                smooth: s[0] == 1,
                mirrored: o.negative_scale,
            })
        })
        .collect()
}

/// Appends the triangles of one object (index `object`) to `out`.
fn add_object(
    o: &ObjectHeader,
    object: usize,
    payload: &[u8],
    out: &mut Collected,
) -> anyhow::Result<()> {
    let Collected {
        tris,
        cutouts,
        shading: normals,
    } = out;
    let name = &o.name;
    let verts = values::<3, f64>(
        payload,
        &o.vertices,
        o.vertex_count,
        f64_le,
        &format!("{name}: vertices"),
    )?;
    let faces = values::<3, u32>(
        payload,
        &o.triangles,
        o.triangle_count,
        u32_le,
        &format!("{name}: triangles"),
    )?;
    let mats = values::<1, u32>(
        payload,
        &o.triangle_material,
        o.triangle_count,
        u32_le,
        &format!("{name}: triangle materials"),
    )?;
    let uvs = match &o.uv {
        Some(r) => Some(values::<6, f64>(
            payload,
            r,
            o.triangle_count,
            f64_le,
            &format!("{name}: UVs"),
        )?),
        None => None,
    };
    if let Some(bad) = verts.iter().flatten().find(|x| !x.is_finite()) {
        bail!("{name}: vertex coordinate {bad}");
    }
    for (k, (f, m)) in faces.iter().zip(&mats).enumerate() {
        if f.iter().any(|&i| i as usize >= verts.len()) {
            bail!(
                "{name}: triangle {k} indexes a vertex beyond the {} there are",
                verts.len()
            );
        }
        let material = o.materials.get(m[0] as usize).with_context(|| {
            format!(
                "{name}: triangle {k} has material {} of {}",
                m[0],
                o.materials.len()
            )
        })?;
        let cutout = match (&material.cutout, &uvs) {
            (None, _) => NO_CUTOUT,
            (Some(CutoutDef::UvDisc { centre, radius }), Some(uvs)) => {
                let c = uvs[k];
                cutouts.push(CutoutUv {
                    uv: [[c[0], c[1]], [c[2], c[3]], [c[4], c[5]]],
                    mask: UvDisc {
                        centre: *centre,
                        radius: *radius,
                    },
                });
                (cutouts.len() - 1) as u32
            }
            (Some(_), None) => bail!(
                "{name}: material {:?} has a cut-out but the object has no UVs",
                material.name
            ),
        };
        tris.push(Triangle {
            v: f.map(|i| verts[i as usize]),
            object,
            cutout,
        });
    }
    normals.extend(shading(o, payload)?);
    Ok(())
}

/// Reads a geometry file; errors name the file and what is wrong with it.
pub fn read_geometry(path: &Path) -> anyhow::Result<SceneGeometry> {
    let bytes = std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
    parse(&bytes).with_context(|| format!("{}", path.display()))
}

fn parse(bytes: &[u8]) -> anyhow::Result<SceneGeometry> {
    let (header, payload) = split(bytes)?;
    let mut out = Collected::default();
    for (i, o) in header.objects.iter().enumerate() {
        add_object(o, i, payload, &mut out)?;
    }
    let objects = header
        .objects
        .into_iter()
        .map(|o| ObjectSummary {
            name: o.name,
            triangles: o.triangle_count,
            materials: o.materials,
        })
        .collect();
    Ok(SceneGeometry {
        blender: header.blender,
        cameras: header.cameras,
        objects,
        scene: RayScene::new(out.tris, out.cutouts).with_shading(out.shading),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Writes a file as `export_geometry.py` does: one leaf quad (two triangles, a cut-out material).
    fn leaf_file() -> Vec<u8> {
        let mut payload = Vec::new();
        let mut put = |data: Vec<u8>| {
            let r = serde_json::json!({"offset": payload.len(), "bytes": data.len()});
            payload.extend(data);
            payload.resize(payload.len().div_ceil(8) * 8, 0);
            r
        };
        let verts: Vec<u8> = [
            [-1.0, -1.0, -2.0],
            [1.0, -1.0, -2.0],
            [1.0, 1.0, -2.0],
            [-1.0, 1.0, -2.0f64],
        ]
        .iter()
        .flatten()
        .flat_map(|x| x.to_le_bytes())
        .collect();
        let tris: Vec<u8> = [0u32, 1, 2, 0, 2, 3]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        let mats: Vec<u8> = [0u32, 0].iter().flat_map(|x| x.to_le_bytes()).collect();
        let uv: Vec<u8> = [
            0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 1.0f64,
        ]
        .iter()
        .flat_map(|x| x.to_le_bytes())
        .collect();
        // The first triangle smooth, its corner normals leaning out of the quad's plane; the
        // second flat (its normals are not used).
        let normals: Vec<u8> = [
            [0.6, 0.0, 0.8],
            [0.0, 0.6, 0.8],
            [-0.6, 0.0, 0.8],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, 1.0f64],
        ]
        .iter()
        .flatten()
        .flat_map(|x| x.to_le_bytes())
        .collect();
        let smooth: Vec<u8> = [1u32, 0].iter().flat_map(|x| x.to_le_bytes()).collect();
        let (v, t, m, u) = (put(verts), put(tris), put(mats), put(uv));
        let (n, s) = (put(normals), put(smooth));
        let cam = serde_json::json!({"matrix_world": [[1.0,0.0,0.0,-0.05],[0.0,1.0,0.0,0.0],[0.0,0.0,1.0,0.0],[0.0,0.0,0.0,1.0]],
            "lens_mm": 35.0, "sensor_width_mm": 36.0, "sensor_fit": "HORIZONTAL", "shift_x": 0.0, "shift_y": 0.0, "clip_start": 0.01, "clip_end": 100.0});
        let header = serde_json::json!({"format_version": 2, "blender": "4.5.1", "cameras": {"left": cam, "right": cam},
            "objects": [{"name": "leaf", "vertex_count": 4, "triangle_count": 2,
                "materials": [{"name": "leaf_mat", "cutout": {"kind": "uv_disc", "centre": [0.5, 0.5], "radius": 0.5}}],
                "vertices": v, "triangles": t, "triangle_material": m, "uv": u,
                "normals": n, "triangle_smooth": s, "negative_scale": false}]});
        let head = serde_json::to_vec(&header).unwrap();
        let mut file = MAGIC.to_vec();
        file.extend((head.len() as u64).to_le_bytes());
        file.extend(head);
        file.extend(payload);
        file
    }

    #[test]
    fn reads_triangles_and_cut_outs() {
        let g = parse(&leaf_file()).unwrap();
        assert_eq!(g.objects.len(), 1);
        assert_eq!(g.scene.triangles.len(), 2);
        assert_eq!(g.scene.cutouts.len(), 2);
        assert!(g.objects[0].materials[0].has_cutout());
        // Through the disc's centre the leaf is there; near its corner it is cut out.
        assert!(
            g.scene
                .first_hit([0.0; 3], [0.0, 0.0, -1.0], 1e-9, f64::INFINITY)
                .is_some()
        );
        assert!(
            g.scene
                .first_hit([0.0; 3], [0.45, 0.45, -1.0], 1e-9, f64::INFINITY)
                .is_none()
        );
    }

    #[test]
    fn shading_normals_interpolate_smooth_triangles_and_face_the_ray() {
        let g = parse(&leaf_file()).unwrap();
        let normal = |origin: [f64; 3], dir: [f64; 3]| {
            let hit = g.scene.first_hit(origin, dir, 1e-9, f64::INFINITY).unwrap();
            g.scene.shading_normal(&hit, dir)
        };
        let close = |a: [f64; 3], b: [f64; 3]| (0..3).all(|i| (a[i] - b[i]).abs() < 1e-12);
        // (0.3, -0.3) on the smooth triangle: barycentric (0.35, 0.3, 0.35) of its corners.
        let len = (0.18f64 * 0.18 + 0.8 * 0.8).sqrt();
        let smooth = [0.0, 0.18 / len, 0.8 / len];
        let n = normal([0.0; 3], [0.15, -0.15, -1.0]);
        assert!(close(n, smooth), "{n:?}");
        // From behind, both the shading and the geometric normal turn round to face the ray.
        let n = normal([0.3, -0.3, -4.0], [0.0, 0.0, 1.0]);
        assert!(close(n, smooth.map(|c| -c)), "{n:?}");
        // (-0.3, 0.3) on the flat triangle: its own geometric normal.
        assert!(close(
            normal([0.0; 3], [-0.15, 0.15, -1.0]),
            [0.0, 0.0, 1.0]
        ));
        assert!(close(
            normal([-0.3, 0.3, -4.0], [0.0, 0.0, 1.0]),
            [0.0, 0.0, -1.0]
        ));
    }

    #[test]
    fn damaged_files_are_refused_with_the_reason() {
        let file = leaf_file();
        assert!(
            parse(&file[..10])
                .unwrap_err()
                .to_string()
                .contains("magic")
        );
        let e = format!("{:#}", parse(&file[..file.len() - 16]).unwrap_err());
        assert!(e.contains("beyond the end"), "{e}");
        let mut bad = file.clone();
        bad[8] ^= 0x40;
        assert!(parse(&bad).is_err());
    }
}
