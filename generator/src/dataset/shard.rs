//! Which shard a farm task renders: given (`--shard K/N`) or read from the scheduler's
//! environment (`--shard auto`).
//!
//! `--shard auto` reads, in this order (the first variable present decides):
//!
//! | variable | scheduler | N from |
//! | --- | --- | --- |
//! | `STEREOGEN_SHARD=K/N` | any (set by hand) | the value |
//! | `SLURM_ARRAY_TASK_ID` | Slurm job array | `SLURM_ARRAY_TASK_COUNT`, else `MAX − MIN + 1`; K = ID − `SLURM_ARRAY_TASK_MIN` |
//! | `JOB_COMPLETION_INDEX` | Kubernetes Indexed Job | `--shards N` or `STEREOGEN_SHARD_COUNT` |
//! | `AWS_BATCH_JOB_ARRAY_INDEX` | AWS Batch array job | `AWS_BATCH_JOB_ARRAY_SIZE`, `--shards N` or `STEREOGEN_SHARD_COUNT` |
//!
//! Detection is asked for, never implicit: a `generate` without `--shard` inside an array job
//! renders the whole range, as on a workstation (and the directory lock stops the second task).
//! `--shards N` (or `STEREOGEN_SHARD_COUNT`) must agree with a count the scheduler gives.

use std::str::FromStr;

use anyhow::{Context, bail};

pub use stereo_io::datasets::stereogen::ShardId;

/// `STEREOGEN_SHARD=K/N`: the shard, set by hand or by a job file.
pub const SHARD_ENV: &str = "STEREOGEN_SHARD";
/// `STEREOGEN_SHARD_COUNT=N`: the number of shards where the scheduler does not say it.
pub const SHARD_COUNT_ENV: &str = "STEREOGEN_SHARD_COUNT";

/// `--shard`: a fixed shard or `auto`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShardArg {
    Fixed(ShardId),
    Auto,
}

impl ShardArg {
    /// The text `--shard` takes for it (`K/N` or `auto`).
    pub fn to_arg(self) -> String {
        match self {
            Self::Fixed(id) => id.to_string(),
            Self::Auto => "auto".into(),
        }
    }
}

impl FromStr for ShardArg {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        if s.trim() == "auto" {
            return Ok(Self::Auto);
        }
        parse_k_of_n(s).map(Self::Fixed)
    }
}

/// `K/N` with `0 <= K < N`.
pub fn parse_k_of_n(s: &str) -> Result<ShardId, String> {
    let (k, n) = s
        .split_once('/')
        .ok_or_else(|| format!("{s:?} is not K/N or auto"))?;
    let k: u64 = k
        .trim()
        .parse()
        .map_err(|_| format!("{s:?}: K is not a number"))?;
    let n: u64 = n
        .trim()
        .parse()
        .map_err(|_| format!("{s:?}: N is not a number"))?;
    ShardId::new(k, n).ok_or_else(|| format!("{s:?}: need 0 <= K < N"))
}

/// A shard read from the environment, and the variables it came from (for the log).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DetectedShard {
    pub shard: ShardId,
    pub source: String,
}

/// Resolves `--shard` against the process environment.
pub fn resolve_shard(arg: ShardArg, shards: Option<u64>) -> anyhow::Result<DetectedShard> {
    match arg {
        ShardArg::Fixed(shard) => {
            if let Some(n) = shards.filter(|&n| n != shard.count) {
                bail!("--shard {shard} and --shards {n} disagree on the number of shards");
            }
            Ok(DetectedShard {
                shard,
                source: format!("--shard {shard}"),
            })
        }
        ShardArg::Auto => detect_shard(&|name| std::env::var(name).ok(), shards),
    }
}

type Env<'a> = dyn Fn(&str) -> Option<String> + 'a;

fn number(env: &Env<'_>, name: &str) -> anyhow::Result<Option<u64>> {
    env(name)
        .map(|v| {
            v.trim()
                .parse::<u64>()
                .with_context(|| format!("{name}={v:?} is not a whole number >= 0"))
        })
        .transpose()
}

