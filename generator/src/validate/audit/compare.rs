//! One sample's disparity maps against ray casting: every audited pixel is a silhouette pixel
//! (counted apart) or an interior one (compared within 0.01 and 0.5 px), may be a flying pixel,
//! and left pixels are checked against the right map (left–right consistency). The same rays
//! check the sample's other maps ([`super::map_check`]).

use rayon::prelude::*;
use stereo_io::DisparityMap;

use super::map_check::{MapTallies, PixelRays, SampleMaps, WORST_PER_MAP, merge_tallies};
use super::raycast::{Hit, RayScene, visible_from};
use super::tally::{IssueKind, MapIssue, PixelIssue, TIGHT_PX, Tally, keep_worst, keep_worst_maps};
use crate::plan::StereoRig;
use crate::plan::rig::View;

/// Rays this far (px) right, left, above and below a pixel centre decide whether the pixel lies
/// at a silhouette (as in `tests/integration/exactness.rs`).
pub const SILHOUETTE_OFFSET_PX: f64 = 0.02;
/// Disparity change (px per px) beyond which a surface counts as grazing, with the silhouettes:
/// there the renderer's float32 ray arithmetic (~1e-4 px) alone moves the value by 1e-3 px.
pub const GRAZING_GRADIENT: f64 = 10.0;
/// How far (in footprints of a [`SILHOUETTE_OFFSET_PX`] step at the centre's depth) a ray's hit
/// on another triangle of the same object may lie off the centre triangle's plane before the two
/// are taken as separate surfaces (a wire before another wire of one wireframe: a silhouette
/// inside one object). Across a crease of one surface the hit lies within about one footprint
/// of the plane; further only where the surface grazes the ray.
pub const STEP_FOOTPRINTS: f64 = 8.0;
/// A value counts as flying when it lies more than this (px) above the lowest and below the
/// highest disparity ray casting finds around the pixel, and this far from every one of them.
pub const FLYING_MARGIN_PX: f64 = 0.25;
/// Worst pixels kept per sample.
const WORST_PER_SAMPLE: usize = 10;

/// The camera side of one sample: rig and clipping range (planar depth, metres).
#[derive(Debug, Clone, Copy)]
pub struct Camera<'a> {
    pub rig: &'a StereoRig,
    pub clip_start: f64,
    pub clip_end: f64,
}

impl Camera<'_> {
    /// The first surface through image position (u, v) of `view`; `t` is the planar depth.
    fn hit(&self, scene: &RayScene, view: View, u: f64, v: f64) -> Option<Hit> {
        let origin = [self.rig.camera_x(view), 0.0, 0.0];
        scene.first_hit(
            origin,
            self.rig.ray_direction(u, v),
            self.clip_start,
            self.clip_end,
        )
    }

    fn disparity(&self, h: Option<Hit>) -> Option<f64> {
        h.map(|h| self.rig.disparity_at_depth(h.t))
    }
}

/// The centre-ray hits of the pixels one view needs (audited pixels, their neighbours, and the
/// right pixels the left–right check reads), computed once.
struct Centres {
    width: usize,
    hits: Vec<Option<Option<Hit>>>,
}

impl Centres {
    fn compute(cam: &Camera, scene: &RayScene, view: View, width: usize, needed: &[bool]) -> Self {
        let hits = needed
            .par_iter()
            .enumerate()
            .map(|(i, &n)| {
                n.then(|| {
                    cam.hit(
                        scene,
                        view,
                        (i % width) as f64 + 0.5,
                        (i / width) as f64 + 0.5,
                    )
                })
            })
            .collect();
        Self { width, hits }
    }

    fn at(&self, x: usize, y: usize) -> Option<Hit> {
        self.hits[y * self.width + x].expect("centre of a needed pixel")
    }
}

/// What one audited pixel shows.
#[derive(Debug, Default)]
struct Outcome {
    tally: Tally,
    issue: Option<PixelIssue>,
    maps: MapTallies,
    map_issues: Vec<MapIssue>,
}

/// A sample's two maps and the scene, ready to audit pixels.
pub struct SampleCheck<'a> {
    pub id: &'a str,
    pub category: &'a str,
    pub camera: Camera<'a>,
    pub scene: &'a RayScene,
    pub left: &'a DisparityMap,
    pub right: &'a DisparityMap,
    /// The sample's other maps, where it has them.
    pub maps: Option<&'a SampleMaps>,
}

/// Tally and worst pixels of one sample, of the disparity and of the other maps.
#[derive(Debug, Clone, Default)]
pub struct SampleOutcome {
    pub tally: Tally,
    pub worst: Vec<PixelIssue>,
    pub maps: MapTallies,
    pub map_worst: Vec<MapIssue>,
}

