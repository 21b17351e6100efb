//! Data-parallel training through the `crestereo` binary on Flex: two processes on the loopback
//! (per-rank batch 1) and two CPU replicas in one process follow a one-replica run with the
//! whole batch (2) step for step; a killed rank stops the other within seconds and `--resume`
//! continues the run exactly; SIGTERM stops every rank after a common step with a checkpoint
//! (exit 75).

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crestereo_train::parallel::compare::{checkpoint_weights, compare_runs, logged_losses};
use crestereo_train::tiny_run::{free_master_port, write_tiny_run};
use test_support::output_text as text;

/// The equality bound of the targets: losses and weights within 1e-5 relative.
const TOLERANCE: f64 = 1e-5;

fn crestereo() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_crestereo"));
    c.env("CRESTEREO_LOG", "warn").stdin(Stdio::null());
    c
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The tiny run of [`write_tiny_run`]: eight synthetic pairs, global batch 2, at the paper's
/// first-step learning rate.
fn setup(dir: &Path, steps: u64) -> PathBuf {
    write_tiny_run(dir, steps).unwrap()
}

/// `crestereo train` of one process with `extra` flags (one CPU thread unless told).
fn train(cfg: &Path, run: &Path, extra: &[&str]) -> Command {
    let mut c = crestereo();
    c.args([
        "train",
        "--config",
        s(cfg),
        "--out",
        s(run),
        "--no-progress",
    ]);
    if !extra.contains(&"--threads") {
        c.args(["--threads", "1"]);
    }
    c.args(extra);
    c
}

/// Rank `rank` of two processes on the loopback.
fn rank(cfg: &Path, run: &Path, rank: usize, port: u16, extra: &[&str]) -> Child {
    let r = rank.to_string();
    let p = port.to_string();
    let mut args = vec![
        "--nnodes",
        "2",
        "--node-rank",
        &r,
        "--master-addr",
        "127.0.0.1",
        "--master-port",
        &p,
        "--check-replicas-every",
        "1",
    ];
    args.extend(extra);
    train(cfg, run, &args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Both ranks of a two-process run on a fresh block of loopback ports, rank r with `extra[r]`.
fn both_ranks(cfg: &Path, run: &Path, extra: [&[&str]; 2]) -> [Child; 2] {
    let port = free_master_port();
    [
        rank(cfg, run, 0, port, extra[0]),
        rank(cfg, run, 1, port, extra[1]),
    ]
}

fn wait_ok(children: impl IntoIterator<Item = Child>) {
    for c in children {
        let o = c.wait_with_output().unwrap();
        assert!(o.status.success(), "a rank failed:\n{}", text(&o));
    }
}

fn losses(run: &Path) -> Vec<(u64, f64)> {
    logged_losses(run).unwrap()
}

fn weights(run: &Path, step: u64) -> Vec<(String, Vec<f32>)> {
    checkpoint_weights(run, step).unwrap()
}

/// Checks that `b` follows `a` (a one-replica run with the whole batch) within the tolerance.
fn assert_follows(a: &Path, b: &Path, step: u64, what: &str) {
    let d = compare_runs(a, b, step).unwrap();
    eprintln!("{what}: {d:?}");
    assert!(d.loss <= TOLERANCE, "losses differ by {:e}", d.loss);
    assert!(d.weight <= TOLERANCE, "weights differ by {:e}", d.weight);
}

#[test]
fn two_processes_train_as_one_with_the_whole_batch() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = setup(dir.path(), 5);
    let (one, two) = (dir.path().join("one"), dir.path().join("two"));
    let o = train(&cfg, &one, &["--threads", "2"]).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let t0 = Instant::now();
    wait_ok(both_ranks(&cfg, &two, [&[], &[]]));
    eprintln!("two processes: {:.1} s", t0.elapsed().as_secs_f64());
    assert_follows(
        &one,
        &two,
        5,
        "2 processes × batch 1 vs 1 process × batch 2, 5 steps",
    );
    // Only rank 0 writes: one log, checkpoints of every step (3 kept), no per-rank leftovers.
    assert_eq!(losses(&two).len(), 5);
    assert!(two.join("checkpoints/step-00000005/model.mpk").is_file());
}

#[test]
fn two_replicas_in_one_process_train_as_one() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = setup(dir.path(), 4);
    let (one, two) = (dir.path().join("one"), dir.path().join("two"));
    let o = train(&cfg, &one, &[]).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let o = train(
        &cfg,
        &two,
        &["--devices", "cpu,cpu", "--check-replicas-every", "1"],
    )
    .output()
    .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert_follows(&one, &two, 4, "2 replicas in one process vs 1, 4 steps");
    // One replica through the collective is the plain run, bit for bit.
    let via = dir.path().join("via");
    let o = train(&cfg, &via, &["--devices", "cpu"]).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(losses(&one), losses(&via));
    assert_eq!(weights(&one, 4), weights(&via, 4));
    // A batch the replicas cannot share is refused in one line.
    let o = train(&cfg, &dir.path().join("odd"), &["--devices", "3"])
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(
        text(&o).contains("cannot be split evenly over 3 replicas"),
        "{}",
        text(&o)
    );
}

