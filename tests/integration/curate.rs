//! Self-curation end to end, every part real: `stereogen generate` renders a small dataset, one
//! sample's disparity maps get a constant 4 px error (an inconsistent sample, planted), `crestereo
//! train` fine-tunes briefly on the rest, `crestereo score` scores every sample, and `stereogen
//! curate` flags the planted one, replaces it (resuming a round a failed render left open), keeps
//! it out of later `generate` runs, shows the round in `stats`, `audit` and `report`, and re-makes
//! the same curated dataset from recipe, seed and log on a fresh render.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use stereogen::dataset::curate::{REPLACEMENT_BASE, replacement_index};
use stereogen::dataset::{DatasetInfo, DatasetLayout, Manifest, ManifestEntry};
use test_support::{
    crestereo_bin, crestereo_train_cmd, generate_cmd, output_text as text_of, run_fails,
    run_ok as run, sha256_hex, stereogen_cmd, write_tiny_recipe,
};

const SEED: u64 = 3;
const COUNT: u64 = 6;
/// Fine-tuning steps on the five consistent samples (64×48, batch 2, no augmentation).
const STEPS: u64 = 200;

fn entries(root: &Path) -> Vec<ManifestEntry> {
    let mut e = Manifest::read(&DatasetLayout::new(root).manifest()).unwrap();
    e.sort_by_key(|e| e.index);
    e
}

fn generate(recipe: &Path, out: &Path) {
    run(generate_cmd(recipe, out, COUNT).args(["--seed", &SEED.to_string()]));
}

/// The error planted in one sample's disparity maps (px, every valid pixel of both views): what
/// a right camera whose sensor sits that far off would give. Twice Bad-2's threshold, so a model
/// that fits the other samples gets nearly every pixel of the planted one wrong.
const PLANTED_ERROR_PX: f32 = 4.0;

/// Plants the inconsistency in the sample of least mean disparity (where a constant error is
/// largest against what it shows) and returns that sample.
fn plant(root: &Path) -> ManifestEntry {
    let mean = |e: &ManifestEntry| e.disparity_left.map_or(0.0, |d| d.mean);
    let planted = entries(root)
        .into_iter()
        .min_by(|a, b| mean(a).total_cmp(&mean(b)))
        .unwrap();
    let layout = DatasetLayout::new(root);
    for rel in [&planted.files.disp_left, &planted.files.disp_right] {
        let path = layout.abs(rel);
        let (mut map, meta) = stereo_io::read_disparity_exr(&path).unwrap();
        for (d, valid) in map.data.iter_mut().zip(&map.valid) {
            if *valid {
                *d += PLANTED_ERROR_PX;
            }
        }
        stereo_io::write_disparity_exr(&path, &map, &meta).unwrap();
    }
    planted
}

/// A copy of the dataset without the planted sample, for fine-tuning.
fn the_rest(root: &Path, planted: &ManifestEntry, out: &Path) {
    let status = Command::new("cp")
        .arg("-r")
        .arg(root)
        .arg(out)
        .status()
        .unwrap();
    assert!(status.success());
    let kept: String = std::fs::read_to_string(root.join("manifest.jsonl"))
        .unwrap()
        .lines()
        .filter(|l| serde_json::from_str::<ManifestEntry>(l).unwrap().index != planted.index)
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(out.join("manifest.jsonl"), kept).unwrap();
}

fn fine_tune(dir: &Path, data: &Path) -> PathBuf {
    let config = dir.join("train.toml");
    std::fs::write(
        &config,
        format!(
            r#"steps = {STEPS}
batch_size = 2
accumulate = 1
iters = 2
[[datasets]]
path = "{}"
[augment]
crop = [48, 64]
swap_prob = 0.0
brightness = [1.0, 1.0]
contrast = [1.0, 1.0]
gamma = [1.0, 1.0]
right_warp_prob = 0.0
rotation_deg = 0.0
vertical_shift_px = 0.0
scale = [1.0, 1.0]
occlusion_prob = 0.0
[schedule]
lr = 0.001
warmup_steps = 0
decay_start = {STEPS}
[checkpoint]
every = 1000
"#,
            data.display()
        ),
    )
    .unwrap();
    let run_dir = dir.join("run");
    run(crestereo_train_cmd(&config, &run_dir).args(["--threads", "2"]));
    run_dir
}

/// Each sample's Bad-2 on all valid pixels, from a scores file.
fn bad2(scores: &Path) -> BTreeMap<String, f64> {
    std::fs::read_to_string(scores)
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).unwrap();
            (
                v["id"].as_str().unwrap().to_string(),
                v["all"]["bad_2"].as_f64().unwrap(),
            )
        })
        .collect()
}

fn curate(root: &Path, args: &[&str]) -> Command {
    let mut c = stereogen_cmd(["curate"]);
    c.arg(root)
        .args(args)
        .args(["--threads", "1", "--no-progress"]);
    c
}

fn info(root: &Path) -> DatasetInfo {
    DatasetLayout::new(root).read_info().unwrap()
}

