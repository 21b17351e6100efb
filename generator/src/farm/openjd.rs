//! Open Job Description (`jobtemplate-2023-09`): a `Render` step whose task parameter `Shard`
//! ranges over the shards, then `Merge` and `Check` steps that depend on it. Cancelling a task
//! sends SIGTERM and waits `--grace` seconds (`NOTIFY_THEN_TERMINATE`) before killing it, the
//! time `generate` has to stop cleanly. How many tasks run at once is the scheduler's setting
//! (e.g. a Deadline Cloud queue's max workers), not the template's.

use std::collections::BTreeMap;

use serde::Serialize;

use super::{FarmOptions, JobFile, TimeLimit, path};

pub const SPECIFICATION_VERSION: &str = "jobtemplate-2023-09";

#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct JobTemplate {
    pub specification_version: String,
    pub name: String,
    pub description: String,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub job_environments: Vec<Environment>,
    pub steps: Vec<Step>,
}

#[derive(Debug, Clone, Serialize)]
pub struct Environment {
    pub name: String,
    pub variables: BTreeMap<String, String>,
}

#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Step {
    pub name: String,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub dependencies: Vec<Dependency>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub parameter_space: Option<ParameterSpace>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub host_requirements: Option<HostRequirements>,
    pub script: StepScript,
}

/// What a worker host must have to run a step's tasks (`amount.worker.vcpu`, `amount.worker.gpu`).
#[derive(Debug, Clone, Serialize)]
pub struct HostRequirements {
    pub amounts: Vec<AmountRequirement>,
}

#[derive(Debug, Clone, Serialize)]
pub struct AmountRequirement {
    pub name: String,
    pub min: u32,
}

#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Dependency {
    pub depends_on: String,
}

#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct ParameterSpace {
    pub task_parameter_definitions: Vec<TaskParameter>,
}

#[derive(Debug, Clone, Serialize)]
pub struct TaskParameter {
    pub name: String,
    #[serde(rename = "type")]
    pub kind: String,
    /// A range expression: `0-63`.
    pub range: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct StepScript {
    pub actions: Actions,
}

#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Actions {
    pub on_run: Action,
}

#[derive(Debug, Clone, Serialize)]
pub struct Action {
    pub command: String,
    pub args: Vec<String>,
    /// Seconds the action may run; then it is cancelled like any other (SIGTERM, `generate`
    /// stops cleanly, the task fails and a retry resumes it).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub timeout: Option<u64>,
    pub cancelation: Cancelation,
}

#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Cancelation {
    pub mode: String,
    pub notify_period_in_seconds: u64,
}

/// The task parameter naming the shard.
const SHARD_PARAM: &str = "Shard";

fn action(opts: &FarmOptions, args: Vec<String>, time_limit: Option<TimeLimit>) -> Action {
    Action {
        command: path(&opts.stereogen),
        args,
        timeout: time_limit.map(TimeLimit::seconds),
        cancelation: Cancelation {
            mode: "NOTIFY_THEN_TERMINATE".into(),
            notify_period_in_seconds: opts.grace_s,
        },
    }
}

fn step(
    name: &str,
    depends_on: Option<&str>,
    parameter_space: Option<ParameterSpace>,
    host_requirements: Option<HostRequirements>,
    on_run: Action,
) -> Step {
    Step {
        name: name.into(),
        dependencies: depends_on
            .map(|d| {
                vec![Dependency {
                    depends_on: d.into(),
                }]
            })
            .unwrap_or_default(),
        parameter_space,
        host_requirements,
        script: StepScript {
            actions: Actions { on_run },
        },
    }
}

/// A render task's host: the task's cores ([`FarmOptions::cpus`]) and, rendering on a GPU, its GPUs.
fn render_host(opts: &FarmOptions) -> HostRequirements {
    let mut amounts = vec![AmountRequirement {
        name: "amount.worker.vcpu".into(),
        min: opts.cpus(),
    }];
    if let Some(gpus) = opts.gpus() {
        amounts.push(AmountRequirement {
            name: "amount.worker.gpu".into(),
            min: gpus,
        });
    }
    HostRequirements { amounts }
}

pub fn template(opts: &FarmOptions) -> JobTemplate {
    // The shard is a template expression OpenJD fills in per task, not a value `--shard` parses
    // here: it is added after the typed command.
    let mut render = opts.generate_command(None).to_args();
    render.extend([
        "--shard".into(),
        format!("{{{{Task.Param.{SHARD_PARAM}}}}}/{}", opts.tasks),
    ]);
    let shards = ParameterSpace {
        task_parameter_definitions: vec![TaskParameter {
            name: SHARD_PARAM.into(),
            kind: "INT".into(),
            range: format!("0-{}", opts.tasks - 1),
        }],
    };
    JobTemplate {
        specification_version: SPECIFICATION_VERSION.into(),
        name: opts.name.clone(),
        description: format!(
            "Written by `stereogen farm openjd` (stereogen {}): samples {}..{} in {} shards into {}, then merge and check.",
            env!("CARGO_PKG_VERSION"),
            opts.task.start,
            opts.task.start + opts.task.count,
            opts.tasks,
            opts.out.display()
        ),
        job_environments: if opts.env.is_empty() {
            vec![]
        } else {
            vec![Environment {
                name: "StereogenEnvironment".into(),
                variables: opts.env.iter().cloned().collect(),
            }]
        },
        steps: vec![
            step(
                "Render",
                None,
                Some(shards),
                Some(render_host(opts)),
                action(opts, render, opts.time_limit),
            ),
            step(
                "Merge",
                Some("Render"),
                None,
                None,
                action(opts, opts.merge_args(), opts.merge_time_limit),
            ),
            step(
                "Check",
                Some("Merge"),
                None,
                None,
                action(opts, opts.check_args(), opts.merge_time_limit),
            ),
        ],
    }
}

pub fn files(opts: &FarmOptions) -> anyhow::Result<Vec<JobFile>> {
    Ok(vec![(
        "openjd-template.yaml".into(),
        serde_norway::to_string(&template(opts))?,
        false,
    )])
}