/// Waits until `path` exists (at most `limit`).
fn wait_for(path: &Path, limit: Duration) {
    let t0 = Instant::now();
    while !path.exists() {
        assert!(t0.elapsed() < limit, "{} did not appear", path.display());
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn a_killed_rank_stops_the_other_and_resume_continues_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = setup(dir.path(), 8);
    let (straight, broken) = (dir.path().join("straight"), dir.path().join("broken"));
    wait_ok(both_ranks(&cfg, &straight, [&[], &[]]));

    let [r0, mut r1] = both_ranks(&cfg, &broken, [&[], &[]]);
    wait_for(
        &broken.join("checkpoints/step-00000003/state.json"),
        Duration::from_secs(300),
    );
    r1.kill().unwrap();
    let killed = Instant::now();
    let _ = r1.wait();
    let o = r0.wait_with_output().unwrap();
    let stopped_s = killed.elapsed().as_secs_f64();
    let said = text(&o);
    eprintln!("rank 0 stopped {stopped_s:.2} s after rank 1 was killed: {said}");
    assert!(!o.status.success(), "rank 0 went on:\n{said}");
    assert_eq!(o.status.code(), Some(69), "{said}");
    assert!(stopped_s < 60.0, "rank 0 took {stopped_s} s to stop");
    assert!(
        said.contains("rank 1 of 2") && said.contains("disconnected"),
        "{said}"
    );
    assert!(
        said.lines().filter(|l| l.starts_with("error")).count() == 1,
        "{said}"
    );

    // Resume: the two ranks continue from the newest whole checkpoint and end as the
    // straight run did.
    wait_ok(both_ranks(&cfg, &broken, [&["--resume"], &["--resume"]]));
    assert_eq!(losses(&straight), losses(&broken));
    assert_eq!(weights(&straight, 8), weights(&broken, 8));
}

#[test]
fn sigterm_stops_every_rank_after_a_common_step() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = setup(dir.path(), 12);
    let run = dir.path().join("run");
    let [r0, r1] = both_ranks(&cfg, &run, [&[], &[]]);
    wait_for(
        &run.join("checkpoints/step-00000002/state.json"),
        Duration::from_secs(300),
    );
    // Only rank 1 is signalled: the flag travels with the step's all-reduce.
    let status = Command::new("kill")
        .args(["-TERM", &r1.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let (o0, o1) = (
        r0.wait_with_output().unwrap(),
        r1.wait_with_output().unwrap(),
    );
    assert_eq!(o0.status.code(), Some(75), "{}", text(&o0));
    assert_eq!(o1.status.code(), Some(75), "{}", text(&o1));
    let stopped = losses(&run).last().unwrap().0;
    assert!(stopped < 12, "the run did not stop early");
    assert!(
        run.join(format!("checkpoints/step-{stopped:08}/model.mpk"))
            .is_file()
    );
    assert!(
        text(&o0).contains(&format!("after step {stopped}")),
        "{}",
        text(&o0)
    );
    // Requeued: the same command with --resume finishes the run.
    wait_ok(both_ranks(&cfg, &run, [&["--resume"], &["--resume"]]));
    assert_eq!(losses(&run).last().unwrap().0, 12);
}

#[test]
fn mismatched_ranks_are_refused_before_any_step() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = setup(dir.path(), 2);
    let run = dir.path().join("run");
    // Rank 1 with another seed: another run.
    let [r0, r1] = both_ranks(&cfg, &run, [&[], &["--seed", "6"]]);
    let (o0, o1) = (
        r0.wait_with_output().unwrap(),
        r1.wait_with_output().unwrap(),
    );
    assert!(!o0.status.success() && !o1.status.success());
    let (said0, said1) = (text(&o0), text(&o1));
    assert!(said0.contains("rank 1 runs another config"), "{said0}");
    assert!(said1.contains("rank 0 refused the run"), "{said1}");
    assert!(!run.join("checkpoints").exists() || losses(&run).is_empty());
}
