//! The `sbatch` script of a data-parallel training run (`crestereo farm slurm`): N nodes, one
//! task (process) per node holding the node's devices, rank 0's host as the master, SIGTERM
//! `grace` seconds before the time limit so every rank stops after a common step with a
//! checkpoint (exit 75), and then the job requeues itself and resumes.

use std::path::Path;

/// What the script asks Slurm for and runs.
#[derive(Debug, Clone)]
pub struct SlurmJob {
    pub name: String,
    pub nodes: u32,
    /// Processes per node (1 for GPU nodes: a process holds all the node's devices).
    pub tasks_per_node: u32,
    pub cpus_per_task: u32,
    /// GPUs per node to request (`--gpus-per-node`), none for CPU runs.
    pub gpus_per_node: Option<u32>,
    pub partition: Option<String>,
    /// `HH:MM:SS` or Slurm's other forms.
    pub time: Option<String>,
    /// Seconds between the SIGTERM and the time limit.
    pub grace_s: u32,
    /// The job's directory: logs go to `logs/` below it; the job starts there.
    pub job_dir: String,
    /// The command each task runs: `crestereo train ...` with `--resume` (a fresh start when
    /// the run has no checkpoint yet, a continuation after a requeue).
    pub command: Vec<String>,
}

fn quote(s: &str) -> String {
    shlex::try_quote(s)
        .map(|q| q.into_owned())
        .unwrap_or_else(|_| format!("'{}'", s.replace('\0', "").replace('\'', r"'\''")))
}

impl SlurmJob {
    pub fn render(&self) -> String {
        let code = crate::interrupt::EXIT_INTERRUPTED;
        let log = Path::new(&self.job_dir).join("logs").join("train-%j.out");
        let mut lines = vec![
            "#!/bin/bash".to_string(),
            format!(
                "# Written by `crestereo farm slurm` (crestereo {}).",
                env!("CARGO_PKG_VERSION")
            ),
            format!(
                "# {} node(s) × {} process(es); every process holds its node's devices and is one rank.",
                self.nodes, self.tasks_per_node
            ),
            format!(
                "# SIGTERM {} s before the time limit: every rank stops after the same step, rank 0 writes a checkpoint,",
                self.grace_s
            ),
            format!(
                "# the ranks exit {code} and the job requeues itself; `--resume` continues the run where it stopped."
            ),
            format!("#SBATCH --job-name={}", self.name),
            format!("#SBATCH --nodes={}", self.nodes),
            format!("#SBATCH --ntasks-per-node={}", self.tasks_per_node),
            format!("#SBATCH --cpus-per-task={}", self.cpus_per_task),
        ];
        if let Some(g) = self.gpus_per_node {
            lines.push(format!("#SBATCH --gpus-per-node={g}"));
        }
        if let Some(p) = &self.partition {
            lines.push(format!("#SBATCH --partition={p}"));
        }
        if let Some(t) = &self.time {
            lines.push(format!("#SBATCH --time={t}"));
        }
        lines.extend([
            format!("#SBATCH --signal=TERM@{}", self.grace_s.max(1)),
            "#SBATCH --requeue".to_string(),
            "#SBATCH --open-mode=append".to_string(),
            format!("#SBATCH --output={}", log.display()),
            format!("#SBATCH --chdir={}", self.job_dir),
            "set -u".to_string(),
            "# Rank 0's host and a port of this job: every rank computes the same.".to_string(),
            "export MASTER_ADDR=\"$(scontrol show hostnames \"$SLURM_JOB_NODELIST\" | head -n 1)\""
                .to_string(),
            // The rule the ranks apply without it (topology.rs), so both agree.
            format!(
                "export MASTER_PORT=$(({} + SLURM_JOB_ID % {}))",
                super::topology::DEFAULT_MASTER_PORT,
                super::topology::SLURM_PORT_SPAN
            ),
            // A handler, not `trap ''` (which the tasks would inherit): the shell waits for the
            // step, whose tasks get the signal themselves.
            "trap 'echo \"crestereo: signal received; waiting for the ranks to stop after a common step\" >&2' TERM INT"
                .to_string(),
            format!(
                "srun --ntasks-per-node={} {}",
                self.tasks_per_node,
                self.command
                    .iter()
                    .map(|a| quote(a))
                    .collect::<Vec<_>>()
                    .join(" ")
            ),
            "rc=$?".to_string(),
            "echo \"crestereo: training step of job ${SLURM_JOB_ID} exited with code ${rc}\""
                .to_string(),
            format!("if [ \"$rc\" -eq {code} ]; then"),
            "  echo \"crestereo: interrupted; requeueing ${SLURM_JOB_ID}\"".to_string(),
            "  scontrol requeue \"${SLURM_JOB_ID}\"".to_string(),
            "fi".to_string(),
            "exit \"$rc\"".to_string(),
        ]);
        lines.join("\n") + "\n"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn script_asks_for_the_nodes_signal_and_requeue() {
        let job = SlurmJob {
            name: "crestereo-train".into(),
            nodes: 4,
            tasks_per_node: 1,
            cpus_per_task: 16,
            gpus_per_node: Some(8),
            partition: Some("gpu".into()),
            time: Some("24:00:00".into()),
            grace_s: 300,
            job_dir: "/scratch/job".into(),
            command: vec![
                "/opt/crestereo".into(),
                "train".into(),
                "--out".into(),
                "/scratch/run one".into(),
                "--resume".into(),
            ],
        };
        let s = job.render();
        for line in [
            "#SBATCH --nodes=4",
            "#SBATCH --ntasks-per-node=1",
            "#SBATCH --gpus-per-node=8",
            "#SBATCH --signal=TERM@300",
            "#SBATCH --requeue",
            "#SBATCH --output=/scratch/job/logs/train-%j.out",
            "srun --ntasks-per-node=1 /opt/crestereo train --out '/scratch/run one' --resume",
            "if [ \"$rc\" -eq 75 ]; then",
        ] {
            assert!(s.lines().any(|l| l == line), "missing `{line}` in\n{s}");
        }
    }
}
