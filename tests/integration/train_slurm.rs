//! Data-parallel training launched by Slurm, on the real single-node cluster the farm tests start:
//! `crestereo farm slurm` writes the job, `sbatch` runs two tasks (two CPU ranks, one sample per
//! rank and step) that must follow a one-process run with the whole batch of two, step for step;
//! then a job is sent SIGTERM mid-run, every rank stops after a common step (exit 75), the job
//! requeues itself and finishes the run, bit for bit as two ranks that were never stopped.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crestereo_train::parallel::compare::{compare_runs, logged_losses};
use crestereo_train::tiny_run::{free_master_port, write_tiny_run};
use test_support::crestereo_bin;
use test_support::output_text;
use test_support::slurm_cluster::{Cluster, ROUND_TIMEOUT, cluster_or_skip};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn crestereo(args: &[&str]) -> String {
    let o = Command::new(crestereo_bin())
        .args(args)
        .env("CRESTEREO_LOG", "warn")
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let text = output_text(&o);
    assert!(o.status.success(), "crestereo {args:?}:\n{text}");
    text
}

/// `crestereo farm slurm` for two CPU ranks on the one node, then `sbatch`; returns the job id.
fn submit(cluster: &Cluster, job_dir: &Path, cfg: &Path, run: &Path) -> String {
    crestereo(&[
        "farm",
        "slurm",
        "--job-dir",
        s(job_dir),
        "--nodes",
        "1",
        "--tasks-per-node",
        "2",
        "--devices",
        "cpu",
        "--cpus-per-task",
        "1",
        "--time",
        "00:10:00",
        "--grace",
        "30",
        "--",
        "--config",
        s(cfg),
        "--out",
        s(run),
        "--no-progress",
        "--check-replicas-every",
        "1",
    ]);
    let o = cluster.run("sbatch", &[s(&job_dir.join("train.sbatch"))]);
    let said = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        o.status.success(),
        "sbatch: {said}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    said.split_whitespace().last().unwrap().to_string()
}

fn job_log(job_dir: &Path, id: &str) -> String {
    std::fs::read_to_string(job_dir.join(format!("logs/train-{id}.out"))).unwrap_or_default()
}

#[test]
fn two_slurm_tasks_train_as_one_process_then_survive_a_requeue() {
    let dir = tempfile::tempdir().unwrap();
    let Some(cluster) = cluster_or_skip(&dir.path().join("slurm")) else {
        return;
    };
    let cfg = write_tiny_run(dir.path(), 6).unwrap();
    let one = dir.path().join("one");
    crestereo(&[
        "train",
        "--config",
        s(&cfg),
        "--out",
        s(&one),
        "--no-progress",
        "--threads",
        "2",
    ]);

    // Two tasks = two ranks (the master address and port from the job, the ranks from Slurm).
    let (job_dir, two) = (dir.path().join("job"), dir.path().join("two"));
    let id = submit(&cluster, &job_dir, &cfg, &two);
    cluster.wait_for_empty_queue("training job");
    let log = job_log(&job_dir, &id);
    assert!(
        log.contains("exited with code 0"),
        "job {id}: {:?}\n{log}\n{}",
        cluster.job(&id),
        cluster.logs()
    );
    let d = compare_runs(&one, &two, 6).unwrap();
    eprintln!(
        "Slurm, 2 tasks × batch 1 vs 1 process × batch 2: losses {:.2e}, weights {:.2e} (relative)",
        d.loss, d.weight
    );
    assert!(d.loss <= 1e-5 && d.weight <= 1e-5, "{d:?}");
    drop(cluster);
    a_preempted_slurm_training_requeues_and_resumes();
}

/// Preemption: SIGTERM to the job's tasks mid-run; every rank stops after one common step with a
/// checkpoint, exits 75, and the job requeues itself and finishes with the straight run's bits.
///
/// Called by the test above, after it: two local Slurm clusters at once would share ports.
fn a_preempted_slurm_training_requeues_and_resumes() {
    let t0 = Instant::now();
    let dir = tempfile::tempdir().unwrap();
    let Some(cluster) = cluster_or_skip(&dir.path().join("slurm")) else {
        return;
    };
    let long = write_tiny_run(dir.path(), 12).unwrap();
    let straight = dir.path().join("straight");
    two_ranks_on_the_loopback(&long, &straight);
    let (job_dir, run) = (dir.path().join("job-requeue"), dir.path().join("requeued"));
    let id = submit(&cluster, &job_dir, &long, &run);
    let started = Instant::now();
    while !run.join("checkpoints/step-00000003/state.json").exists() {
        assert!(
            started.elapsed() < ROUND_TIMEOUT,
            "the job never reached step 3: {}\n{}",
            cluster.queue(),
            job_log(&job_dir, &id)
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let o = cluster.run("scancel", &["--signal=TERM", &id]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    cluster.wait_for_empty_queue("requeued training job");
    let log = job_log(&job_dir, &id);
    assert!(log.contains("exited with code 75"), "{log}");
    assert!(log.contains("interrupted; requeueing"), "{log}");
    assert!(
        log.contains("exited with code 0"),
        "the requeued job did not finish:\n{log}"
    );
    let losses = logged_losses(&run).unwrap();
    assert_eq!(losses.last().unwrap().0, 12);
    // The same two ranks straight through: the stop and requeue changed no bit.
    let d = compare_runs(&straight, &run, 12).unwrap();
    eprintln!(
        "Slurm, preempted and requeued vs a straight two-rank run: losses {:.2e}, weights {:.2e}; test {:.1} s",
        d.loss,
        d.weight,
        t0.elapsed().as_secs_f64()
    );
    assert_eq!((d.loss, d.weight), (0.0, 0.0));
    assert_eq!(losses, logged_losses(&straight).unwrap());
}

/// Two ranks of `cfg` on the loopback, outside Slurm (one CPU thread each).
fn two_ranks_on_the_loopback(cfg: &Path, run: &Path) {
    let port = free_master_port();
    let ranks: Vec<_> = (0..2)
        .map(|r| {
            Command::new(crestereo_bin())
                .args([
                    "train",
                    "--config",
                    s(cfg),
                    "--out",
                    s(run),
                    "--no-progress",
                ])
                .args([
                    "--threads",
                    "1",
                    "--nnodes",
                    "2",
                    "--node-rank",
                    &r.to_string(),
                ])
                .args([
                    "--master-addr",
                    "127.0.0.1",
                    "--master-port",
                    &port.to_string(),
                ])
                .env("CRESTEREO_LOG", "warn")
                .stdin(Stdio::null())
                .stdout(Stdio::piped())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap()
        })
        .collect();
    for r in ranks {
        let o = r.wait_with_output().unwrap();
        assert!(o.status.success(), "{}", output_text(&o));
    }
}