#[test]
fn a_planted_inconsistent_sample_is_flagged_replaced_and_the_curation_replays() {
    let dir = tempfile::tempdir().unwrap();
    let recipe = write_tiny_recipe(dir.path(), "crestereo");
    let a = dir.path().join("a");
    generate(&recipe, &a);
    let planted = plant(&a);
    let rest = dir.path().join("rest");
    the_rest(&a, &planted, &rest);
    let weights = fine_tune(dir.path(), &rest);
    let scores = dir.path().join("scores.jsonl");
    run(Command::new(crestereo_bin())
        .arg("score")
        .arg(&a)
        .arg("--weights")
        .arg(&weights)
        .args(["--iters", "2", "--out"])
        .arg(&scores));

    // The planted sample is the one the model gets most wrong, clearly.
    let bad2 = bad2(&scores);
    eprintln!(
        "Bad-2 (%) after {STEPS} steps on the rest: {bad2:?}; planted {} (+{PLANTED_ERROR_PX} px)",
        planted.id
    );
    let runner_up = bad2
        .iter()
        .filter(|(id, _)| **id != planted.id)
        .map(|(_, b)| *b)
        .fold(f64::MIN, f64::max);
    assert!(
        bad2[&planted.id] > runner_up + 5.0,
        "the planted sample {} is not clearly the worst: {bad2:?}",
        planted.id
    );
    let rule = format!("{:.3}", (bad2[&planted.id] + runner_up) / 2.0);
    let rule = ["--scores", scores.to_str().unwrap(), "--max-bad2", &rule];

    // Listing changes nothing.
    let before = std::fs::read(a.join("manifest.jsonl")).unwrap();
    let o = run(&mut curate(&a, &rule));
    let said = text_of(&o);
    assert!(
        said.contains(&format!("1 of {COUNT} scored samples flagged")),
        "{said}"
    );
    assert!(said.contains(&planted.id), "{said}");
    assert_eq!(std::fs::read(a.join("manifest.jsonl")).unwrap(), before);
    assert!(!a.join("curation.jsonl").exists());

    // The replacement: fresh, the planted sample's category, a function of (seed, index, round).
    let taken = entries(&a).iter().map(|e| e.index).collect();
    let recipe_value = info(&a).recipe;
    let r = replacement_index(
        &recipe_value,
        SEED,
        planted.index,
        1,
        &planted.category,
        &taken,
    )
    .unwrap();
    assert!(r >= REPLACEMENT_BASE);

    // A round whose render fails stays open, the manifest untouched; re-running finishes it.
    let mut failing = curate(&a, &rule);
    failing
        .arg("--replace")
        .env("STEREOGEN_FAULT", format!("raise@{r}"));
    let err = run_fails(&mut failing);
    assert!(err.contains("the round stays open"), "{err}");
    assert_eq!(std::fs::read(a.join("manifest.jsonl")).unwrap(), before);
    let open = info(&a).curation;
    assert_eq!(open.len(), 1);
    assert!(!open[0].complete);
    let o = run(curate(&a, &rule).arg("--replace"));
    assert!(
        text_of(&o).contains("curation round(s) 1 finished"),
        "{}",
        text_of(&o)
    );

    // The dataset keeps its size; the planted sample is out, its replacement in, every file
    // as its checksum says.
    let now = entries(&a);
    assert_eq!(now.len() as u64, COUNT);
    assert!(now.iter().all(|e| e.index != planted.index));
    let new = now
        .iter()
        .find(|e| e.index == r)
        .expect("the replacement is in");
    assert_eq!(new.category, planted.category);
    assert!(
        new.notes
            .iter()
            .any(|n| n.contains(&format!("replaces {}", planted.id))),
        "{:?}",
        new.notes
    );
    for (key, rel) in new.files.all() {
        assert!(rel.starts_with("curation/round-0001"), "{}", rel.display());
        assert_eq!(sha256_hex(&a.join(rel)), new.sha256[key]);
    }
    let round = &info(&a).curation[0];
    assert!(round.complete);
    assert_eq!((round.replaced, round.scored), (1, COUNT));
    // The model is the checkpoint the scores were made with, resolved from the run folder.
    assert!(
        Path::new(&round.model).starts_with(&weights) && round.model.ends_with(".mpk"),
        "{}",
        round.model
    );
    assert_eq!(round.model_fingerprint.len(), 8);

    // A later `generate` of the same range does not bring the planted sample back.
    let o = run(generate_cmd(&recipe, &a, COUNT).args(["--seed", &SEED.to_string()]));
    assert!(text_of(&o).contains("0 rendered"), "{}", text_of(&o));
    assert_eq!(entries(&a), now);
    // Scores of the dataset before curation are refused now: they name a sample it no longer holds.
    let err = run_fails(&mut curate(&a, &rule));
    assert!(err.contains("does not hold"), "{err}");

    // stats, audit and the report show the round.
    let o = run(stereogen_cmd(["stats"]).arg(&a));
    assert!(
        text_of(&o).contains("curation round 1: 1 of 6 scored samples replaced"),
        "{}",
        text_of(&o)
    );
    let o = run(stereogen_cmd(["audit"]).arg(&a).args([
        "--samples",
        "1",
        "--pixels",
        "64",
        "--threads",
        "2",
    ]));
    assert!(
        text_of(&o).contains("every replacement is"),
        "{}",
        text_of(&o)
    );
    let page = dir.path().join("report.html");
    run(stereogen_cmd(["report"]).arg(&a).arg("--out").arg(&page));
    let html = std::fs::read_to_string(&page).unwrap();
    assert_eq!(html.matches("class=\"tile curation-tile\"").count(), 2);
    assert!(html.contains(&format!(
        "{} · {} · round 1: replaced",
        planted.id, planted.category
    )));

    // Recipe + seed + log re-make the curated dataset: the same samples, every file the same
    // bytes (the replacement too).
    let b = dir.path().join("b");
    generate(&recipe, &b);
    let log = a.join("curation.jsonl");
    run(&mut curate(&b, &["--from-log", log.to_str().unwrap()]));
    let remade = entries(&b);
    assert_eq!(
        remade
            .iter()
            .map(|e| (e.index, e.id.clone()))
            .collect::<Vec<_>>(),
        now.iter()
            .map(|e| (e.index, e.id.clone()))
            .collect::<Vec<_>>()
    );
    for (x, y) in now.iter().zip(&remade) {
        assert_eq!(x.sha256.len(), 5, "sample {}: {:?}", x.id, x.sha256);
        assert_eq!(x.sha256, y.sha256, "sample {}: a file differs", x.id);
    }
    let replayed = info(&b).curation;
    assert_eq!(replayed.len(), 1);
    assert!(replayed[0].complete);
}

