//! `stereogen farm slurm` on a real single-node Slurm cluster (Debian's `slurm-wlm` and `munge`,
//! started by `tests/farm/slurm-cluster.sh` under a temporary directory): the emitted
//! `submit.sh` renders a tiny dataset with a job array and a dependent merge-and-check job (the
//! merge writing WebDataset shards too, `--webdataset`); then a task is preempted with SIGTERM,
//! the file re-submitted, and the dataset is still complete.
//!
//! Without Slurm (not root, no packages and no `apt-get`) the test prints why and passes, unless
//! `CI` or `STEREOGEN_REQUIRE_SLURM` is set: then it fails, so CI cannot skip it silently.

use std::ffi::OsStr;
use std::path::Path;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use stereogen::dataset::{DatasetLayout, Manifest};
use test_support::files::walk;
use test_support::slurm_cluster::{Cluster, ROUND_TIMEOUT, cluster_or_skip};
use test_support::{farm_cmd, run_ok, stats_cmd, write_tiny_recipe};

/// `stereogen farm slurm` for `count` samples in `tasks` tasks, at most 2 at once; `extra` added.
fn write_job_files(recipe: &Path, out: &Path, count: u64, tasks: u64, extra: &[&OsStr]) {
    run_ok(
        farm_cmd("slurm", recipe, out, count, tasks)
            .args(["--max-parallel", "2", "--seed", "3"])
            .args(extra),
    );
}

/// Runs `submit.sh`; returns the render array's and the merge job's ids.
fn submit(cluster: &Cluster, out: &Path) -> (String, String) {
    let o = run_ok(cluster.cmd("bash").arg(out.join("jobs/submit.sh")));
    let text = String::from_utf8_lossy(&o.stdout).into_owned();
    // "render array: 12  merge and check: 13"
    let words: Vec<&str> = text.split_whitespace().collect();
    let after = |w: &str| {
        words
            .iter()
            .position(|x| *x == w)
            .map(|i| words[i + 1].to_string())
            .unwrap_or_else(|| panic!("no {w} in {text}"))
    };
    (after("array:"), after("check:"))
}

fn merge_log(out: &Path, merge_job: &str) -> String {
    std::fs::read_to_string(out.join(format!("jobs/logs/merge-{merge_job}.out")))
        .unwrap_or_default()
}

/// One dataset over the shards: every index once, each in its own shard, every file there with
/// its checksum, nothing else in the shard directories (no partial file, no lock).
fn assert_complete_farm(out: &Path, count: u64, tasks: u64) {
    let entries = Manifest::read(&out.join("manifest.jsonl")).expect("the merged manifest reads");
    let indices: Vec<u64> = entries.iter().map(|e| e.index).collect();
    assert_eq!(
        indices,
        (0..count).collect::<Vec<_>>(),
        "every index exactly once, in order"
    );
    let layout = DatasetLayout::new(out);
    for e in &entries {
        let shard = format!("shards/{:04}-of-{:04}/", e.index % tasks, tasks);
        for (key, rel) in e.files.all() {
            assert!(
                rel.to_string_lossy().starts_with(&shard),
                "sample {} file {} is in its shard {shard}",
                e.index,
                rel.display()
            );
            let path = layout.abs(rel);
            let sum = Command::new("sha256sum").arg(&path).output().unwrap();
            let sum = String::from_utf8_lossy(&sum.stdout)
                .split_whitespace()
                .next()
                .unwrap_or("")
                .to_string();
            assert_eq!(
                sum,
                e.sha256[key],
                "{} matches its checksum",
                path.display()
            );
        }
    }
    for k in 0..tasks {
        let shard = out.join(format!("shards/{k:04}-of-{tasks:04}"));
        let own = Manifest::read(&shard.join("manifest.jsonl")).unwrap();
        assert_eq!(
            own.len() as u64,
            (0..count).filter(|i| i % tasks == k).count() as u64,
            "{}",
            shard.display()
        );
        let mut files = 0;
        for entry in walk(&shard) {
            let name = entry.file_name().unwrap().to_string_lossy().into_owned();
            assert!(
                !stereo_io::is_temp_name(&name) && !name.starts_with(".stereogen.lock"),
                "partial or lock file left: {}",
                entry.display()
            );
            if entry.parent() != Some(shard.as_path()) {
                files += 1;
            }
        }
        assert_eq!(
            files,
            5 * own.len(),
            "{}: five files per sample, nothing else",
            shard.display()
        );
    }
}