/// `--shard auto`: the shard from `env` (see the module docs); `shards` is `--shards N`.
pub fn detect_shard(env: &Env<'_>, shards: Option<u64>) -> anyhow::Result<DetectedShard> {
    if shards == Some(0) {
        bail!("--shards must be at least 1");
    }
    let count_hint = match shards {
        Some(n) => Some((n, "--shards".to_string())),
        None => number(env, SHARD_COUNT_ENV)?.map(|n| (n, SHARD_COUNT_ENV.to_string())),
    };
    if let Some(value) = env(SHARD_ENV) {
        let shard = parse_k_of_n(&value).map_err(|e| anyhow::anyhow!("{SHARD_ENV}: {e}"))?;
        return with_count(
            shard.index,
            Some((shard.count, SHARD_ENV.into())),
            count_hint,
            &format!("{SHARD_ENV}={value}"),
        );
    }
    if let Some(id) = number(env, "SLURM_ARRAY_TASK_ID")? {
        return slurm(env, id, count_hint);
    }
    if let Some(index) = number(env, "JOB_COMPLETION_INDEX")? {
        return with_count(
            index,
            None,
            count_hint,
            &format!("JOB_COMPLETION_INDEX={index}"),
        );
    }
    if let Some(index) = number(env, "AWS_BATCH_JOB_ARRAY_INDEX")? {
        let size = number(env, "AWS_BATCH_JOB_ARRAY_SIZE")?
            .map(|n| (n, "AWS_BATCH_JOB_ARRAY_SIZE".to_string()));
        return with_count(
            index,
            size,
            count_hint,
            &format!("AWS_BATCH_JOB_ARRAY_INDEX={index}"),
        );
    }
    bail!(
        "--shard auto: no shard in the environment: set {SHARD_ENV}=K/N, or run as a Slurm array task (SLURM_ARRAY_TASK_ID), a Kubernetes Indexed Job (JOB_COMPLETION_INDEX) or an AWS Batch array job (AWS_BATCH_JOB_ARRAY_INDEX)"
    )
}

/// Slurm: K = ID − MIN; N = COUNT, which must equal MAX − MIN + 1 (a stepped or sparse array
/// does not map onto shards).
fn slurm(
    env: &Env<'_>,
    id: u64,
    count_hint: Option<(u64, String)>,
) -> anyhow::Result<DetectedShard> {
    let min = number(env, "SLURM_ARRAY_TASK_MIN")?;
    let max = number(env, "SLURM_ARRAY_TASK_MAX")?;
    let count = number(env, "SLURM_ARRAY_TASK_COUNT")?;
    let first = min.unwrap_or(0);
    if id < first {
        bail!("SLURM_ARRAY_TASK_ID={id} is below SLURM_ARRAY_TASK_MIN={first}");
    }
    let span = match (min, max) {
        (Some(lo), Some(hi)) if hi >= lo => Some(hi - lo + 1),
        (Some(lo), Some(hi)) => {
            bail!("SLURM_ARRAY_TASK_MAX={hi} is below SLURM_ARRAY_TASK_MIN={lo}")
        }
        _ => None,
    };
    let scheduler_count = match (count, span) {
        (Some(c), Some(s)) if c != s => bail!(
            "SLURM_ARRAY_TASK_COUNT={c} but SLURM_ARRAY_TASK_MIN..MAX spans {s} ids: a stepped or sparse array does not map onto shards; submit --array=A-B (every id from A to B)"
        ),
        (Some(c), _) => Some((c, "SLURM_ARRAY_TASK_COUNT".to_string())),
        (None, Some(s)) => Some((s, "SLURM_ARRAY_TASK_MIN/MAX".to_string())),
        (None, None) => None,
    };
    let source = format!(
        "SLURM_ARRAY_TASK_ID={id}{}",
        min.map(|m| format!(", SLURM_ARRAY_TASK_MIN={m}"))
            .unwrap_or_default()
    );
    with_count(id - first, scheduler_count, count_hint, &source)
}

