//! Slurm: a job array that renders (one array task per shard, at most `--max-parallel` at once),
//! a merge-and-check job that depends on it (`afterany`: it runs even when a task failed, and
//! then reports what is missing), and `submit.sh`, which submits both.
//!
//! The `#SBATCH` lines come from [`SbatchOptions`] serialised field by field; commands are argv
//! lists quoted for the shell. Each render task runs `generate --shard auto` as a job step
//! (`srun`), so `scancel --signal=TERM`, preemption and the `--signal=TERM@GRACE` that Slurm sends
//! GRACE seconds before the time limit reach it; when it stops interrupted (exit
//! [`INTERRUPTED_EXIT_CODE`]) the script requeues the task, which resumes where it stopped.

use serde::Serialize;

use super::{FarmOptions, INTERRUPTED_EXIT_CODE, JobFile, TimeLimit, path};
use crate::dataset::shard::ShardArg;

/// `#SBATCH` options. Field names are sbatch's long options (`cpus_per_task` → `--cpus-per-task`);
/// `None` leaves an option out, `true` writes a bare flag.
#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "kebab-case")]
pub struct SbatchOptions {
    pub job_name: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub array: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub partition: Option<String>,
    pub ntasks: u32,
    pub cpus_per_task: u32,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gpus_per_task: Option<u32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mem: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub time: Option<String>,
    /// `TERM@SECS`: SIGTERM to the job steps SECS before the time limit, so `generate` stops
    /// cleanly (exit 75) and the script requeues the task before Slurm kills it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub signal: Option<String>,
    /// Log file (`%A` array job id, `%a` task id, `%j` job id).
    pub output: String,
    /// `append`: a requeued task adds to its log instead of replacing it.
    pub open_mode: String,
    /// Requeue on node failure or preemption.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub requeue: bool,
    /// Where the job starts: the job directory.
    pub chdir: String,
}

impl SbatchOptions {
    /// `#SBATCH --name=value` lines, sorted by option name (sbatch does not care about order).
    fn directives(&self) -> Vec<String> {
        let value = serde_json::to_value(self).expect("sbatch options serialise");
        let mut lines = Vec::new();
        for (key, v) in value.as_object().expect("a struct serialises to an object") {
            match v {
                serde_json::Value::Bool(true) => lines.push(format!("#SBATCH --{key}")),
                serde_json::Value::Bool(false) | serde_json::Value::Null => {}
                serde_json::Value::String(s) => lines.push(format!("#SBATCH --{key}={s}")),
                other => lines.push(format!("#SBATCH --{key}={other}")),
            }
        }
        lines
    }
}

/// A batch script: options, environment, then shell lines.
#[derive(Debug, Clone)]
pub struct BatchScript {
    pub comment: Vec<String>,
    pub options: SbatchOptions,
    pub env: Vec<(String, String)>,
    pub body: Vec<String>,
}

impl BatchScript {
    pub fn render(&self) -> String {
        let mut lines = vec!["#!/bin/bash".to_string()];
        lines.extend(self.comment.iter().map(|c| format!("# {c}")));
        lines.extend(self.options.directives());
        lines.push("set -u".into());
        lines.extend(
            self.env
                .iter()
                .map(|(k, v)| format!("export {k}={}", quote(v))),
        );
        lines.extend(self.body.iter().cloned());
        lines.join("\n") + "\n"
    }
}

/// One argv quoted for the shell.
pub fn command_line(argv: &[String]) -> String {
    argv.iter().map(|a| quote(a)).collect::<Vec<_>>().join(" ")
}

fn quote(s: &str) -> String {
    shlex::try_quote(s)
        .map(|q| q.into_owned())
        .unwrap_or_else(|_| format!("'{}'", s.replace('\0', "").replace('\'', r"'\''")))
}

fn options(
    opts: &FarmOptions,
    job_name: String,
    cpus: u32,
    time: Option<TimeLimit>,
    output: &str,
) -> SbatchOptions {
    SbatchOptions {
        job_name,
        array: None,
        partition: opts.partition.clone(),
        ntasks: 1,
        cpus_per_task: cpus,
        gpus_per_task: None,
        mem: opts.memory.clone(),
        time: time.map(TimeLimit::slurm),
        signal: None,
        output: path(&opts.job_dir.join("logs").join(output)),
        open_mode: "append".into(),
        requeue: false,
        chdir: path(&opts.job_dir),
    }
}

