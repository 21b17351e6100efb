//! The maps a recipe's `outputs` ask for (depth, normals, instance and semantic ids, both views),
//! rendered by the real worker for a scene of every category of the default preset and read back
//! through stereo-io: each describes the same first surface as the disparity at every pixel.
//! (`stereogen audit` checks them against its own ray cast: `audit_generated`.)

use stereo_io::{DisparityMap, IdMap, MapKind, read_depth_exr, read_id_png, read_normals_exr};
use stereogen::plan::{OutputMap, SEMANTIC_CLASSES, SceneSpec};
use stereogen::render::RenderService;
use test_support::{render, worker_config};

/// The first scene of each category of the default preset (seed 11) with every map, small.
fn one_spec_per_category_with_maps() -> Vec<SceneSpec> {
    test_support::one_spec_per_category(11, (160, 90), 2, &OutputMap::ALL)
}

/// Share of the left view's pixels that see the same object as the right view where the
/// disparity says they match (the left-right check of the two disparity maps passes).
fn instance_agreement(
    disp_l: &DisparityMap,
    disp_r: &DisparityMap,
    inst_l: &IdMap,
    inst_r: &IdMap,
) -> f64 {
    let consistent = disp_l.left_right_consistent(disp_r, 0.5);
    let (mut same, mut checked) = (0usize, 0usize);
    for (i, ok) in consistent.iter().enumerate() {
        if !ok {
            continue;
        }
        let (x, y) = (i % disp_l.width, i / disp_l.width);
        let xr = (x as f32 + 0.5 - disp_l.data[i]).floor();
        if xr < 0.0 {
            continue;
        }
        checked += 1;
        same += usize::from(inst_l.data[i] == inst_r.data[y * inst_r.width + xr as usize]);
    }
    same as f64 / checked.max(1) as f64
}

#[test]
fn every_map_of_every_category_describes_the_surface_of_the_disparity() {
    let specs = one_spec_per_category_with_maps();
    let mut service = RenderService::new(worker_config());
    for spec in &specs {
        let pair = render(&mut service, spec);
        let e = &pair.entry;
        let what = format!("{} ({})", spec.id, spec.category);
        assert_eq!(e.sha256.len(), 13, "{what}: {:?}", e.sha256.keys());
        assert_eq!(e.files.maps(), MapKind::ALL.to_vec(), "{what}");
        let fb = e.f_px * e.baseline_m;
        let mut ids = Vec::new();
        for (view, disp) in [("left", &pair.left), ("right", &pair.right)] {
            let at = |kind| pair.layout.abs(e.files.map(kind, view).unwrap());
            let depth = read_depth_exr(&at(MapKind::Depth)).unwrap();
            let normals = read_normals_exr(&at(MapKind::Normals)).unwrap();
            let instance = read_id_png(&at(MapKind::Instance)).unwrap();
            let semantic = read_id_png(&at(MapKind::Semantic)).unwrap();
            let (mut facing, mut valid, mut no_normal) = (0usize, 0usize, 0usize);
            for i in 0..disp.data.len() {
                let (x, y) = (i % disp.width, i / disp.width);
                let here = format!("{what} {view} ({x}, {y})");
                let v = disp.valid[i];
                assert_eq!(v, depth.data[i] > 0.0, "{here}: depth {}", depth.data[i]);
                assert_eq!(v, instance.data[i] > 0, "{here}: instance");
                assert_eq!(v, semantic.data[i] > 0, "{here}: semantic");
                let n = normals.data[i].map(f64::from);
                let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                if !v {
                    assert_eq!(len, 0.0, "{here}: a normal where no surface is");
                    continue;
                }
                valid += 1;
                // The disparity is f·B / depth, rounded once.
                let d = (fb / f64::from(depth.data[i])) as f32;
                assert_eq!(
                    d.to_bits(),
                    disp.data[i].to_bits(),
                    "{here}: {d} vs {}",
                    disp.data[i]
                );
                // Unit length, or none where the surface has no shading normal (rare).
                if len == 0.0 {
                    no_normal += 1;
                } else {
                    assert!((len - 1.0).abs() < 1e-6, "{here}: |n| = {len}");
                    // Camera frame: z forward, so a normal the camera sees points back at it.
                    facing += usize::from(n[2] < 0.0);
                }
                let id = instance.data[i];
                let object = spec
                    .objects
                    .get(usize::from(id) - 1)
                    .unwrap_or_else(|| panic!("{here}: instance {id} is no object"));
                assert_eq!(semantic.data[i], object.semantic_class(), "{here}");
                ids.push(id);
            }
            assert!(
                no_normal * 10_000 <= valid,
                "{what} {view}: {no_normal} of {valid} pixels without a normal"
            );
            // Smooth shading tilts a normal off the face near silhouettes: a few may look away.
            assert!(
                facing as f64 >= 0.97 * valid as f64,
                "{what} {view}: {facing} of {valid} normals face the camera"
            );
            if view == "right" {
                let inst_l = read_id_png(
                    &pair
                        .layout
                        .abs(e.files.map(MapKind::Instance, "left").unwrap()),
                )
                .unwrap();
                let agree = instance_agreement(&pair.left, &pair.right, &inst_l, &instance);
                assert!(
                    agree > 0.99,
                    "{what}: left and right ids agree at {agree:.4} of matched pixels"
                );
            }
        }
        // The instance table names every id seen, with the class its pixels carry.
        ids.sort_unstable();
        ids.dedup();
        assert!(ids.len() >= 2, "{what}: only {ids:?} visible");
        for id in &ids {
            let record = e
                .instances
                .iter()
                .find(|r| r.id == *id)
                .unwrap_or_else(|| panic!("{what}: id {id} not in {:?}", e.instances));
            let object = &spec.objects[usize::from(*id) - 1];
            assert_eq!(record.name, object.name);
            assert_eq!(record.source, object.source);
            assert_eq!(
                SEMANTIC_CLASSES[usize::from(record.semantic) - 1],
                if SEMANTIC_CLASSES.contains(&object.source.as_str()) {
                    object.source.as_str()
                } else {
                    "other"
                }
            );
        }
        assert_eq!(
            e.instances[0].role, "background",
            "{what}: the wall is object 1"
        );
    }
}
