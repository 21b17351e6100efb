//! Ground-truth disparity written by the real Blender worker, checked against analytic geometry
//! and an independent ray caster (pixel centres at x + 0.5, y + 0.5).

use stereo_io::DisparityMap;
use stereogen::plan::rig::View;
use stereogen::render::RenderService;
use stereogen::validate::audit::raycast::{
    RayScene, disparity_at, scene_triangles, visible_in_right,
};
use test_support::{render, scenes, worker_config};

/// Steepest disparity change (px per px) tolerated before a pixel counts as grazing: there a
/// ray offset of 1e-4 px (float32 raster arithmetic) already moves the disparity by 1e-3 px.
const GRAZING_GRADIENT: f64 = 10.0;

/// Compares a rendered map with ray casting. Returns (max error over exact pixels, grazing count,
/// pixels with the wrong validity). A pixel is "grazing" when rays 0.02 px around its centre hit
/// different objects (or none), or see the surface so obliquely that the disparity gradient
/// exceeds [`GRAZING_GRADIENT`].
fn compare(
    map: &DisparityMap,
    rig: &stereogen::plan::StereoRig,
    tris: &RayScene,
    view: View,
) -> (f64, usize, usize) {
    let (mut max_err, mut grazing, mut wrong_validity) = (0f64, 0usize, 0usize);
    for y in 0..map.height {
        for x in 0..map.width {
            let (u, v) = (x as f64 + 0.5, y as f64 + 0.5);
            let centre = disparity_at(rig, tris, view, u, v);
            let around: Vec<Option<(f64, usize)>> =
                [(-0.02, 0.0), (0.02, 0.0), (0.0, -0.02), (0.0, 0.02)]
                    .iter()
                    .map(|(du, dv)| disparity_at(rig, tris, view, u + du, v + dv))
                    .collect();
            let steep = around.iter().any(|h| match (h, centre) {
                (Some((d, _)), Some((dc, _))) => (d - dc).abs() / 0.02 > GRAZING_GRADIENT,
                _ => false,
            });
            if steep || around.iter().any(|h| h.map(|h| h.1) != centre.map(|h| h.1)) {
                grazing += 1;
                continue;
            }
            match centre {
                Some((d, _)) => {
                    if !map.is_valid(x, y) {
                        wrong_validity += 1;
                    } else {
                        max_err = max_err.max((f64::from(map.get(x, y)) - d).abs());
                    }
                }
                None => {
                    if map.is_valid(x, y) || map.get(x, y) != 0.0 {
                        wrong_validity += 1;
                    }
                }
            }
        }
    }
    (max_err, grazing, wrong_validity)
}

#[test]
fn fronto_parallel_plane_is_exact_everywhere() {
    let mut service = RenderService::new(worker_config());
    for z in [0.8, 2.0, 7.5] {
        let spec = scenes::fronto_parallel(z);
        let pair = render(&mut service, &spec);
        let expected = spec.rig.f_px() * spec.rig.baseline_m / z;
        for map in [&pair.left, &pair.right] {
            assert!(map.valid.iter().all(|&v| v), "every pixel sees the plane");
            let worst = map
                .data
                .iter()
                .map(|&d| ((f64::from(d) - expected) / expected).abs())
                .fold(0.0, f64::max);
            println!(
                "fronto-parallel z={z}: expected {expected:.6} px, worst relative error {worst:.2e}"
            );
            assert!(worst <= 1e-5, "relative error {worst} at z={z}");
        }
    }
}

#[test]
fn tilted_plane_and_sphere_match_ray_casting() {
    let mut service = RenderService::new(worker_config());
    for spec in [
        scenes::tilted_plane(),
        scenes::sphere_before_wall(),
        scenes::sphere_alone(),
    ] {
        let pair = render(&mut service, &spec);
        let tris = scene_triangles(&spec);
        let n = spec.rig.width as usize * spec.rig.height as usize;
        for (map, view) in [(&pair.left, View::Left), (&pair.right, View::Right)] {
            let (max_err, grazing, wrong_validity) = compare(map, &spec.rig, &tris, view);
            println!(
                "{} {view:?}: max |error| {max_err:.2e} px, {grazing} grazing pixels ({:.3}%), {wrong_validity} with wrong validity",
                spec.id,
                100.0 * grazing as f64 / n as f64
            );
            assert!(
                max_err <= 1e-3,
                "{} {view:?}: max error {max_err} px",
                spec.id
            );
            assert!(
                grazing as f64 <= 0.001 * n as f64,
                "{} {view:?}: {grazing} grazing pixels",
                spec.id
            );
            assert_eq!(
                wrong_validity, 0,
                "{} {view:?}: pixels whose validity disagrees with ray casting",
                spec.id
            );
        }
        if spec.id == "sphere_alone" {
            let background = pair.left.valid.iter().filter(|v| !**v).count();
            assert!(background > n / 2, "most of the view is empty");
        }
    }
}