/// The render array: one task per shard.
pub fn render_script(opts: &FarmOptions) -> BatchScript {
    let mut o = options(
        opts,
        format!("{}-render", opts.name),
        opts.cpus(),
        opts.time_limit,
        "render-%A_%a.out",
    );
    o.signal = Some(format!("TERM@{}", opts.grace_s.max(1)));
    o.array = Some(match opts.max_parallel {
        Some(m) => format!("0-{}%{m}", opts.tasks - 1),
        None => format!("0-{}", opts.tasks - 1),
    });
    o.gpus_per_task = opts.gpus();
    o.requeue = true;
    let mut generate = vec![
        "srun".to_string(),
        "--ntasks=1".into(),
        path(&opts.stereogen),
    ];
    generate.extend(opts.generate_command(Some(ShardArg::Auto)).to_args());
    let code = INTERRUPTED_EXIT_CODE;
    BatchScript {
        comment: vec![
            format!("Written by `stereogen farm slurm` (stereogen {}).", env!("CARGO_PKG_VERSION")),
            format!("Renders samples {}..{} in {} shards; shard = SLURM_ARRAY_TASK_ID - SLURM_ARRAY_TASK_MIN.", opts.task.start, opts.task.start + opts.task.count, opts.tasks),
            format!("A task asks for {}.", opts.resources()),
            format!("Exit {code} = generate stopped on SIGTERM/SIGINT (scancel, preemption, or --signal {} s before the time limit): the task requeues itself and resumes.", opts.grace_s.max(1)),
        ],
        options: o,
        env: opts.env.clone(),
        body: vec![
            // A handler (not `trap ''`, which children would inherit): the shell waits for the
            // step, which gets the signal itself, to stop cleanly.
            "trap 'echo \"stereogen farm: signal received; waiting for generate to stop\" >&2' TERM INT".into(),
            command_line(&generate),
            "rc=$?".into(),
            "echo \"stereogen farm: task ${SLURM_ARRAY_TASK_ID} generate exited with code ${rc}\"".into(),
            format!("if [ \"$rc\" -eq {code} ]; then"),
            "  echo \"stereogen farm: interrupted; requeueing ${SLURM_ARRAY_JOB_ID}_${SLURM_ARRAY_TASK_ID}\"".into(),
            "  scontrol requeue \"${SLURM_ARRAY_JOB_ID}_${SLURM_ARRAY_TASK_ID}\"".into(),
            "fi".into(),
            "exit \"$rc\"".into(),
        ],
    }
}

/// The merge-and-check job.
pub fn merge_script(opts: &FarmOptions) -> BatchScript {
    let merge = [vec![path(&opts.stereogen)], opts.merge_args()].concat();
    let check = [vec![path(&opts.stereogen)], opts.check_args()].concat();
    BatchScript {
        comment: vec![
            format!("Written by `stereogen farm slurm` (stereogen {}).", env!("CARGO_PKG_VERSION")),
            "Runs after every render task ended (afterany): merges the shards and checks the dataset.".into(),
        ],
        options: options(
            opts,
            format!("{}-merge", opts.name),
            2,
            opts.merge_time_limit,
            "merge-%j.out",
        ),
        env: opts.env.clone(),
        body: vec!["set -e".into(), command_line(&merge), command_line(&check), "echo \"stereogen farm: merge and check passed\"".into()],
    }
}

/// `submit.sh`: submits the array, then the merge job depending on it.
pub fn submit_script(opts: &FarmOptions) -> String {
    let render = path(&opts.job_dir.join("render.sbatch"));
    let merge = path(&opts.job_dir.join("merge.sbatch"));
    let status = command_line(&[path(&opts.stereogen), "status".into(), path(&opts.out)]);
    [
        "#!/bin/bash".to_string(),
        format!(
            "# Written by `stereogen farm slurm`: submit with `bash {}`; re-submit to resume.",
            path(&opts.job_dir.join("submit.sh"))
        ),
        "set -euo pipefail".into(),
        format!("mkdir -p {}", quote(&path(&opts.job_dir.join("logs")))),
        // `--parsable` prints `id` or `id;cluster`.
        format!("render=$(sbatch --parsable {})", quote(&render)),
        "render=${render%%;*}".into(),
        format!(
            "merge=$(sbatch --parsable --dependency=afterany:${{render}} {})",
            quote(&merge)
        ),
        "merge=${merge%%;*}".into(),
        "echo \"render array: ${render}  merge and check: ${merge}\"".into(),
        format!("echo \"watch progress: {}\"", status.replace('"', "\\\"")),
    ]
    .join("\n")
        + "\n"
}

pub fn files(opts: &FarmOptions) -> anyhow::Result<Vec<JobFile>> {
    Ok(vec![
        ("submit.sh".into(), submit_script(opts), true),
        ("render.sbatch".into(), render_script(opts).render(), false),
        ("merge.sbatch".into(), merge_script(opts).render(), false),
    ])
}
