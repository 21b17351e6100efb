//! Kubernetes: a `batch/v1` Indexed Job renders (one completion index per shard, `parallelism`
//! at once, `backoffLimitPerIndex` retries each), a second Job merges and checks. Kubernetes has
//! no dependencies between Jobs: apply the merge Job once the render Job is complete
//! (`kubectl wait --for=condition=complete job/NAME-render`), as `README` shows.
//!
//! The shared output is a PersistentVolumeClaim mounted at `--out` in every pod, so a task's
//! command is the same `stereogen generate --shard auto` as anywhere (index from
//! `JOB_COMPLETION_INDEX`, count from `STEREOGEN_SHARD_COUNT`, which the Job sets). The pod
//! failure policy does not count an interrupted task (exit [`INTERRUPTED_EXIT_CODE`]) or an
//! evicted/preempted pod (`DisruptionTarget`) against the retries.

use std::collections::BTreeMap;

use serde::Serialize;

use super::{FarmOptions, INTERRUPTED_EXIT_CODE, JobFile, TimeLimit, path};
use crate::dataset::shard::{SHARD_COUNT_ENV, ShardArg};

#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Job {
    pub api_version: String,
    pub kind: String,
    pub metadata: ObjectMeta,
    pub spec: JobSpec,
}

#[derive(Debug, Clone, Serialize)]
pub struct ObjectMeta {
    pub name: String,
    pub labels: BTreeMap<String, String>,
}

#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct JobSpec {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub completion_mode: Option<String>,
    pub completions: u64,
    pub parallelism: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub backoff_limit_per_index: Option<u32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub backoff_limit: Option<u32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pod_failure_policy: Option<PodFailurePolicy>,
    pub template: PodTemplate,
}

#[derive(Debug, Clone, Serialize)]
pub struct PodFailurePolicy {
    pub rules: Vec<PodFailurePolicyRule>,
}

#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct PodFailurePolicyRule {
    pub action: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub on_exit_codes: Option<OnExitCodes>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub on_pod_conditions: Vec<OnPodCondition>,
}

#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct OnExitCodes {
    pub container_name: String,
    pub operator: String,
    pub values: Vec<i32>,
}

#[derive(Debug, Clone, Serialize)]
pub struct OnPodCondition {
    #[serde(rename = "type")]
    pub kind: String,
    pub status: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct PodTemplate {
    pub metadata: ObjectMeta,
    pub spec: PodSpec,
}

#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct PodSpec {
    pub restart_policy: String,
    pub termination_grace_period_seconds: u64,
    /// The task's time limit: the pod is stopped (SIGTERM, then SIGKILL after the grace period)
    /// this many seconds after it started; an interrupted `generate` exits 75, which the pod
    /// failure policy does not count, so the index gets a new pod that resumes.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub active_deadline_seconds: Option<u64>,
    /// Run one after another before `containers`; a failure fails the pod.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub init_containers: Vec<Container>,
    pub containers: Vec<Container>,
    pub volumes: Vec<Volume>,
}

#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Container {
    pub name: String,
    pub image: String,
    pub command: Vec<String>,
    pub env: Vec<EnvVar>,
    pub resources: Resources,
    pub volume_mounts: Vec<VolumeMount>,
}

#[derive(Debug, Clone, Serialize)]
pub struct EnvVar {
    pub name: String,
    pub value: String,
}

#[derive(Debug, Clone, Serialize, Default)]
pub struct Resources {
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub requests: BTreeMap<String, String>,
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub limits: BTreeMap<String, String>,
}

#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct VolumeMount {
    pub name: String,
    pub mount_path: String,
}

#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Volume {
    pub name: String,
    pub persistent_volume_claim: ClaimSource,
}

#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct ClaimSource {
    pub claim_name: String,
}

/// Retries of one index before the Job gives up on it.
const RETRIES_PER_INDEX: u32 = 3;
const VOLUME: &str = "stereogen-data";

fn meta(opts: &FarmOptions, name: String, role: &str) -> ObjectMeta {
    ObjectMeta {
        name,
        labels: BTreeMap::from([
            ("app.kubernetes.io/name".into(), "stereogen".into()),
            ("stereogen/job".into(), opts.name.clone()),
            ("stereogen/role".into(), role.into()),
        ]),
    }
}

