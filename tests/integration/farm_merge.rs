//! `stereogen generate --shard`, `merge` and `status` with the real CLI and renderer: shards
//! rendered by separate processes merge into one dataset that `stats`, `export`, the readers,
//! the audit, the report and the trainer take like any other; hand-made broken shard sets give
//! one line per problem and a non-zero exit; a second `generate` on a shard fails at once naming
//! the holder, and a killed holder's lock is detected as stale.

use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use crestereo_train::parallel::compare::logged_losses;
use stereogen::dataset::{DatasetLayout, Manifest};
use test_support::{
    audit_cmd, crestereo_train_cmd, export_cmd, generate_cmd, output_text as text, run_ok,
    stats_cmd, stereogen_cmd, two_shard_farm, write_tiny_recipe,
};

fn generate(recipe: &Path, out: &Path, count: u64, shard: &str) -> Command {
    let mut c = generate_cmd(recipe, out, count);
    c.args(["--seed", "9", "--shard", shard]);
    c
}

fn run(mut c: Command) -> Output {
    c.output().expect("run stereogen")
}

fn copy_tree(from: &Path, to: &Path) {
    let o = Command::new("cp")
        .arg("-a")
        .arg(from)
        .arg(to)
        .output()
        .unwrap();
    assert!(o.status.success(), "cp: {}", text(&o));
}

fn merge(out: &Path, verify: bool) -> Output {
    let mut c = stereogen_cmd(["merge"]);
    c.arg(out);
    if verify {
        c.arg("--verify");
    }
    run(c)
}

/// The `problem:` lines merge printed.
fn problems(o: &Output) -> Vec<String> {
    String::from_utf8_lossy(&o.stdout)
        .lines()
        .filter_map(|l| l.strip_prefix("problem: "))
        .map(str::to_string)
        .collect()
}