impl SampleOutcome {
    fn add(mut self, o: Outcome) -> Self {
        self.tally.merge(&o.tally);
        self.worst.extend(o.issue);
        merge_tallies(&mut self.maps, &o.maps);
        self.map_worst.extend(o.map_issues);
        self.trim(4);
        self
    }

    fn merge(mut self, o: SampleOutcome) -> Self {
        self.tally.merge(&o.tally);
        self.worst.extend(o.worst);
        merge_tallies(&mut self.maps, &o.maps);
        self.map_worst.extend(o.map_worst);
        self.trim(4);
        self
    }

    /// Keeps the worst lists short once they hold `slack` times what a sample keeps.
    fn trim(&mut self, slack: usize) {
        if self.worst.len() > slack * WORST_PER_SAMPLE {
            keep_worst(&mut self.worst, WORST_PER_SAMPLE);
        }
        if self.map_worst.len() > slack * 4 * WORST_PER_MAP {
            keep_worst_maps(&mut self.map_worst, WORST_PER_MAP);
        }
    }
}

fn rendered(map: &DisparityMap, x: usize, y: usize) -> Option<f32> {
    map.is_valid(x, y).then(|| map.get(x, y))
}

/// Marks `(x, y)` and its 8 neighbours.
fn mark_neighbourhood(needed: &mut [bool], w: usize, h: usize, x: usize, y: usize) {
    for ny in y.saturating_sub(1)..=(y + 1).min(h - 1) {
        for nx in x.saturating_sub(1)..=(x + 1).min(w - 1) {
            needed[ny * w + nx] = true;
        }
    }
}

/// The right-map columns a left pixel with disparity `d` reads: floor and ceil of x − d.
fn right_partners(x: usize, d: f32, w: usize) -> Option<(usize, usize, f64)> {
    let xr = x as f64 - f64::from(d);
    if !(xr >= 0.0 && xr <= (w - 1) as f64) {
        return None;
    }
    let x0 = xr.floor() as usize;
    Some((x0, (x0 + 1).min(w - 1), xr - x0 as f64))
}