/// Task logs are files people read with `less` or a web viewer: no terminal colour codes.
fn assert_plain_text_logs(out: &Path, tasks: u64) {
    let logs: Vec<_> = std::fs::read_dir(out.join("jobs/logs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    // One log per render task (render-%A_%a.out) and the merge job's.
    assert_eq!(logs.len() as u64, tasks + 1, "logs: {logs:?}");
    for log in logs {
        let text = std::fs::read(&log).unwrap();
        // A render task logs where its shard came from: the line tracing would colour.
        let render = log
            .file_name()
            .unwrap()
            .to_string_lossy()
            .starts_with("render-");
        assert!(
            !render || String::from_utf8_lossy(&text).contains("INFO shard "),
            "{} lacks the plain `INFO shard` line of --shard auto:\n{}",
            log.display(),
            String::from_utf8_lossy(&text)
        );
        assert!(
            !text.contains(&0x1b),
            "{} holds terminal escape codes:\n{}",
            log.display(),
            String::from_utf8_lossy(&text)
        );
    }
}

fn stats_check(out: &Path) -> Output {
    stats_cmd(out)
        .arg("--check")
        .arg("--out")
        .arg(out.join("stats-test"))
        .output()
        .unwrap()
}

/// Asserts that the merge-and-check job `merge` completed; `what` names it in the message, which
/// shows the job and its log.
fn assert_merge_completed(cluster: &Cluster, out: &Path, merge: &str, what: &str) {
    let merge_job = cluster.job(merge);
    assert_eq!(
        merge_job.get("JobState").map(String::as_str),
        Some("COMPLETED"),
        "{what}: {merge_job:?}\n{}",
        merge_log(out, merge)
    );
}

#[test]
fn a_slurm_array_renders_merges_and_survives_preemption() {
    let t0 = Instant::now();
    let dir = tempfile::tempdir().unwrap();
    let Some(cluster) = cluster_or_skip(&dir.path().join("slurm")) else {
        return;
    };
    let recipe = write_tiny_recipe(dir.path(), "crestereo");
    let (count, tasks) = (8, 4);

    // One submission: 4 array tasks (2 at once), then merge (into WebDataset shards too) and check.
    let out = dir.path().join("farm");
    let wds = dir.path().join("wds");
    let shard_args = [OsStr::new("--webdataset"), wds.as_os_str()];
    write_job_files(&recipe, &out, count, tasks, &shard_args);
    let (render, merge) = submit(&cluster, &out);
    cluster.wait_for_empty_queue("first farm");
    assert_merge_completed(&cluster, &out, &merge, "merge job");
    assert!(
        merge_log(&out, &merge).contains("stereogen farm: merge and check passed"),
        "{}",
        merge_log(&out, &merge)
    );
    for k in 0..tasks {
        let task = cluster.job(&format!("{render}_{k}"));
        assert_eq!(
            task.get("JobState").map(String::as_str),
            Some("COMPLETED"),
            "render task {k}: {task:?}"
        );
    }
    assert_complete_farm(&out, count, tasks);
    assert_plain_text_logs(&out, tasks);
    assert_eq!(
        stereo_io::open_dataset(&wds, None)
            .expect("the merge job's shards read")
            .len() as u64,
        count
    );
    let stats = stats_check(&out);
    assert!(
        stats.status.success(),
        "stats --check on the merged dataset: {}",
        String::from_utf8_lossy(&stats.stdout)
    );
    let first_round = t0.elapsed();

    // Preemption: SIGTERM to a task while it renders, then the same file again.
    let out = dir.path().join("preempted");
    write_job_files(&recipe, &out, count, tasks, &[]);
    let (render, _) = submit(&cluster, &out);
    let lock = out.join(format!("shards/0001-of-{tasks:04}/.stereogen.lock"));
    let t_wait = Instant::now();
    while !lock.exists() {
        assert!(
            t_wait.elapsed() < ROUND_TIMEOUT,
            "task 1 never started: {}",
            cluster.queue()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let task = format!("{render}_1");
    let t_term = Instant::now();
    // scancel's exit status is not checked: it is non-zero when the task ends while scancel
    // retries ("already completing"). What counts is that the task stops, checked below.
    let o = cluster.run("scancel", &["--verbose", "--signal=TERM", &task]);
    let said = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(
        said.contains("Signal 15 to job"),
        "scancel did not signal {task}: {said}"
    );
    while cluster
        .job(&task)
        .get("JobState")
        .is_some_and(|s| s == "RUNNING")
        && lock.exists()
    {
        assert!(
            t_term.elapsed() < Duration::from_secs(120),
            "task 1 ignored SIGTERM"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let stop_time = t_term.elapsed();
    cluster.wait_for_empty_queue("preempted farm");
    let (_, merge) = submit(&cluster, &out);
    cluster.wait_for_empty_queue("re-submitted farm");
    assert_merge_completed(&cluster, &out, &merge, "merge after re-submission");
    assert_complete_farm(&out, count, tasks);
    assert!(stats_check(&out).status.success());
    eprintln!(
        "farm_slurm: first farm ({count} samples, {tasks} tasks, 2 at once) {:.1} s; SIGTERM stopped a task in {:.2} s; whole test {:.1} s",
        first_round.as_secs_f64(),
        stop_time.as_secs_f64(),
        t0.elapsed().as_secs_f64()
    );
}
