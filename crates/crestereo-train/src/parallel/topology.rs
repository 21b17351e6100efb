//! Who this process is in a data-parallel run: its rank among the processes, how many there
//! are, and where rank 0 listens — from flags, else torchrun's environment, else Slurm's.
//!
//! A process holds one node's worth of devices (`--devices`); every process must hold the same
//! number. Replica `p · devices + d` is device `d` of process `p`; replicas are numbered the same
//! way whatever launched them, so the data each one reads is fixed by the numbers alone.
//!
//! Ports, from the master port `P` (torchrun's default 29500): `P` the collective's orchestrator,
//! `P + 1` the liveness channel, `P + 2 + rank` each process's tensor data service.

use anyhow::{Context, Result, bail};

/// torchrun's default master port.
pub const DEFAULT_MASTER_PORT: u16 = 29_500;
/// Slurm jobs take their master port from DEFAULT_MASTER_PORT + job id mod this: 29500..32499.
pub const SLURM_PORT_SPAN: usize = 3_000;

/// The process-group flags of `crestereo train` (each overrides the environment).
#[derive(Debug, Clone, Default, clap::Args)]
pub struct ProcessFlags {
    /// Processes (nodes) in the run [env: WORLD_SIZE, else SLURM_NTASKS; default 1].
    #[arg(long, value_name = "N")]
    pub nnodes: Option<usize>,
    /// This process's rank, 0..nnodes [env: RANK, else SLURM_PROCID].
    #[arg(long, value_name = "R")]
    pub node_rank: Option<usize>,
    /// Host of rank 0, which runs the orchestrator [env: MASTER_ADDR, else the first host of
    /// SLURM_JOB_NODELIST; default 127.0.0.1].
    #[arg(long, value_name = "HOST")]
    pub master_addr: Option<String>,
    /// Port of rank 0's orchestrator; the next ports are used too (P+1 liveness, P+2+rank each
    /// process's tensor service) [env: MASTER_PORT; under Slurm 29500 + job id mod 10000;
    /// default 29500].
    #[arg(long, value_name = "P")]
    pub master_port: Option<u16>,
    /// The address the other processes reach this one at [default: 127.0.0.1 when the master is
    /// on the loopback, else this host's name].
    #[arg(long, value_name = "HOST")]
    pub node_addr: Option<String>,
}

/// Where a process stands in a group of several.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProcessGroup {
    pub rank: usize,
    pub size: usize,
    pub master_addr: String,
    pub master_port: u16,
    /// How the others reach this process.
    pub node_addr: String,
    /// Where the numbers came from (for the log): `flags`, `torchrun` or `slurm`.
    pub source: &'static str,
}

impl ProcessGroup {
    pub fn orchestrator_port(&self) -> u16 {
        self.master_port
    }

    pub fn liveness_port(&self) -> u16 {
        self.master_port.saturating_add(1)
    }

    /// This process's tensor data service port.
    pub fn data_port(&self) -> Result<u16> {
        u16::try_from(usize::from(self.master_port) + 2 + self.rank)
            .ok()
            .filter(|&p| p > self.master_port)
            .with_context(|| {
                format!(
                    "master port {} leaves no room for {} processes' ports above it",
                    self.master_port, self.size
                )
            })
    }
}

/// Reads one environment variable (injected so tests need not set the real environment).
pub type Env<'a> = &'a dyn Fn(&str) -> Option<String>;

/// The process environment.
pub fn process_env(key: &str) -> Option<String> {
    std::env::var(key).ok().filter(|v| !v.is_empty())
}

