//! `stereogen stats --check` on a dataset the real generator rendered with real Blender: 24 scenes
//! of the tiny `crestereo` mix (64×48, disparity law uniform [3, 20] px, 2–3 objects per scene,
//! four categories). Its numbers are recounted here from the files, and the same rendered data
//! must fail the check once its dataset.json claims a law it was not drawn from.

use std::path::{Path, PathBuf};
use std::process::Output;
use test_support::{run_shown, stats_cmd};

use serde_json::Value;
use stereogen::dataset::{DatasetInfo, Manifest};
use stereogen::plan::Dist;

const SCENES: u64 = 24;

fn generate(dir: &Path) -> PathBuf {
    test_support::generate_tiny_dataset(dir, "data", SCENES, 3)
}

fn stats(data: &Path, out: &Path) -> (Output, String) {
    run_shown(
        stats_cmd(data)
            .args(["--check", "--plot", "--out"])
            .arg(out),
    )
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

#[test]
fn stats_check_passes_on_a_generated_mixed_dataset_and_fails_when_the_law_is_misstated() {
    let tmp = tempfile::tempdir().unwrap();
    let data = generate(tmp.path());
    let out = tmp.path().join("stats");
    let (o, text) = stats(&data, &out);
    assert!(
        o.status.success(),
        "stats --check failed on a correct dataset:\n{text}"
    );
    assert!(text.contains("verdict: PASS"), "{text}");

    // Recount everything from the files the generator wrote.
    let entries = Manifest::read(&data.join("manifest.jsonl")).unwrap();
    assert_eq!(entries.len() as u64, SCENES);
    let mut targets = Vec::new();
    let mut valid_values: Vec<f64> = Vec::new();
    let mut pixels = 0u64;
    for e in &entries {
        let spec = stereogen::dataset::read_scene_spec(&data.join(&e.files.scene)).unwrap();
        targets.extend(spec.target_disparities());
        for rel in [&e.files.disp_left, &e.files.disp_right] {
            let (m, _) = stereo_io::read_disparity_exr(&data.join(rel)).unwrap();
            pixels += m.data.len() as u64;
            valid_values.extend(
                m.data
                    .iter()
                    .zip(&m.valid)
                    .filter(|(_, v)| **v)
                    .map(|(d, _)| f64::from(*d)),
            );
        }
    }
    valid_values.sort_by(f64::total_cmp);
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("stats.json")).unwrap()).unwrap();
    let all = &report["overall"];
    assert_eq!(report["samples"], SCENES);
    assert_eq!(all["objects"]["count"], targets.len());
    assert_eq!(all["pixels"]["pixels"], pixels);
    assert_eq!(all["pixels"]["valid"], valid_values.len());
    let cat_samples: u64 = report["categories"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["samples"].as_u64().unwrap())
        .sum();
    assert_eq!(cat_samples, SCENES);
    // Streaming percentiles agree with the exact ones within two fine bins.
    let fine_bin = f(&report["pixel_range"][1]) / 16384.0;
    let exact_median = valid_values[valid_values.len() / 2];
    let median = f(&all["pixels"]["percentiles"]["p50"]);
    assert!(
        (median - exact_median).abs() <= 2.0 * fine_bin + 1e-6,
        "median {median} vs exact {exact_median}"
    );
    // KS distance recomputed independently of the stats module.
    let law = Dist::uniform(3.0, 20.0);
    let ks = stereogen::plan::dist::ks_distance(&targets, &law);
    assert!((f(&all["objects"]["ks_distance"]) - ks).abs() < 1e-12);
    // The sample is large enough for a meaningful gap check: 48-72 objects allow 7-10 bins.
    let gap = &all["pixels"]["gap_check"];
    assert!(gap["bins"].as_u64().unwrap() >= 6, "{gap}");
    assert_eq!(gap["empty"].as_array().unwrap().len(), 0);
    // Every category line says OK (or SKIP when the 24 draws missed it).
    for line in text
        .lines()
        .filter(|l| l.starts_with("OK") || l.starts_with("FAIL") || l.starts_with("SKIP"))
    {
        assert!(!line.starts_with("FAIL"), "{line}");
    }
    for name in [
        "stats_objects.png",
        "stats_pixels.png",
        "stats_categories.png",
        "stats_coverage.png",
    ] {
        let img = stereo_io::read_rgb(&out.join(name)).unwrap();
        assert!(img.width >= 1000 && img.height >= 600, "{name}");
        assert!(img.data.iter().any(|&b| b < 128), "{name} is blank");
    }

    // The same pixels against a law they were not drawn from: the dataset claims [3, 50] px (still a valid
    // recipe at 64 px width), while no object was aimed beyond 20 px.
    let info_path = data.join("dataset.json");
    let mut info: DatasetInfo =
        serde_json::from_str(&std::fs::read_to_string(&info_path).unwrap()).unwrap();
    info.recipe.placement.disparity_px = Dist::uniform(3.0, 50.0);
    std::fs::write(&info_path, serde_json::to_string_pretty(&info).unwrap()).unwrap();
    let (o, text) = stats(&data, &tmp.path().join("stats-wrong"));
    assert!(
        !o.status.success(),
        "stats --check passed against a misstated law:\n{text}"
    );
    assert!(text.contains("verdict: FAIL"), "{text}");
    let all_line = text.lines().find(|l| l.contains(" all ")).unwrap();
    assert!(
        all_line.starts_with("FAIL") && all_line.contains("KS") && all_line.contains("gap:"),
        "{all_line}"
    );
}