/// `crestereo train` on a merged dataset: two steps on 32×48 crops of the 64×48 samples, every
/// sample drawn once; both losses finite (a non-finite one would have skipped its step).
fn train_two_steps_on(data: &Path, run: &Path) {
    let cfg = run.with_extension("toml");
    std::fs::write(
        &cfg,
        format!(
            r#"steps = 2
batch_size = 2
accumulate = 1
iters = 2

[[datasets]]
path = "{}"

[augment]
crop = [32, 48]

[schedule]
warmup_steps = 1
decay_start = 1

[loader]
workers = 2

[log]
every = 1

[checkpoint]
every = 2
"#,
            data.display()
        ),
    )
    .unwrap();
    run_ok(&mut crestereo_train_cmd(&cfg, run));
    let state: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(run.join("checkpoints/step-00000002/state.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(state["step"], 2, "{state}");
    assert_eq!(state["skipped_steps"], 0, "{state}");
    // The data position: two batches of two, as many draws as the merged dataset holds.
    assert_eq!(state["samples"], 4, "{state}");
    let losses = logged_losses(run).unwrap();
    assert_eq!(
        losses.iter().map(|l| l.0).collect::<Vec<_>>(),
        [1, 2],
        "{losses:?}"
    );
    assert!(losses.iter().all(|l| l.1.is_finite()), "{losses:?}");
}

#[test]
fn shards_merge_into_one_dataset_and_broken_sets_list_each_problem() {
    let dir = tempfile::tempdir().unwrap();
    let out = two_shard_farm(dir.path(), 4);
    for (shard, indices) in [("0000-of-0002", vec![0, 2]), ("0001-of-0002", vec![1, 3])] {
        let own: Vec<u64> = Manifest::read(&out.join("shards").join(shard).join("manifest.jsonl"))
            .unwrap()
            .iter()
            .map(|e| e.index)
            .collect();
        assert_eq!(own, indices, "{shard} holds its own indices");
    }

    // Unmerged: readers say what to do instead of reading a part.
    let o = run(stats_cmd(&out));
    assert!(
        !o.status.success()
            && text(&o).contains("not merged yet")
            && text(&o).contains("stereogen merge"),
        "{}",
        text(&o)
    );
    let status = run({
        let mut c = stereogen_cmd(["status"]);
        c.arg(&out);
        c
    });
    let status_text = text(&status);
    assert!(
        status.status.success()
            && status_text.contains("0000-of-0002")
            && status_text.contains("finished")
            && status_text.contains("not merged yet"),
        "{status_text}"
    );

    // The broken copies are made before the good one is merged (merge writes into OUT).
    let broken = dir.path().join("broken");
    copy_tree(&out, &broken);

    let t0 = Instant::now();
    let o = merge(&out, true);
    let verify_time = t0.elapsed();
    assert!(o.status.success(), "{}", text(&o));
    assert!(
        text(&o).contains("merged 4 samples of 2 shards"),
        "{}",
        text(&o)
    );
    let merged = Manifest::read(&out.join("manifest.jsonl")).unwrap();
    assert_eq!(
        merged.iter().map(|e| e.index).collect::<Vec<_>>(),
        vec![0, 1, 2, 3]
    );
    assert!(
        merged[1].files.left.starts_with("shards/0001-of-0002"),
        "paths point into the shards: {:?}",
        merged[1].files.left
    );
    // The merged dataset reads like any other: stats --check, export, the stereo-io reader.
    let o = run({
        let mut c = stats_cmd(&out);
        c.arg("--check");
        c
    });
    assert!(
        o.status.success(),
        "stats --check on the merged dataset: {}",
        text(&o)
    );
    let exported = dir.path().join("middlebury");
    let o = run(export_cmd(&out, "middlebury", &exported));
    assert!(
        o.status.success(),
        "export of the merged dataset: {}",
        text(&o)
    );
    assert_eq!(stereo_io::open_dataset(&out, None).unwrap().len(), 4);
    train_two_steps_on(&out, &dir.path().join("train-run"));
    // The audit and the report take the merged dataset too (paths into the shards).
    let o = run({
        let mut c = audit_cmd(&out);
        c.args(["--all", "--every-pixel", "--check"]);
        c
    });
    assert!(
        o.status.success(),
        "audit --check on the merged dataset: {}",
        text(&o)
    );
    let report = dir.path().join("merged-report.html");
    let o = run({
        let mut c = stereogen_cmd(["report", "--out"]);
        c.arg(&report).arg(&out);
        c
    });
    assert!(
        o.status.success(),
        "report of the merged dataset: {}",
        text(&o)
    );
    let html = std::fs::read_to_string(&report).unwrap();
    assert!(
        html.contains("data:image/"),
        "the merged report embeds the gallery's pictures"
    );

    // One set with four problems: a missing index, a duplicated one, another recipe, a live lock.
    let shard1 = DatasetLayout::new(broken.join("shards/0001-of-0002"));
    let shard0 = DatasetLayout::new(broken.join("shards/0000-of-0002"));
    let lines0 = std::fs::read_to_string(shard0.manifest()).unwrap();
    let lines1 = std::fs::read_to_string(shard1.manifest()).unwrap();
    let first1 = lines1.lines().next().unwrap();
    // Shard 1 loses index 3 and gains shard 0's index 0.
    std::fs::write(
        shard1.manifest(),
        format!("{first1}\n{}\n", lines0.lines().next().unwrap()),
    )
    .unwrap();
    let info = std::fs::read_to_string(shard1.info()).unwrap();
    let mut json: serde_json::Value = serde_json::from_str(&info).unwrap();
    json["recipe_fingerprint"] = serde_json::Value::String("0000000000000000".into());
    std::fs::write(shard1.info(), serde_json::to_string_pretty(&json).unwrap()).unwrap();
    let mut holder = Command::new("sleep").arg("120").spawn().unwrap();
    let lock = serde_json::json!({"host": stereogen::dataset::lock::hostname(), "pid": holder.id(), "started_unix_s": stereogen::dataset::lock::unix_now(), "started": "now", "stereogen_version": "0.1.0", "command": "stereogen generate"});
    std::fs::write(shard0.lock(), lock.to_string()).unwrap();

    let o = merge(&broken, false);
    let _ = holder.kill();
    let _ = holder.wait();
    assert!(!o.status.success(), "a broken set fails: {}", text(&o));
    let lines = problems(&o);
    let has = |needle: &str| lines.iter().filter(|l| l.contains(needle)).count();
    assert_eq!(has("1 of 4 indices are missing: 3"), 1, "{lines:#?}");
    assert_eq!(
        has("index 0 is duplicated: 2 entries (shards/0000-of-0002, shards/0001-of-0002)"),
        1,
        "{lines:#?}"
    );
    assert_eq!(
        has("shards/0001-of-0002 was made with another recipe"),
        1,
        "{lines:#?}"
    );
    assert_eq!(
        has(&format!(
            "shards/0000-of-0002 is still locked: being written by pid {}",
            holder.id()
        )),
        1,
        "{lines:#?}"
    );
    assert!(
        !broken.join("manifest.jsonl").exists(),
        "nothing is written when anything is wrong"
    );
    assert!(
        text(&o).lines().last().unwrap().contains("problem(s)"),
        "{}",
        text(&o)
    );

    // A damaged file: found by --verify, named with its shard.
    let damaged = dir.path().join("damaged");
    copy_tree(&out, &damaged);
    let png = damaged.join(&merged[2].files.left);
    let mut bytes = std::fs::read(&png).unwrap();
    let last = bytes.len() - 20;
    bytes[last] ^= 0xff;
    std::fs::write(&png, bytes).unwrap();
    let o = merge(&damaged, true);
    assert!(!o.status.success());
    assert_eq!(
        problems(&o)
            .iter()
            .filter(|l| l.contains("SHA-256 differs"))
            .count(),
        1,
        "{}",
        text(&o)
    );
    eprintln!(
        "farm_merge: merge --verify of 4 samples took {:.3} s",
        verify_time.as_secs_f64()
    );
}

#[test]
fn a_second_generate_fails_naming_the_holder_and_a_killed_holder_is_stale() {
    let dir = tempfile::tempdir().unwrap();
    let recipe = write_tiny_recipe(dir.path(), "crestereo");
    let out = dir.path().join("farm");
    let lock = out.join("shards/0000-of-0002/.stereogen.lock");
    let mut first = generate(&recipe, &out, 400, "0/2")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    while !lock.exists() {
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "the first generate never took the lock"
        );
        assert!(
            first.try_wait().unwrap().is_none(),
            "the first generate ended early"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let t1 = Instant::now();
    let o = run(generate(&recipe, &out, 400, "0/2"));
    let second_took = t1.elapsed();
    let err = text(&o);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains(&format!(
            "pid {} on host {}",
            first.id(),
            stereogen::dataset::lock::hostname()
        )) && err.contains("--break-lock"),
        "{err}"
    );
    assert!(
        second_took < Duration::from_secs(5),
        "the second fails at once, not after {second_took:?}"
    );
    assert_eq!(err.trim().lines().count(), 1, "one line: {err}");

    // SIGKILL leaves the lock behind: status and merge call it killed, the next run breaks it.
    first.kill().unwrap();
    first.wait().unwrap();
    assert!(lock.exists());
    let status = text(&run({
        let mut c = stereogen_cmd(["status"]);
        c.arg(&out);
        c
    }));
    assert!(
        status.contains(&format!("killed (pid {}", first.id()))
            && status.contains("is not running"),
        "{status}"
    );
    let o = run(generate(&recipe, &out, 2, "0/2"));
    assert!(o.status.success(), "{}", text(&o));
    assert!(
        text(&o).contains("breaking the lock") && text(&o).contains(&format!("pid {}", first.id())),
        "{}",
        text(&o)
    );
    assert!(!lock.exists(), "the new run's lock goes with it");
}