/// A farm's merged output is curated with the replacements rendered as one more farm round
/// (`curate --shard K/N` per task, then one commit), and a later `merge` of its shards keeps the
/// curation: the finished rounds are applied again over what the shards hold. The scores file is
/// written here as `crestereo score` writes it (the file is the interface).
#[test]
fn a_merge_after_curation_keeps_the_rounds() {
    let dir = tempfile::tempdir().unwrap();
    let recipe = write_tiny_recipe(dir.path(), "crestereo");
    let farm = dir.path().join("farm");
    for shard in ["0/2", "1/2"] {
        run(generate_cmd(&recipe, &farm, 4).args(["--seed", "9", "--shard", shard]));
    }
    run(&mut test_support::merge_cmd(&farm));
    let merged = entries(&farm);
    assert_eq!(merged.len(), 4);
    let scores = dir.path().join("scores.jsonl");
    let mut text = String::from(
        "{\"scores\":\"crestereo-scores\",\"dataset\":\"farm\",\"weights\":\"w.mpk\",\"weights_crc32c\":\"00000001\",\"iters\":2,\"stages\":2,\"lr_tolerance_px\":1.0}\n",
    );
    for (i, e) in merged.iter().enumerate() {
        let bad2 = if e.index >= 2 { 90.0 } else { 10.0 };
        text.push_str(&format!(
            "{{\"id\":\"{}\",\"all\":{{\"bad_2\":{bad2}}},\"nonocc\":{{\"bad_2\":{bad2}}},\"index\":{i}}}\n",
            e.id
        ));
    }
    std::fs::write(&scores, text).unwrap();
    // The replacements as one more farm round: each task renders its part (here one after the
    // other), then the round is committed from the tasks' folders.
    let replace = ["--scores", scores.to_str().unwrap(), "--replace"];
    for shard in ["1/2", "0/2"] {
        let o = run(curate(&farm, &replace).args(["--shard", shard]));
        assert!(
            text_of(&o).contains("this task's part of the round"),
            "{}",
            text_of(&o)
        );
        assert_eq!(entries(&farm), merged, "a task commits nothing");
    }
    let o = run(&mut curate(&farm, &replace));
    assert!(
        text_of(&o).contains("curation round(s) 1 finished: 0 replacement(s) rendered"),
        "{}",
        text_of(&o)
    );
    let curated = entries(&farm);
    assert_eq!(curated.len(), 4);
    let records = stereogen::dataset::curate::read_records(&DatasetLayout::new(&farm)).unwrap();
    assert_eq!(records.len(), 2);
    for r in &records {
        let e = curated
            .iter()
            .find(|e| e.index == r.replacement_index)
            .unwrap();
        let shard = format!(
            "curation/round-0001/shards/{:04}-of-0002",
            r.replacement_index % 2
        );
        assert!(
            e.files.left.starts_with(&shard),
            "{}",
            e.files.left.display()
        );
        assert!(curated.iter().all(|e| e.index != r.index));
    }
    run(&mut test_support::merge_cmd(&farm));
    assert_eq!(entries(&farm), curated, "merge undid the curation");
    assert_eq!(info(&farm).curation.len(), 1);
}
