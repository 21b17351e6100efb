//! A tiny training run, for the tests and demonstrations of data-parallel training: its data and
//! config and a block of free loopback ports for its ranks.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};

/// Writes (once) eight synthetic 64×128 pairs to `dir/data` and the config of a `steps`-step run
/// over them to `dir/train-STEPS.toml`, and returns the config's path.
///
/// The run: 32×64 crops, 2 iterations, global batch 2 (one sample per replica of two), logged
/// and checkpointed every step (3 kept), at the learning rate of the paper's first steps (its
/// warm-up starts at 5% of 4e-4: 2e-5). There a run on two replicas follows the one-replica run
/// within 1e-5 relative; at 4e-4, Adam (which divides each gradient by its running magnitude)
/// magnifies the rounding differences of sums taken in another order to 2e-5–2e-4.
pub fn write_tiny_run(dir: &Path, steps: u64) -> Result<PathBuf> {
    let data = dir.join("data");
    if !data.exists() {
        crate::synthetic::write_crestereo_dataset(&data, 8, 128, 64, 0)?;
    }
    let cfg = dir.join(format!("train-{steps}.toml"));
    let text = format!(
        r#"steps = {steps}
batch_size = 2
accumulate = 1
iters = 2
seed = 5

[[datasets]]
path = "{}"

[augment]
crop = [32, 64]

[schedule]
lr = 2e-5
warmup_steps = 1
decay_start = {steps}

[loader]
workers = 1
prefetch = 2

[log]
every = 1

[checkpoint]
every = 1
keep = 3
"#,
        data.display()
    );
    std::fs::write(&cfg, text).with_context(|| format!("cannot write {}", cfg.display()))?;
    Ok(cfg)
}

/// A master port P for a run on the loopback whose next four ports are free too (P: the
/// collective's orchestrator, P + 1: the liveness channel, P + 2 + rank: two ranks' data
/// services).
///
/// P lies in 20000..28000, below the kernel's ephemeral range (32768.. on Linux) and the
/// default master port: an outgoing connection is never given one of these ports, so between
/// this check and the ranks' binds only another explicit bind can take them. (A port the kernel
/// hands out for `bind(0)` lies in the ephemeral range, where any concurrent connection of the
/// machine — another test's ranks talking to each other — may take P + 2 before its rank binds
/// it; that rank then serves no data and its peer fails to connect.) Candidates step through the
/// range from a start that depends on the process, so concurrent test processes spread out.
pub fn free_master_port() -> u16 {
    use std::sync::atomic::{AtomicU32, Ordering};
    const FIRST: u32 = 20_000;
    const BLOCKS: u32 = 1_000; // of 8 ports: 20000..28000
    static NEXT: AtomicU32 = AtomicU32::new(0);
    let start = std::process::id().wrapping_mul(7_919);
    loop {
        let k = NEXT.fetch_add(1, Ordering::Relaxed);
        let p = (FIRST + (start.wrapping_add(k) % BLOCKS) * 8) as u16;
        if (p..p + 5).all(|q| std::net::TcpListener::bind(("0.0.0.0", q)).is_ok()) {
            return p;
        }
    }
}