/// `([lo, hi] m)`: the depths sample `e` can hold, from its disparity range and rig
/// (`depth = f_px · baseline / disparity`), with 5% slack.
fn depth_bounds(e: &stereogen::dataset::ManifestEntry) -> [f64; 2] {
    let fb = e.f_px * e.baseline_m;
    let (mut lo, mut hi) = (f64::INFINITY, 0f64);
    for s in [e.disparity_left, e.disparity_right].into_iter().flatten() {
        lo = lo.min(fb / f64::from(s.max) * 0.95);
        hi = hi.max(fb / f64::from(s.min) * 1.05);
    }
    [lo, hi]
}

/// The number after `key` in `line`, up to the next space (`"a/b/c"` pieces split by `/`).
fn numbers_after(line: &str, key: &str) -> Vec<f64> {
    let rest = line
        .split(key)
        .nth(1)
        .unwrap_or_else(|| panic!("no {key}: {line}"));
    rest.split_whitespace()
        .next()
        .unwrap()
        .split('/')
        .map(|v| v.trim_end_matches('%').parse().unwrap())
        .collect()
}

/// A tiny dataset whose recipe asks for every map: `stats` names each map with the numbers the
/// files hold, `stats --plot` draws them, `sheet` gets a row per map under each sample's pair and
/// `report` shows them with the semantic class table.
#[test]
fn stats_sheet_and_report_show_every_map_of_a_generated_dataset() {
    const N: u64 = 4;
    let tmp = tempfile::tempdir().unwrap();
    let mut recipe = test_support::tiny_recipe("crestereo");
    recipe.render.outputs = stereogen::plan::OutputMap::ALL.to_vec();
    let recipe_path = tmp.path().join("maps.toml");
    std::fs::write(&recipe_path, toml::to_string(&recipe).unwrap()).unwrap();
    let data = tmp.path().join("data");
    test_support::run_ok(test_support::generate_cmd(&recipe_path, &data, N).args(["--seed", "7"]));
    let entries = Manifest::read(&data.join("manifest.jsonl")).unwrap();
    assert_eq!(entries.len() as u64, N);
    let info: DatasetInfo =
        serde_json::from_str(&std::fs::read_to_string(data.join("dataset.json")).unwrap()).unwrap();
    assert!(!info.semantic_classes.is_empty());

    // Recount from the files.
    let (mut depths, mut bounds) = (Vec::new(), [f64::INFINITY, 0f64]);
    let mut classes = std::collections::BTreeMap::<u16, u64>::new();
    let mut visible = Vec::new();
    for e in &entries {
        let [lo, hi] = depth_bounds(e);
        bounds = [bounds[0].min(lo), bounds[1].max(hi)];
        let mut ids = std::collections::BTreeSet::new();
        for view in ["left", "right"] {
            let path = |k| data.join(e.files.map(k, view).unwrap());
            let d = stereo_io::read_depth_exr(&path(stereo_io::MapKind::Depth)).unwrap();
            depths.extend(d.data.iter().filter(|&&z| z > 0.0).map(|&z| f64::from(z)));
            let s = stereo_io::read_id_png(&path(stereo_io::MapKind::Semantic)).unwrap();
            s.data
                .iter()
                .for_each(|&id| *classes.entry(id).or_default() += 1);
            let i = stereo_io::read_id_png(&path(stereo_io::MapKind::Instance)).unwrap();
            ids.extend(i.data.iter().copied().filter(|&id| id != 0));
        }
        visible.push(ids.len() as f64);
    }
    depths.sort_by(f64::total_cmp);

    let out = tmp.path().join("stats");
    let (o, text) = stats(&data, &out);
    assert!(o.status.success(), "{text}");
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("stats.json")).unwrap()).unwrap();
    let maps = &report["maps"];
    // Depth: the text's min/median/max are the files' (median within a histogram bin, 0.001
    // decade), and lie in the range the rig and the disparities allow.
    let line = |name: &str| {
        text.lines()
            .find(|l| l.starts_with(&format!("map {name}")))
            .unwrap_or_else(|| panic!("no line for map {name}:\n{text}"))
    };
    let mmm = numbers_after(line("depth"), "min/median/max ");
    let exact_median = depths[depths.len() / 2];
    assert!((mmm[0] - depths[0]).abs() < 1e-3, "{mmm:?}");
    assert!((mmm[2] - depths[depths.len() - 1]).abs() < 1e-3, "{mmm:?}");
    assert!(
        (mmm[1] / exact_median - 1.0).abs() < 0.005,
        "{mmm:?} vs {exact_median}"
    );
    assert!(
        bounds[0] <= mmm[0] && mmm[2] <= bounds[1],
        "{mmm:?} outside {bounds:?}"
    );
    assert_eq!(maps["depth"]["valid"], depths.len());
    assert!(
        f(&maps["depth"]["valid_fraction"]) > 0.9,
        "{}",
        maps["depth"]
    );
    // Normals: nested shares, the side a ray sees, unit length.
    let facing: Vec<f64> = (0..3).map(|k| f(&maps["normals"]["facing"][k])).collect();
    assert!(
        facing[0] <= facing[1] && facing[1] <= facing[2],
        "{facing:?}"
    );
    assert!(facing[2] > 0.95 && facing[0] > 0.05, "{facing:?}");
    assert!(f(&maps["normals"]["unit_fraction"]) > 0.99);
    assert!(line("normals").contains("within 30/60/90 deg"), "{text}");
    // Instances: visible per sample as recounted.
    let vis = numbers_after(line("instance"), "min/mean/max ");
    let mean = visible.iter().sum::<f64>() / visible.len() as f64;
    let (lo, hi) = visible
        .iter()
        .fold((f64::MAX, 0f64), |(a, b), &v| (a.min(v), b.max(v)));
    assert_eq!(
        vis,
        vec![lo, (mean * 100.0).round() / 100.0, hi],
        "{visible:?}"
    );
    assert!(lo >= 2.0, "the wall and at least one object: {visible:?}");
    // Semantic: each class's pixels as recounted, named by the dataset's table; shares sum to 1.
    let mut sum = 0.0;
    for c in maps["semantic"]["classes"].as_array().unwrap() {
        let id = c["id"].as_u64().unwrap() as u16;
        assert_eq!(c["pixels"], classes.get(&id).copied().unwrap_or(0), "{c}");
        if let Some(k) = info.semantic_classes.iter().find(|k| k.id == id) {
            assert_eq!(c["name"], k.name.as_str());
        }
        sum += f(&c["share"]);
    }
    assert!((sum - 1.0).abs() < 1e-9, "{sum}");
    let shares = line("semantic").split("pixel share: ").nth(1).unwrap();
    let text_sum: f64 = shares
        .split(", ")
        .map(|s| {
            s.rsplit_once(' ')
                .unwrap()
                .1
                .trim_end_matches('%')
                .parse::<f64>()
                .unwrap()
        })
        .sum();
    assert!((text_sum - 100.0).abs() < 0.3, "{shares}");
    assert!(shares.contains(&info.semantic_classes[0].name), "{shares}");
    let plot = stereo_io::read_rgb(&out.join("stats_maps.png")).unwrap();
    assert!(
        plot.data.iter().any(|&b| b < 128),
        "stats_maps.png is blank"
    );

    // The contact sheet: 2 x 2 samples, each its image and disparity, then four map rows.
    let sheet = tmp.path().join("sheet.png");
    let (o, t) = run_shown(
        test_support::stereogen_cmd(["sheet"])
            .arg(&data)
            .args(["--count", "4", "--cols", "2", "--out"])
            .arg(&sheet),
    );
    assert!(o.status.success(), "{t}");
    let img = stereo_io::read_rgb(&sheet).unwrap();
    let (w, h, gap) = (64, 48, 6);
    let tile_h = h + 4 * (h + gap);
    assert_eq!(
        (img.width, img.height),
        (2 * (2 * w + gap) + 3 * 2 * gap, 2 * tile_h + 3 * gap)
    );
    let px = |x: usize, y: usize| -> [u8; 3] {
        img.data[(y * img.width + x) * 3..][..3].try_into().unwrap()
    };
    for (i, e) in entries.iter().enumerate() {
        let (x0, y0) = (
            2 * gap + (i % 2) * (2 * w + 3 * gap),
            gap + (i / 2) * (tile_h + gap),
        );
        for (k, kind) in stereo_io::MapKind::ALL.into_iter().enumerate() {
            let y = y0 + (k + 1) * (h + gap);
            let colours: std::collections::HashSet<[u8; 3]> = (y..y + h)
                .flat_map(|y| (x0..x0 + 2 * w + gap).map(move |x| (x, y)))
                .map(|(x, y)| px(x, y))
                .collect();
            assert!(colours.len() > 2, "sample {} {kind} row: {colours:?}", e.id);
        }
        // The normals row's centre pixel of the left view is (n + 1) / 2 of the file's normal.
        let n = stereo_io::read_normals_exr(
            &data.join(e.files.map(stereo_io::MapKind::Normals, "left").unwrap()),
        )
        .unwrap();
        let c = n.data[(h / 2) * w + w / 2];
        let want = c.map(|v| ((v + 1.0) * 0.5 * 255.0).round() as u8);
        assert_eq!(px(x0 + w / 2, y0 + 2 * (h + gap) + h / 2), want, "{}", e.id);
    }

    // The report: the maps' section with the class table, and the maps under each gallery tile.
    let page = tmp.path().join("report.html");
    let (o, t) = run_shown(
        test_support::stereogen_cmd(["report", "--thumbnails", "2", "--out"])
            .arg(&page)
            .arg(&data),
    );
    assert!(o.status.success(), "{t}");
    let html = std::fs::read_to_string(&page).unwrap();
    assert!(html.contains("id=\"maps\"") && html.contains("id=\"semantic-classes\""));
    for c in &info.semantic_classes {
        assert!(
            html.contains(&format!("<td>{}</td>", c.name)),
            "class {} missing",
            c.name
        );
    }
    for kind in stereo_io::MapKind::ALL {
        assert_eq!(
            html.matches(&format!(" {kind}\" title=")).count(),
            2,
            "{kind} thumbnails"
        );
    }
    assert!(
        html.contains(line("depth")),
        "the stats line of depth is on the page"
    );
}