/// This process's group, or `None` for a run of one process.
pub fn resolve(flags: &ProcessFlags, env: Env) -> Result<Option<ProcessGroup>> {
    let parse = |key: &str| -> Result<Option<usize>> {
        env(key)
            .map(|v| {
                v.trim()
                    .parse::<usize>()
                    .with_context(|| format!("environment {key}={v} is not a number"))
            })
            .transpose()
    };
    let torchrun = env("WORLD_SIZE").is_some() || env("RANK").is_some();
    let slurm = env("SLURM_NTASKS").is_some() && env("SLURM_PROCID").is_some();
    let (size, rank, source) = if flags.nnodes.is_some() || flags.node_rank.is_some() {
        (
            flags.nnodes.unwrap_or(1),
            flags.node_rank.unwrap_or(0),
            "flags",
        )
    } else if torchrun {
        (
            parse("WORLD_SIZE")?.unwrap_or(1),
            parse("RANK")?.unwrap_or(0),
            "torchrun",
        )
    } else if slurm {
        (
            parse("SLURM_NTASKS")?.unwrap_or(1),
            parse("SLURM_PROCID")?.unwrap_or(0),
            "slurm",
        )
    } else {
        (1, 0, "flags")
    };
    if size == 0 {
        bail!("a run needs at least one process ({source} say 0)");
    }
    if rank >= size {
        bail!("rank {rank} is not below the number of processes {size} ({source})");
    }
    if size == 1 {
        return Ok(None);
    }
    let master_addr = match &flags.master_addr {
        Some(a) => a.clone(),
        None => match env("MASTER_ADDR") {
            Some(a) => a,
            None => match env("SLURM_JOB_NODELIST").or_else(|| env("SLURM_NODELIST")) {
                Some(list) => first_host(&list)?,
                None => "127.0.0.1".to_string(),
            },
        },
    };
    let master_port = match flags.master_port {
        Some(p) => p,
        None => match env("MASTER_PORT") {
            Some(p) => p
                .trim()
                .parse()
                .with_context(|| format!("environment MASTER_PORT={p} is not a port"))?,
            None => match parse("SLURM_JOB_ID")? {
                // One job's ranks agree on it; two jobs on one node rarely collide. The block
                // (P .. P + 2 + ranks on a node) stays below 32768, where Linux's ephemeral ports
                // begin: no outgoing connection on the node can hold one of them.
                Some(job) => DEFAULT_MASTER_PORT + (job % SLURM_PORT_SPAN) as u16,
                None => DEFAULT_MASTER_PORT,
            },
        },
    };
    let node_addr = match &flags.node_addr {
        Some(a) => a.clone(),
        None if is_loopback(&master_addr) => "127.0.0.1".to_string(),
        None => env("SLURMD_NODENAME")
            .or_else(|| {
                std::fs::read_to_string("/proc/sys/kernel/hostname")
                    .ok()
                    .map(|h| h.trim().to_string())
            })
            .or_else(|| env("HOSTNAME"))
            .context("cannot tell this host's name: pass --node-addr")?,
    };
    let group = ProcessGroup {
        rank,
        size,
        master_addr,
        master_port,
        node_addr,
        source,
    };
    group.data_port()?;
    Ok(Some(group))
}

fn is_loopback(host: &str) -> bool {
    host == "localhost" || host == "::1" || host.starts_with("127.")
}

