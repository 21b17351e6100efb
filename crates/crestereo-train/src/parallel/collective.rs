//! Every call into Burn's collective (`burn-collective` 0.21) is in this file: a Burn upgrade
//! that replaces it (upstream moved to a distributed context) changes this file only.
//!
//! What we use: `register` (one peer per device; with several processes each registers through
//! the global orchestrator that rank 0 runs), `all_reduce` (sum) on one flat tensor, and
//! `finish_collective`. What it lacks, and how it is handled here: its calls block without a
//! limit, and a peer that died leaves them blocked for ever — each call is armed on a
//! [`Watchdog`] that ends the process with one clear line when the call outlives its timeout
//! (a dead process is noticed sooner, by the liveness channel).

use std::collections::HashMap;
use std::str::FromStr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

use anyhow::{Result, anyhow};
use burn::prelude::*;
use burn::tensor::TensorPrimitive;
use burn_collective::{
    AllReduceStrategy, CollectiveConfig, PeerId, ReduceOperation, all_reduce, finish_collective,
    register,
};

use super::liveness::EXIT_PEER_LOST;
use super::topology::ProcessGroup;

/// How long a collective call may block before the run is declared stuck.
#[derive(Debug, Clone, Copy)]
pub struct Timeouts {
    /// Joining: every process and device registered (processes may start minutes apart).
    pub join: Duration,
    /// Each all-reduce, counted from when this replica enters it: the others' lag.
    pub step: Duration,
}

/// The collective's settings for this process: its devices, and the global part when there
/// are several processes.
#[derive(Debug, Clone)]
pub struct CollectiveSetup {
    config: CollectiveConfig,
}

impl CollectiveSetup {
    /// `devices` replicas in this process, and `group` when other processes take part.
    pub fn new(devices: usize, group: Option<&ProcessGroup>) -> Result<Self> {
        // Two peers or two nodes add in one order whatever the strategy (a + b = b + a in
        // floating point); a tree over the local devices keeps the sum on one device.
        let mut config = CollectiveConfig::default()
            .with_num_devices(devices)
            .with_local_all_reduce_strategy(AllReduceStrategy::Tree(2));
        if let Some(g) = group {
            let address = |host: &str, port: u16| {
                burn_communication::Address::from_str(&format!("ws://{host}:{port}"))
                    .map_err(|e| anyhow!("bad address {host}:{port}: {e}"))
            };
            config = config
                .with_num_nodes(g.size as u32)
                .with_global_address(address(&g.master_addr, g.orchestrator_port())?)
                .with_node_address(address(&g.node_addr, g.data_port()?)?)
                .with_data_service_port(g.data_port()?)
                .with_global_all_reduce_strategy(AllReduceStrategy::Ring);
        }
        Ok(Self { config })
    }
}

/// One replica's membership of the collective, on backend `B` (the inner, non-autodiff one).
pub struct Collective<B: Backend> {
    peer: PeerId,
    timeouts: Timeouts,
    _backend: std::marker::PhantomData<B>,
}

impl<B: Backend> Collective<B> {
    /// Registers replica `replica` on `device`; returns when every replica of the run has (or
    /// fails after `timeouts.join`).
    pub fn join(
        replica: usize,
        device: &B::Device,
        setup: &CollectiveSetup,
        timeouts: Timeouts,
    ) -> Result<Self> {
        let peer = PeerId::from(replica);
        let _armed = Watchdog::get().arm(
            format!("replica {replica}: joining the other replicas"),
            timeouts.join,
        );
        let config = setup.config.clone();
        off_pool(|| register::<B>(peer, device.clone(), config))
            .map_err(|e| anyhow!("replica {replica} cannot join the collective: {e:?}"))?;
        Ok(Self {
            peer,
            timeouts,
            _backend: std::marker::PhantomData,
        })
    }

    /// The element-wise sum of `tensor` over all replicas (every replica gets it).
    pub fn sum(&self, tensor: Tensor<B, 1>, what: &str) -> Result<Tensor<B, 1>> {
        let _armed = Watchdog::get().arm(
            format!("replica {}: {what}", self.peer.0),
            self.timeouts.step,
        );
        let (peer, primitive) = (self.peer, tensor.into_primitive().tensor());
        let out = off_pool(|| all_reduce::<B>(peer, primitive, ReduceOperation::Sum))
            .map_err(|e| anyhow!("all-reduce ({what}) failed: {e:?}"))?;
        Ok(Tensor::from_primitive(TensorPrimitive::Float(out)))
    }

