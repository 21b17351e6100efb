//! A single-node Slurm cluster for the farm and training tests (Debian's `slurm-wlm` and
//! `munge`, started by `tests/farm/slurm-cluster.sh` under a temporary directory).
//!
//! Without Slurm (not root, no packages and no `apt-get`) [`cluster_or_skip`] prints why and the
//! test passes, unless `CI` or `STEREOGEN_REQUIRE_SLURM` is set: then it fails, so CI cannot skip
//! it silently.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::MutexGuard;
use std::time::{Duration, Instant};

const SCRIPT: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../tests/farm/slurm-cluster.sh"
);
/// No farm round of this test takes near this long (one is about 20 s on 2 cores).
pub const ROUND_TIMEOUT: Duration = Duration::from_secs(600);

/// The cluster's daemons, stopped (by their pid files) when this is dropped, pass or fail.
pub struct Cluster {
    dir: PathBuf,
    conf: PathBuf,
    /// This machine's node, one cluster at a time; released after the daemons are stopped
    /// (fields drop after `Drop::drop`).
    _node: MutexGuard<'static, ()>,
}

impl Cluster {
    /// Starts the cluster, or says why it cannot.
    pub fn start(dir: &Path) -> Result<Self, String> {
        let node = crate::turns::slurm_node();
        // A port of our own, so a cluster left by another run does not answer.
        let port = 20_000 + std::process::id() % 20_000;
        // The script installs Slurm with apt-get where it is missing.
        let apt = crate::turns::apt();
        let o = Command::new("bash")
            .args([SCRIPT, "start"])
            .arg(dir)
            .env("STEREOGEN_INSTALL_SLURM", "1")
            .env("STEREOGEN_SLURM_PORT", port.to_string())
            .stdin(Stdio::null())
            .output()
            .map_err(|e| format!("cannot run {SCRIPT}: {e}"))?;
        drop(apt);
        let cluster = Self {
            dir: dir.to_path_buf(),
            conf: dir.join("slurm.conf"),
            _node: node,
        };
        if !o.status.success() {
            return Err(format!(
                "{SCRIPT} start failed ({}): {}",
                o.status,
                String::from_utf8_lossy(&o.stderr).trim()
            ));
        }
        Ok(cluster)
    }

    pub fn cmd(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        c.env("SLURM_CONF", &self.conf).stdin(Stdio::null());
        c
    }

    pub fn run(&self, program: &str, args: &[&str]) -> Output {
        self.cmd(program)
            .args(args)
            .output()
            .unwrap_or_else(|e| panic!("{program}: {e}"))
    }

    /// Fields of `scontrol show job ID` (for an array: its first task), e.g. `JobState`.
    pub fn job(&self, id: &str) -> BTreeMap<String, String> {
        let o = self.run("scontrol", &["show", "job", "--oneliner", id]);
        let text = String::from_utf8_lossy(&o.stdout);
        text.lines()
            .next()
            .unwrap_or("")
            .split_whitespace()
            .filter_map(|kv| kv.split_once('='))
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect()
    }

    /// Every job's `id state` as squeue sees them (pending, running, ...).
    pub fn queue(&self) -> String {
        String::from_utf8_lossy(&self.run("squeue", &["-h", "-o", "%i %T"]).stdout).into_owned()
    }

    pub fn wait_for_empty_queue(&self, what: &str) {
        let t0 = Instant::now();
        while !self.queue().trim().is_empty() {
            assert!(
                t0.elapsed() < ROUND_TIMEOUT,
                "{what}: jobs still queued after {ROUND_TIMEOUT:?}:\n{}\n{}",
                self.queue(),
                self.logs()
            );
            std::thread::sleep(Duration::from_millis(500));
        }
    }

    pub fn logs(&self) -> String {
        let tail = |name: &str| {
            std::fs::read_to_string(self.dir.join("log").join(name))
                .unwrap_or_default()
                .lines()
                .rev()
                .take(15)
                .collect::<Vec<_>>()
                .join("\n")
        };
        format!(
            "slurmctld.log (last lines, reversed):\n{}\nslurmd.log:\n{}",
            tail("slurmctld.log"),
            tail("slurmd.log")
        )
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let _ = Command::new("bash")
            .args([SCRIPT, "stop"])
            .arg(&self.dir)
            .stdin(Stdio::null())
            .output();
    }
}

/// The cluster, or `None` after printing why not (a failure where Slurm is required).
pub fn cluster_or_skip(dir: &Path) -> Option<Cluster> {
    let required =
        std::env::var_os("CI").is_some() || std::env::var_os("STEREOGEN_REQUIRE_SLURM").is_some();
    match Cluster::start(dir) {
        Ok(c) => Some(c),
        Err(why) if required => panic!(
            "a Slurm cluster is required here (CI or STEREOGEN_REQUIRE_SLURM is set) but: {why}"
        ),
        Err(why) => {
            eprintln!("SKIPPED: no local Slurm cluster: {why}");
            None
        }
    }
}