impl SampleCheck<'_> {
    /// Audits `pixels` (indices y·w + x, the same for both views).
    pub fn run(&self, pixels: &[usize]) -> SampleOutcome {
        let (w, h) = (self.left.width, self.left.height);
        let mut needed = [vec![false; w * h], vec![false; w * h]];
        for &i in pixels {
            let (x, y) = (i % w, i / w);
            mark_neighbourhood(&mut needed[0], w, h, x, y);
            mark_neighbourhood(&mut needed[1], w, h, x, y);
            if let Some((x0, x1, _)) =
                rendered(self.left, x, y).and_then(|d| right_partners(x, d, w))
            {
                needed[1][y * w + x0] = true;
                needed[1][y * w + x1] = true;
            }
        }
        let left = Centres::compute(&self.camera, self.scene, View::Left, w, &needed[0]);
        let right = Centres::compute(&self.camera, self.scene, View::Right, w, &needed[1]);
        let views = [
            (View::Left, self.left, &left),
            (View::Right, self.right, &right),
        ];
        let mut outcome = pixels
            .par_iter()
            .flat_map_iter(|&i| {
                views
                    .iter()
                    .map(move |&(view, map, centres)| (i, view, map, centres))
            })
            .map(|(i, view, map, centres)| self.pixel(view, map, centres, &right, i % w, i / w))
            .fold(SampleOutcome::default, SampleOutcome::add)
            .reduce(SampleOutcome::default, SampleOutcome::merge);
        outcome.trim(1);
        outcome
    }

    /// Whether a ray beside the centre meets the centre's object on a surface that does not join
    /// the centre's there: its hit lies more than [`STEP_FOOTPRINTS`] footprints off the plane
    /// of the centre's triangle.
    fn steps_within_an_object(
        &self,
        view: View,
        (u, v): (f64, f64),
        offsets: &[(f64, f64); 4],
        centre: Option<Hit>,
        around: &[Option<Hit>; 4],
    ) -> bool {
        let Some(c) = centre else { return false };
        let rig = self.camera.rig;
        let tri = &self.scene.triangles[c.triangle];
        let footprint = SILHOUETTE_OFFSET_PX * c.t / rig.f_px();
        let x0 = rig.camera_x(view);
        around.iter().zip(offsets).any(|(a, (du, dv))| match a {
            Some(a) if a.object == c.object && a.triangle != c.triangle => {
                // The ray direction has z = −1: t is the planar depth.
                let d = rig.ray_direction(u + du, v + dv);
                let p = [x0 + a.t * d[0], a.t * d[1], a.t * d[2]];
                tri.plane_distance(p)
                    .is_some_and(|h| h > STEP_FOOTPRINTS * footprint)
            }
            _ => false,
        })
    }

    /// One pixel of one view.
    fn pixel(
        &self,
        view: View,
        map: &DisparityMap,
        centres: &Centres,
        right: &Centres,
        x: usize,
        y: usize,
    ) -> Outcome {
        let cam = &self.camera;
        let (u, v) = (x as f64 + 0.5, y as f64 + 0.5);
        let centre = centres.at(x, y);
        let o = SILHOUETTE_OFFSET_PX;
        let offsets = [(-o, 0.0), (o, 0.0), (0.0, -o), (0.0, o)];
        let around = offsets.map(|(du, dv)| cam.hit(self.scene, view, u + du, v + dv));
        let value = rendered(map, x, y);
        let expected = cam.disparity(centre);
        let mut out = Outcome::default();
        out.tally.pixels = 1;
        let issue = |kind, error| PixelIssue {
            sample: self.id.to_string(),
            category: self.category.to_string(),
            view: if view == View::Left { "left" } else { "right" }.to_string(),
            x,
            y,
            kind,
            rendered: value,
            expected,
            error,
        };

        let steep = around.iter().any(|a| match (cam.disparity(*a), expected) {
            (Some(d), Some(e)) => (d - e).abs() / o > GRAZING_GRADIENT,
            _ => false,
        }) || self.steps_within_an_object(view, (u, v), &offsets, centre, &around);
        if let Some(maps) = self.maps {
            let rays = PixelRays {
                view,
                x,
                y,
                dirs: std::array::from_fn(|k| {
                    let (du, dv) = if k == 0 { (0.0, 0.0) } else { offsets[k - 1] };
                    cam.rig.ray_direction(u + du, v + dv)
                }),
                hits: [centre, around[0], around[1], around[2], around[3]],
                steep,
                sample: self.id,
                category: self.category,
            };
            maps.check(self.scene, &rays, &mut out.maps, &mut out.map_issues);
        }
        let silhouette = steep
            || around
                .iter()
                .any(|a| a.map(|h| h.object) != centre.map(|h| h.object));
        if silhouette {
            out.tally.silhouette = 1;
            let matches = |h: &Option<Hit>| match (value, cam.disparity(*h)) {
                (Some(r), Some(d)) => (f64::from(r) - d).abs() <= TIGHT_PX,
                (None, None) => true,
                _ => false,
            };
            out.tally.silhouette_disagree =
                u64::from(!matches(&centre) && !around.iter().any(matches));
        } else {
            let (error, validity) = match (value, expected) {
                (Some(r), Some(e)) => ((f64::from(r) - e).abs(), false),
                (None, None) => (0.0, false),
                (Some(r), None) => (f64::from(r).abs(), true),
                (None, Some(e)) => (e, true),
            };
            out.tally.add_interior(error, validity);
            // Every non-zero error is a candidate for the worst list, so it names the largest
            // errors of a sound dataset too, not only those beyond the tolerance.
            if validity || error > 0.0 {
                out.issue = Some(issue(
                    if validity {
                        IssueKind::Validity
                    } else {
                        IssueKind::Value
                    },
                    error,
                ));
            }
            if view == View::Left
                && let (Some(r), Some(c)) = (value, centre)
                && let Some(e) = self.left_right(right, x, y, r, c)
            {
                out.tally.add_lr(e);
            }
        }
        if let Some(r) = value
            && self.flying(centres, &around, x, y, f64::from(r))
        {
            out.tally.flying = 1;
            let error = expected.map_or(f64::from(r), |e| (f64::from(r) - e).abs());
            // A flying pixel outranks a plain value error of the same pixel in the worst list.
            out.issue = Some(issue(IssueKind::Flying, error));
        }
        out
    }

    /// Whether value `r` lies between the surfaces ray casting sees at the pixel (centre and the
    /// rays around it) and at its 8 neighbours' centres, on none of them. Background counts as 0.
    fn flying(
        &self,
        centres: &Centres,
        around: &[Option<Hit>; 4],
        x: usize,
        y: usize,
        r: f64,
    ) -> bool {
        let (w, h) = (self.left.width, self.left.height);
        let cam = &self.camera;
        let mut seen: Vec<f64> = around
            .iter()
            .map(|a| cam.disparity(*a).unwrap_or(0.0))
            .collect();
        for ny in y.saturating_sub(1)..=(y + 1).min(h - 1) {
            for nx in x.saturating_sub(1)..=(x + 1).min(w - 1) {
                seen.push(cam.disparity(centres.at(nx, ny)).unwrap_or(0.0));
            }
        }
        let m = FLYING_MARGIN_PX;
        let lo = seen.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = seen.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        r > lo + m && r < hi - m && seen.iter().all(|s| (r - s).abs() > m)
    }

    /// |d_R(x − d_L) − d_L| for an interior left pixel whose point the right camera sees and whose
    /// two right neighbours show the same object (bilinear along the row); `None` when not checked.
    fn left_right(
        &self,
        right: &Centres,
        x: usize,
        y: usize,
        d_left: f32,
        centre: Hit,
    ) -> Option<f64> {
        let rig = self.camera.rig;
        let (u, v) = (x as f64 + 0.5, y as f64 + 0.5);
        let point = rig.unproject_left(u, v, centre.t);
        if !visible_from(rig, self.scene, View::Right, point) {
            return None;
        }
        let (x0, x1, t) = right_partners(x, d_left, self.right.width)?;
        let same = |xr: usize| right.at(xr, y).is_some_and(|h| h.object == centre.object);
        let (a, b) = (rendered(self.right, x0, y)?, rendered(self.right, x1, y)?);
        if !(same(x0) && same(x1)) {
            return None;
        }
        let d_right = f64::from(a) * (1.0 - t) + f64::from(b) * t;
        Some((d_right - f64::from(d_left)).abs())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::validate::audit::raycast::{NO_CUTOUT, Triangle};

    /// A quad of object `object` at planar depth `z`, from x = `x0` to `x1` (metres), tall enough
    /// to fill the view: two triangles.
    fn quad(object: usize, x0: f64, x1: f64, z0: f64, z1: f64) -> [Triangle; 2] {
        let (a, b) = ([x0, -10.0, -z0], [x1, -10.0, -z1]);
        let (c, d) = ([x1, 10.0, -z1], [x0, 10.0, -z0]);
        [
            Triangle {
                v: [a, b, c],
                object,
                cutout: NO_CUTOUT,
            },
            Triangle {
                v: [a, c, d],
                object,
                cutout: NO_CUTOUT,
            },
        ]
    }

    /// A 64×16 view with f = 64 px and a 10 cm baseline.
    fn rig() -> StereoRig {
        StereoRig {
            width: 64,
            height: 16,
            focal_mm: 36.0,
            sensor_width_mm: 36.0,
            baseline_m: 0.1,
        }
    }

    /// Whether pixel (x, 8) of the left view counts as a silhouette: the maps hold ray casting's
    /// own values, so only the silhouette rule is under test.
    fn silhouette_at(triangles: Vec<Triangle>, x: usize) -> bool {
        let rig = rig();
        let scene = RayScene::new(triangles, Vec::new());
        let camera = Camera {
            rig: &rig,
            clip_start: 0.01,
            clip_end: 100.0,
        };
        let mut maps = [DisparityMap::new(64, 16), DisparityMap::new(64, 16)];
        for (map, view) in maps.iter_mut().zip([View::Left, View::Right]) {
            for y in 0..16 {
                for x in 0..64 {
                    if let Some(d) =
                        camera.disparity(camera.hit(&scene, view, x as f64 + 0.5, y as f64 + 0.5))
                    {
                        map.data[y * 64 + x] = d as f32;
                        map.valid[y * 64 + x] = true;
                    }
                }
            }
        }
        let check = SampleCheck {
            id: "t",
            category: "t",
            camera,
            scene: &scene,
            left: &maps[0],
            right: &maps[1],
            maps: None,
        };
        let out = check.run(&[8 * 64 + x]);
        assert_eq!(out.tally.pixels, 2);
        out.tally.silhouette > 0
    }

    #[test]
    fn a_step_inside_one_object_is_a_silhouette_and_a_crease_is_not() {
        // f = 64 px, depth 2 m: pixel 40's centre (8.5 px right of the principal point) looks
        // along x = 8.5/64 · 2 m from the left camera; an edge 0.01 px to its left there.
        let rig = rig();
        let edge = |px: f64, z: f64| rig.camera_x(View::Left) + (px - 32.0) / rig.f_px() * z;
        // A front quad of object 0 ending just left of the centre, a back one 1 cm behind it.
        let mut step = quad(0, -5.0, edge(40.49, 2.0), 2.0, 2.0).to_vec();
        step.extend(quad(0, -5.0, 5.0, 2.01, 2.01));
        assert!(
            silhouette_at(step.clone(), 40),
            "a step of 1 cm inside one object"
        );
        // The same with the back quad another object's: a silhouette by the object rule too.
        for t in &mut step[2..] {
            t.object = 1;
        }
        assert!(silhouette_at(step, 40));
        // A crease at the same place: the surface bends there but stays one surface.
        let x = edge(40.49, 2.0);
        let mut crease = quad(0, -5.0, x, 2.0, 2.0).to_vec();
        crease.extend(quad(0, x, 5.0, 2.0, 2.6));
        assert!(
            !silhouette_at(crease, 40),
            "a crease counted as a silhouette"
        );
    }
}