    /// Leaves the collective.
    pub fn leave(self) -> Result<()> {
        let _armed = Watchdog::get().arm(
            format!("replica {}: leaving the collective", self.peer.0),
            self.timeouts.join,
        );
        let peer = self.peer;
        off_pool(|| finish_collective::<B>(peer))
            .map_err(|e| anyhow!("leaving the collective failed: {e:?}"))
    }
}

/// Runs a blocking collective call. On a thread of the CPU pool (where a replica's work runs)
/// the call goes to a helper thread while this one keeps serving the pool: the collective's own
/// threads add tensors with the CPU backend, whose kernels need the pool's threads, and a pool
/// of one thread blocked in the call would never see them.
fn off_pool<T: Send>(call: impl FnOnce() -> T + Send) -> T {
    if rayon::current_thread_index().is_none() {
        return call();
    }
    std::thread::scope(|scope| {
        let handle = scope.spawn(call);
        wait_on_pool(|| handle.is_finished().then_some(()));
        match handle.join() {
            Ok(v) => v,
            Err(panic) => std::panic::resume_unwind(panic),
        }
    })
}

/// Polls `ready` until it gives a value; meanwhile, on a thread of the CPU pool, runs the pool's
/// pending work (so a waiting thread never starves the kernels it waits for).
pub fn wait_on_pool<T>(mut ready: impl FnMut() -> Option<T>) -> T {
    loop {
        if let Some(v) = ready() {
            return v;
        }
        let worked = rayon::current_thread_index().is_some()
            && matches!(rayon::yield_now(), Some(rayon::Yield::Executed));
        if !worked {
            std::thread::sleep(Duration::from_micros(200));
        }
    }
}

/// Starts the global orchestrator (rank 0 of a multi-process run) on a thread of its own.
pub fn start_orchestrator(port: u16) -> Result<()> {
    // A port taken by another program would only show as a hang of every rank: check first.
    std::net::TcpListener::bind(("0.0.0.0", port)).map_err(|e| {
        anyhow!("rank 0 cannot listen on port {port} for the collective's orchestrator: {e}")
    })?;
    std::thread::Builder::new()
        .name("orchestrator".into())
        .spawn(move || {
            let runtime = match tokio::runtime::Builder::new_multi_thread()
                .worker_threads(1)
                .enable_all()
                .build()
            {
                Ok(r) => r,
                Err(e) => {
                    eprintln!("error: cannot start the orchestrator's runtime: {e}");
                    std::process::exit(EXIT_PEER_LOST);
                }
            };
            runtime.block_on(burn_collective::start_global_orchestrator(port));
        })?;
    Ok(())
}

/// Ends the process when an armed call outlives its deadline: a peer hangs (or died without
/// its socket closing, as on a lost network).
pub struct Watchdog {
    armed: Mutex<HashMap<u64, (Instant, String, Duration)>>,
    next: AtomicU64,
}

/// Disarms its entry when dropped.
pub struct Armed {
    id: u64,
}

impl Drop for Armed {
    fn drop(&mut self) {
        Watchdog::get().armed.lock().unwrap().remove(&self.id);
    }
}

impl Watchdog {
    /// The process's watchdog (its thread starts on first use).
    pub fn get() -> &'static Arc<Watchdog> {
        static DOG: OnceLock<Arc<Watchdog>> = OnceLock::new();
        DOG.get_or_init(|| {
            let dog = Arc::new(Watchdog {
                armed: Mutex::new(HashMap::new()),
                next: AtomicU64::new(0),
            });
            let watching = dog.clone();
            std::thread::Builder::new()
                .name("collective-watchdog".into())
                .spawn(move || {
                    loop {
                        std::thread::sleep(Duration::from_millis(200));
                        let now = Instant::now();
                        let late = watching
                            .armed
                            .lock()
                            .unwrap()
                            .values()
                            .find(|(deadline, ..)| now > *deadline)
                            .map(|(_, what, limit)| (what.clone(), *limit));
                        if let Some((what, limit)) = late {
                            eprintln!(
                                "error: {what}: no answer from the other replicas within {} s (one hangs or its node is unreachable); stopping (the last whole checkpoint is kept; continue with --resume; --collective-timeout sets the limit)",
                                limit.as_secs()
                            );
                            std::process::exit(EXIT_PEER_LOST);
                        }
                    }
                })
                .expect("the watchdog thread starts");
            dog
        })
    }

    /// Watches `what` for `limit` until the returned guard is dropped.
    pub fn arm(&self, what: String, limit: Duration) -> Armed {
        let id = self.next.fetch_add(1, Ordering::Relaxed);
        self.armed
            .lock()
            .unwrap()
            .insert(id, (Instant::now() + limit, what, limit));
        Armed { id }
    }
}