#[test]
fn sphere_silhouette_has_no_flying_pixels() {
    let mut service = RenderService::new(worker_config());
    let spec = scenes::sphere_before_wall();
    let pair = render(&mut service, &spec);
    let rig = &spec.rig;
    let sphere = &spec.objects[1];
    let nearest = -sphere.location[2] - sphere.scale[0];
    let farthest = -sphere.location[2] + sphere.scale[0];
    let wall = rig.disparity_at_depth(-spec.objects[0].location[2]);
    let (sphere_min, sphere_max) = (
        rig.disparity_at_depth(farthest),
        rig.disparity_at_depth(nearest),
    );
    for map in [&pair.left, &pair.right] {
        let flying = map
            .data
            .iter()
            .filter(|&&d| f64::from(d) > wall + 1e-3 && f64::from(d) < sphere_min - 1e-3)
            .count();
        let beyond = map
            .data
            .iter()
            .filter(|&&d| f64::from(d) > sphere_max + 1e-3)
            .count();
        let on_sphere = map
            .data
            .iter()
            .filter(|&&d| f64::from(d) >= sphere_min - 1e-3)
            .count();
        println!(
            "wall {wall:.4} px, sphere {sphere_min:.4}..{sphere_max:.4} px: {on_sphere} sphere pixels, {flying} flying, {beyond} beyond"
        );
        assert!(on_sphere > 500);
        assert_eq!(flying, 0, "pixels between the wall and the sphere");
        assert_eq!(beyond, 0);
    }
}

/// Bilinear sample of a row at fractional column `x` (pixel-index coordinates).
fn bilinear_row(map: &DisparityMap, x: f64, y: usize) -> Option<(f64, usize, usize)> {
    if x < 0.0 || x > (map.width - 1) as f64 {
        return None;
    }
    let x0 = x.floor() as usize;
    let x1 = (x0 + 1).min(map.width - 1);
    let t = x - x0 as f64;
    Some((
        f64::from(map.get(x0, y)) * (1.0 - t) + f64::from(map.get(x1, y)) * t,
        x0,
        x1,
    ))
}

#[test]
fn left_and_right_views_agree() {
    let mut service = RenderService::new(worker_config());
    for spec in [scenes::tilted_plane(), scenes::sphere_before_wall()] {
        let pair = render(&mut service, &spec);
        let tris = scene_triangles(&spec);
        let rig = &spec.rig;
        let (mut checked, mut worst) = (0usize, 0f64);
        for y in 0..pair.left.height {
            for x in 0..pair.left.width {
                if !pair.left.is_valid(x, y) {
                    continue;
                }
                let (u, v) = (x as f64 + 0.5, y as f64 + 0.5);
                let d = f64::from(pair.left.get(x, y));
                if !visible_in_right(rig, &tris, u, v, d) {
                    continue;
                }
                let Some((dr, x0, x1)) = bilinear_row(&pair.right, x as f64 - d, y) else {
                    continue;
                };
                // Both right neighbours must show the same surface as the left pixel.
                let own = disparity_at(rig, &tris, View::Left, u, v).map(|h| h.1);
                let same = [x0, x1].iter().all(|&xr| {
                    disparity_at(rig, &tris, View::Right, xr as f64 + 0.5, v).map(|h| h.1) == own
                });
                if !same {
                    continue;
                }
                worst = worst.max((dr - d).abs());
                checked += 1;
            }
        }
        println!(
            "{}: {checked} non-occluded pixels, max |d_L - d_R(x - d_L)| = {worst:.2e} px",
            spec.id
        );
        assert!(checked > pair.left.data.len() / 2);
        assert!(
            worst <= 0.05,
            "{}: left/right disagree by {worst} px",
            spec.id
        );
    }
}
