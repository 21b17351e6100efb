//! `crestereo farm slurm`: the sbatch script of a multi-node data-parallel training run.

use std::path::PathBuf;

use crate::parallel::slurm::SlurmJob;
use anyhow::{Context, Result, bail};

#[derive(Debug, clap::Subcommand)]
pub enum FarmCommand {
    /// Write `JOB_DIR/train.sbatch`: N nodes, one `crestereo train` process per node holding the
    /// node's devices; SIGTERM --grace seconds before the time limit stops every rank after a
    /// common step with a checkpoint, and the job requeues itself and resumes. Submit it with
    /// `sbatch JOB_DIR/train.sbatch`.
    Slurm(SlurmArgs),
}

#[derive(Debug, clap::Args)]
pub struct SlurmArgs {
    /// Folder of the job script and its logs (`logs/train-JOBID.out`).
    #[arg(long)]
    job_dir: PathBuf,
    #[arg(long, default_value_t = 1)]
    nodes: u32,
    /// Processes per node: 1 for GPU nodes (one process holds them all); more to run several
    /// CPU ranks on one machine.
    #[arg(long, default_value_t = 1)]
    tasks_per_node: u32,
    /// Devices of each process, as `crestereo train --devices` takes them (`cuda:0,...,cuda:7`);
    /// `cuda`/`vulkan` devices also set `--gpus-per-node`.
    #[arg(long, default_value = "cpu")]
    devices: String,
    #[arg(long, default_value_t = 8)]
    cpus_per_task: u32,
    #[arg(long)]
    partition: Option<String>,
    /// Time limit (`HH:MM:SS`, `D-HH:MM:SS`, ...).
    #[arg(long)]
    time: Option<String>,
    /// Seconds between SIGTERM and the time limit: enough for one training step and a
    /// checkpoint.
    #[arg(long, default_value_t = 300)]
    grace: u32,
    #[arg(long, default_value = "crestereo-train")]
    name: String,
    /// The `crestereo` binary the nodes run (default: this one).
    #[arg(long)]
    crestereo: Option<PathBuf>,
    /// `crestereo train` arguments (after `--`): at least --out, on a folder every node sees.
    #[arg(last = true, required = true, value_name = "TRAIN_ARGS")]
    train: Vec<String>,
}

pub fn run(command: &FarmCommand) -> Result<()> {
    let FarmCommand::Slurm(a) = command;
    if !a
        .train
        .iter()
        .any(|t| t == "--out" || t.starts_with("--out="))
    {
        bail!("the training arguments after `--` need --out (a run folder every node sees)");
    }
    for owned in [
        "--devices",
        "--nnodes",
        "--node-rank",
        "--master-addr",
        "--master-port",
        "--resume",
    ] {
        if a.train
            .iter()
            .any(|t| t == owned || t.starts_with(&format!("{owned}=")))
        {
            bail!("{owned} is set by the script; leave it out of the training arguments");
        }
    }
    let list = super::devices::parse_devices(&a.devices, super::DeviceKind::Cpu)?;
    let gpus = (list.kind != super::DeviceKind::Cpu).then_some(list.devices.len() as u32);
    let crestereo = match &a.crestereo {
        Some(p) => p.clone(),
        None => std::env::current_exe().context("cannot tell where this binary is")?,
    };
    let job_dir = std::path::absolute(&a.job_dir)?;
    std::fs::create_dir_all(job_dir.join("logs"))
        .with_context(|| format!("cannot create {}", job_dir.display()))?;
    let mut command = vec![
        crestereo.display().to_string(),
        "train".into(),
        "--devices".into(),
        a.devices.clone(),
        "--resume".into(),
    ];
    if list.kind == super::DeviceKind::Cpu {
        // CPU ranks use the cores Slurm gave their task, not the whole node.
        command.extend(["--threads".into(), a.cpus_per_task.to_string()]);
    }
    command.extend(a.train.iter().cloned());
    let job = SlurmJob {
        name: a.name.clone(),
        nodes: a.nodes,
        tasks_per_node: a.tasks_per_node,
        cpus_per_task: a.cpus_per_task,
        gpus_per_node: gpus,
        partition: a.partition.clone(),
        time: a.time.clone(),
        grace_s: a.grace,
        job_dir: job_dir.display().to_string(),
        command,
    };
    let script = job_dir.join("train.sbatch");
    stereo_io::write_bytes_atomically(&script, job.render().as_bytes())
        .with_context(|| format!("cannot write {}", script.display()))?;
    println!(
        "wrote {} ({} node(s) × {} process(es) × {} device(s)); submit with: sbatch {}",
        script.display(),
        a.nodes,
        a.tasks_per_node,
        list.devices.len(),
        script.display()
    );
    Ok(())
}