/// The first host of a Slurm host list: `node[03-05,9],gpu1` → `node03`.
pub fn first_host(list: &str) -> Result<String> {
    let first = list.trim();
    // The first entry ends at the first comma outside brackets.
    let mut depth = 0usize;
    let mut end = first.len();
    for (i, ch) in first.char_indices() {
        match ch {
            '[' => depth += 1,
            ']' => depth = depth.saturating_sub(1),
            ',' if depth == 0 => {
                end = i;
                break;
            }
            _ => {}
        }
    }
    let entry = &first[..end];
    let Some(open) = entry.find('[') else {
        if entry.is_empty() {
            bail!("empty Slurm node list");
        }
        return Ok(entry.to_string());
    };
    let close = entry[open..]
        .find(']')
        .map(|c| open + c)
        .with_context(|| format!("Slurm node list {list}: unclosed `[`"))?;
    let range = &entry[open + 1..close];
    let first_item = range.split(',').next().unwrap_or("");
    let lo = first_item.split('-').next().unwrap_or("").trim();
    if lo.is_empty() || !lo.chars().all(|c| c.is_ascii_digit()) {
        bail!("Slurm node list {list}: cannot read the range `{range}`");
    }
    Ok(format!("{}{lo}{}", &entry[..open], &entry[close + 1..]))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env_of(pairs: &[(&str, &str)]) -> impl Fn(&str) -> Option<String> {
        let map: std::collections::HashMap<String, String> = pairs
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        move |k: &str| map.get(k).cloned()
    }

    #[test]
    fn slurm_host_lists() {
        assert_eq!(first_host("node[03-05,9],gpu1").unwrap(), "node03");
        assert_eq!(first_host("gpu1,gpu2").unwrap(), "gpu1");
        assert_eq!(first_host("a[7]b").unwrap(), "a7b");
        assert_eq!(first_host("host").unwrap(), "host");
        assert!(first_host("n[").is_err());
        assert!(first_host("").is_err());
    }

    #[test]
    fn one_process_without_anything() {
        let none = env_of(&[]);
        assert_eq!(resolve(&ProcessFlags::default(), &none).unwrap(), None);
        let single = env_of(&[("SLURM_NTASKS", "1"), ("SLURM_PROCID", "0")]);
        assert_eq!(resolve(&ProcessFlags::default(), &single).unwrap(), None);
    }

    #[test]
    fn torchrun_then_slurm_then_flags() {
        let env = env_of(&[
            ("SLURM_NTASKS", "4"),
            ("SLURM_PROCID", "3"),
            ("SLURM_JOB_NODELIST", "gpu[12-15]"),
            ("SLURM_JOB_ID", "123456"),
            ("SLURMD_NODENAME", "gpu15"),
        ]);
        let g = resolve(&ProcessFlags::default(), &env).unwrap().unwrap();
        assert_eq!((g.rank, g.size, g.source), (3, 4, "slurm"));
        assert_eq!(g.master_addr, "gpu12");
        assert_eq!(g.master_port, DEFAULT_MASTER_PORT + 456); // 123456 mod 3000
        assert_eq!(g.node_addr, "gpu15");
        assert_eq!(g.data_port().unwrap(), g.master_port + 5);

        let env = env_of(&[
            ("WORLD_SIZE", "2"),
            ("RANK", "1"),
            ("MASTER_ADDR", "127.0.0.1"),
            ("MASTER_PORT", "40000"),
            ("SLURM_NTASKS", "4"),
            ("SLURM_PROCID", "3"),
        ]);
        let g = resolve(&ProcessFlags::default(), &env).unwrap().unwrap();
        assert_eq!((g.rank, g.size, g.source), (1, 2, "torchrun"));
        assert_eq!((g.master_port, g.node_addr.as_str()), (40000, "127.0.0.1"));

        let flags = ProcessFlags {
            nnodes: Some(3),
            node_rank: Some(2),
            master_port: Some(31000),
            ..Default::default()
        };
        let g = resolve(&flags, &env).unwrap().unwrap();
        assert_eq!((g.rank, g.size, g.source), (2, 3, "flags"));
        assert_eq!(g.master_addr, "127.0.0.1");
        assert_eq!(g.master_port, 31000);
    }

    #[test]
    fn bad_numbers_are_clear_errors() {
        let env = env_of(&[("WORLD_SIZE", "two"), ("RANK", "0")]);
        let e = resolve(&ProcessFlags::default(), &env).unwrap_err();
        assert!(e.to_string().contains("WORLD_SIZE=two"), "{e}");
        let flags = ProcessFlags {
            nnodes: Some(2),
            node_rank: Some(2),
            ..Default::default()
        };
        let e = resolve(&flags, &env_of(&[])).unwrap_err();
        assert!(e.to_string().contains("rank 2"), "{e}");
        let flags = ProcessFlags {
            nnodes: Some(2),
            node_rank: Some(1),
            master_port: Some(65_534),
            ..Default::default()
        };
        let e = resolve(&flags, &env_of(&[])).unwrap_err();
        assert!(e.to_string().contains("no room"), "{e}");
    }
}