fn container(
    opts: &FarmOptions,
    name: &str,
    command: Vec<String>,
    cpus: u32,
    gpus: Option<u32>,
) -> Container {
    let mut env: Vec<EnvVar> = opts
        .env
        .iter()
        .map(|(k, v)| EnvVar {
            name: k.clone(),
            value: v.clone(),
        })
        .collect();
    env.push(EnvVar {
        name: SHARD_COUNT_ENV.into(),
        value: opts.tasks.to_string(),
    });
    let mut resources = Resources::default();
    resources.requests.insert("cpu".into(), cpus.to_string());
    if let Some(m) = &opts.memory {
        resources.requests.insert("memory".into(), m.clone());
    }
    if let Some(g) = gpus {
        resources
            .limits
            .insert("nvidia.com/gpu".into(), g.to_string());
    }
    Container {
        name: name.into(),
        image: opts.image.clone(),
        command,
        env,
        resources,
        volume_mounts: vec![VolumeMount {
            name: VOLUME.into(),
            mount_path: path(&opts.out),
        }],
    }
}

fn pod(
    opts: &FarmOptions,
    role: &str,
    init_containers: Vec<Container>,
    container: Container,
    time_limit: Option<TimeLimit>,
) -> PodTemplate {
    PodTemplate {
        metadata: meta(opts, format!("{}-{role}", opts.name), role),
        spec: PodSpec {
            restart_policy: "Never".into(),
            termination_grace_period_seconds: opts.grace_s,
            active_deadline_seconds: time_limit.map(TimeLimit::seconds),
            init_containers,
            containers: vec![container],
            volumes: vec![Volume {
                name: VOLUME.into(),
                persistent_volume_claim: ClaimSource {
                    claim_name: opts.volume_claim.clone(),
                },
            }],
        },
    }
}

/// The Indexed Job that renders.
pub fn render_job(opts: &FarmOptions) -> Job {
    let mut command = vec![path(&opts.stereogen)];
    command.extend(opts.generate_command(Some(ShardArg::Auto)).to_args());
    let c = container(opts, "render", command, opts.cpus(), opts.gpus());
    Job {
        api_version: "batch/v1".into(),
        kind: "Job".into(),
        metadata: meta(opts, format!("{}-render", opts.name), "render"),
        spec: JobSpec {
            completion_mode: Some("Indexed".into()),
            completions: opts.tasks,
            parallelism: opts.max_parallel.unwrap_or(opts.tasks).min(opts.tasks),
            backoff_limit_per_index: Some(RETRIES_PER_INDEX),
            backoff_limit: None,
            pod_failure_policy: Some(PodFailurePolicy {
                rules: vec![
                    PodFailurePolicyRule {
                        action: "Ignore".into(),
                        on_exit_codes: Some(OnExitCodes {
                            container_name: "render".into(),
                            operator: "In".into(),
                            values: vec![INTERRUPTED_EXIT_CODE],
                        }),
                        on_pod_conditions: vec![],
                    },
                    PodFailurePolicyRule {
                        action: "Ignore".into(),
                        on_exit_codes: None,
                        on_pod_conditions: vec![OnPodCondition {
                            kind: "DisruptionTarget".into(),
                            status: "True".into(),
                        }],
                    },
                ],
            }),
            template: pod(opts, "render", vec![], c, opts.time_limit),
        },
    }
}

/// The Job that merges and checks: one pod, `merge` as its init container, then `stats --check`.
pub fn merge_job(opts: &FarmOptions) -> Job {
    let bin = path(&opts.stereogen);
    let merge = container(
        opts,
        "merge",
        [vec![bin.clone()], opts.merge_args()].concat(),
        2,
        None,
    );
    let check = container(
        opts,
        "check",
        [vec![bin], opts.check_args()].concat(),
        2,
        None,
    );
    Job {
        api_version: "batch/v1".into(),
        kind: "Job".into(),
        metadata: meta(opts, format!("{}-merge", opts.name), "merge"),
        spec: JobSpec {
            completion_mode: None,
            completions: 1,
            parallelism: 1,
            backoff_limit_per_index: None,
            backoff_limit: Some(0),
            pod_failure_policy: None,
            template: pod(opts, "merge", vec![merge], check, opts.merge_time_limit),
        },
    }
}

fn yaml(job: &Job, comment: &str) -> anyhow::Result<String> {
    Ok(format!("# {comment}\n{}", serde_norway::to_string(job)?))
}

pub fn files(opts: &FarmOptions) -> anyhow::Result<Vec<JobFile>> {
    let render = render_job(opts);
    let head = format!(
        "Written by `stereogen farm k8s` (stereogen {}).",
        env!("CARGO_PKG_VERSION")
    );
    Ok(vec![
        (
            "k8s-render.yaml".into(),
            yaml(
                &render,
                &format!("{head} kubectl apply -f this; re-apply to resume."),
            )?,
            false,
        ),
        (
            "k8s-merge.yaml".into(),
            yaml(
                &merge_job(opts),
                &format!(
                    "{head} Apply after `kubectl wait --for=condition=complete --timeout=-1s job/{}`.",
                    render.metadata.name
                ),
            )?,
            false,
        ),
    ])
}
