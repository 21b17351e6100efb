//! The render-settings study (`generator/bench/render_study.py`, the command the README shows)
//! end to end at a tiny size: real `stereogen plan`/`render`, real Cycles renders of the reference
//! and the candidates, metrics by scikit-image, the table and the Pareto plot.

use std::path::Path;
use std::process::Command;

use serde_json::Value;
use test_support::stereogen_bin;

#[test]
fn the_study_renders_reference_and_candidates_and_reports_per_category() {
    let tmp = tempfile::tempdir().unwrap();
    let work = tmp.path().join("study");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("generator/bench/render_study.py");
    let run = |extra: &[&str]| {
        let out = Command::new("python3")
            .arg(&script)
            .args([
                "--work",
                work.to_str().unwrap(),
                "--size",
                "96x54",
                "--per-category",
                "1",
            ])
            .args([
                "--reference-samples",
                "32",
                "--candidates",
                "s4,s8,s32,s8-dn,s32-dn,s32-shared",
            ])
            .arg("--stereogen")
            .arg(stereogen_bin())
            .args(extra)
            .output()
            .expect("python3 runs the study");
        let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
        assert!(
            out.status.success(),
            "{stdout}\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        stdout
    };
    let stdout = run(&[]);
    assert!(stdout.contains("| setting | CPU s/view |"), "{stdout}");

    let results: Value =
        serde_json::from_str(&std::fs::read_to_string(work.join("results.json")).unwrap()).unwrap();
    let rows = results["rows"].as_array().unwrap();
    let cats = ["hole", "reflective", "shapenet", "tree"];
    assert_eq!(
        rows.len(),
        6 * cats.len(),
        "every candidate in every category"
    );
    let row = |setting: &str, cat: &str| {
        rows.iter()
            .find(|r| r["setting"] == setting && r["category"] == cat)
            .unwrap_or_else(|| panic!("no row {setting}/{cat}"))
    };
    for r in rows {
        let (psnr, ssim, lr) = (
            r["psnr_db"].as_f64().unwrap(),
            r["ssim"].as_f64().unwrap(),
            r["lr_disagreement"].as_f64().unwrap(),
        );
        assert!(psnr > 5.0 && psnr < 80.0, "{r}");
        assert!(ssim > 0.0 && ssim <= 1.0, "{r}");
        assert!((0.0..100.0).contains(&lr), "{r}");
        assert!(r["cpu_s_per_view"].as_f64().unwrap() > 0.0, "{r}");
        for key in [
            "noise_correlation_same_pixel",
            "noise_correlation_stereo_match",
        ] {
            let v = r[key].as_f64().unwrap_or_else(|| panic!("{key}: {r}"));
            assert!((-1.0..=1.0).contains(&v), "{r}");
        }
    }
    // One Cycles seed for both views puts the same sampling noise at the same pixel of each; the
    // views' own seeds (what a plan now holds) do not: pooled over the categories, the residual
    // noise of the shared-seed render correlates between the views where the other does not.
    let same_pixel = |setting: &str| {
        cats.iter()
            .map(|c| {
                row(setting, c)["noise_correlation_same_pixel"]
                    .as_f64()
                    .unwrap()
            })
            .sum::<f64>()
            / cats.len() as f64
    };
    let (shared, own) = (same_pixel("s32-shared"), same_pixel("s32"));
    assert!(
        shared > own + 0.03,
        "shared seed r = {shared}, own seeds r = {own}"
    );
    // Noise falls with samples: without the denoiser, 32 samples are closer to the reference
    // than 4 (expected 9 dB apart at equal reference noise), and they cost more.
    for cat in cats {
        let (s4, s32) = (row("s4", cat), row("s32", cat));
        assert!(
            s32["psnr_db"].as_f64().unwrap() > s4["psnr_db"].as_f64().unwrap() + 2.0,
            "{s4} {s32}"
        );
        assert!(s32["cpu_s_per_view"].as_f64().unwrap() > s4["cpu_s_per_view"].as_f64().unwrap());
    }
    // Our PSNR formula agrees with scikit-image's on the images it was computed from.
    assert!(
        results["psnr_check"]["max_abs_difference_db"]
            .as_f64()
            .unwrap()
            < 1e-9
    );
    assert_eq!(results["old_default"], "s32-dn");
    assert!(
        results["recommended"].is_string(),
        "{}",
        results["recommended"]
    );
    for cat in cats {
        assert!(!results["pareto_front"][cat].as_array().unwrap().is_empty());
        assert!(
            results["reference_convergence"][cat]["psnr_half_vs_half_db"]
                .as_f64()
                .unwrap()
                > 5.0
        );
    }
    let png = std::fs::read(work.join("pareto.png")).unwrap();
    assert!(png.starts_with(b"\x89PNG\r\n\x1a\n") && png.len() > 10_000);

    // A re-run renders nothing again (every render is kept) and reports the same numbers.
    let times = std::fs::read_to_string(work.join("times.jsonl")).unwrap();
    run(&[]);
    assert_eq!(
        std::fs::read_to_string(work.join("times.jsonl")).unwrap(),
        times
    );
    let again: Value =
        serde_json::from_str(&std::fs::read_to_string(work.join("results.json")).unwrap()).unwrap();
    assert_eq!(again["rows"], results["rows"]);
}