/// Puts the index together with a count from the scheduler and/or the user, which must agree.
fn with_count(
    index: u64,
    scheduler: Option<(u64, String)>,
    user: Option<(u64, String)>,
    source: &str,
) -> anyhow::Result<DetectedShard> {
    let (count, from) = match (scheduler, user) {
        (Some((a, from_a)), Some((b, from_b))) if a != b => {
            bail!("{from_a} says {a} shards but {from_b} says {b}")
        }
        (Some(c), _) | (None, Some(c)) => c,
        (None, None) => bail!(
            "{source} is set but the number of shards is not: pass --shards N or set {SHARD_COUNT_ENV}"
        ),
    };
    let Some(shard) = ShardId::new(index, count) else {
        bail!("{source}: shard index {index} is not below the number of shards {count} ({from})");
    };
    Ok(DetectedShard {
        shard,
        source: format!("{source}, {count} shards from {from}"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn detect(vars: &[(&str, &str)], shards: Option<u64>) -> anyhow::Result<ShardId> {
        let env = |name: &str| {
            vars.iter()
                .find(|(k, _)| *k == name)
                .map(|(_, v)| v.to_string())
        };
        detect_shard(&env, shards).map(|d| d.shard)
    }

    fn err(vars: &[(&str, &str)], shards: Option<u64>) -> String {
        detect(vars, shards).unwrap_err().to_string()
    }

    #[test]
    fn each_scheduler_gives_its_shard() {
        let s = |k, n| ShardId::new(k, n).unwrap();
        assert_eq!(
            detect(&[("STEREOGEN_SHARD", "3/8")], None).unwrap(),
            s(3, 8)
        );
        assert_eq!(
            detect(
                &[
                    ("SLURM_ARRAY_TASK_ID", "2"),
                    ("SLURM_ARRAY_TASK_COUNT", "4")
                ],
                None
            )
            .unwrap(),
            s(2, 4)
        );
        // An array that starts at 1: ids 1..=4 are shards 0..=3.
        let one_based = [
            ("SLURM_ARRAY_TASK_ID", "4"),
            ("SLURM_ARRAY_TASK_MIN", "1"),
            ("SLURM_ARRAY_TASK_MAX", "4"),
        ];
        assert_eq!(detect(&one_based, None).unwrap(), s(3, 4));
        assert_eq!(
            detect(
                &[
                    ("JOB_COMPLETION_INDEX", "5"),
                    ("STEREOGEN_SHARD_COUNT", "6")
                ],
                None
            )
            .unwrap(),
            s(5, 6)
        );
        assert_eq!(
            detect(&[("JOB_COMPLETION_INDEX", "5")], Some(7)).unwrap(),
            s(5, 7)
        );
        assert_eq!(
            detect(
                &[
                    ("AWS_BATCH_JOB_ARRAY_INDEX", "0"),
                    ("AWS_BATCH_JOB_ARRAY_SIZE", "2")
                ],
                None
            )
            .unwrap(),
            s(0, 2)
        );
        // STEREOGEN_SHARD wins over a scheduler's variables.
        assert_eq!(
            detect(
                &[
                    ("STEREOGEN_SHARD", "1/2"),
                    ("SLURM_ARRAY_TASK_ID", "0"),
                    ("SLURM_ARRAY_TASK_COUNT", "9")
                ],
                None
            )
            .unwrap(),
            s(1, 2)
        );
    }

    #[test]
    fn missing_or_inconsistent_variables_are_named() {
        assert!(err(&[], None).contains("no shard in the environment"));
        assert!(
            err(&[("JOB_COMPLETION_INDEX", "1")], None)
                .contains("JOB_COMPLETION_INDEX=1 is set but the number of shards is not")
        );
        assert!(
            err(&[("SLURM_ARRAY_TASK_ID", "x")], None)
                .contains("SLURM_ARRAY_TASK_ID=\"x\" is not a whole number")
        );
        assert!(
            err(&[("SLURM_ARRAY_TASK_ID", "3")], None)
                .contains("SLURM_ARRAY_TASK_ID=3 is set but the number of shards is not")
        );
        let stepped = [
            ("SLURM_ARRAY_TASK_ID", "2"),
            ("SLURM_ARRAY_TASK_MIN", "0"),
            ("SLURM_ARRAY_TASK_MAX", "6"),
            ("SLURM_ARRAY_TASK_COUNT", "4"),
        ];
        assert!(err(&stepped, None).contains("stepped or sparse"));
        assert!(
            err(
                &[
                    ("SLURM_ARRAY_TASK_ID", "4"),
                    ("SLURM_ARRAY_TASK_COUNT", "4")
                ],
                None
            )
            .contains("not below the number of shards 4 (SLURM_ARRAY_TASK_COUNT)")
        );
        assert!(
            err(
                &[
                    ("SLURM_ARRAY_TASK_ID", "1"),
                    ("SLURM_ARRAY_TASK_COUNT", "4")
                ],
                Some(5)
            )
            .contains("SLURM_ARRAY_TASK_COUNT says 4 shards but --shards says 5")
        );
        assert!(err(&[("STEREOGEN_SHARD", "4/4")], None).starts_with("STEREOGEN_SHARD:"));
        assert!(
            err(
                &[
                    ("AWS_BATCH_JOB_ARRAY_INDEX", "1"),
                    ("STEREOGEN_SHARD_COUNT", "two")
                ],
                None
            )
            .contains("STEREOGEN_SHARD_COUNT=\"two\"")
        );
    }

    #[test]
    fn the_flag_parses_fixed_and_auto() {
        assert_eq!("auto".parse::<ShardArg>(), Ok(ShardArg::Auto));
        assert_eq!(
            "1/3".parse::<ShardArg>(),
            Ok(ShardArg::Fixed(ShardId::new(1, 3).unwrap()))
        );
        assert!("3/3".parse::<ShardArg>().is_err());
        assert!(resolve_shard(ShardArg::Fixed(ShardId::new(1, 3).unwrap()), Some(4)).is_err());
    }
}
