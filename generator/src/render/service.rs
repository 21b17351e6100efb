//! A service that keeps one Blender worker alive: started lazily, restarted after a crash or
//! hang, each request retried on a fresh scratch directory.

use std::path::Path;
use std::time::Duration;

use super::protocol::{Fault, GeometryOutput, RenderOutput};
use super::scratch;
use super::worker::{Worker, WorkerConfig, WorkerError};
use crate::plan::SceneSpec;

/// Keeps one worker alive: starts it lazily, restarts it after a crash or hang, and retries.
pub struct RenderService {
    cfg: WorkerConfig,
    worker: Option<Worker>,
    /// Worker restarts so far (crashes and hangs).
    pub restarts: u32,
    /// Seconds the last worker start took (process start to its hello), until a render takes it.
    started_s: Option<f64>,
}

/// A finished render: the reply plus the scratch directory that holds its files until dropped
/// (see [`scratch`]).
pub struct Rendered {
    pub reply: RenderOutput,
    pub scratch: tempfile::TempDir,
    /// Seconds spent starting a worker for this render (process start, Blender's import, the
    /// hello), where this render started one; a worker's first sample pays it.
    pub worker_start_s: Option<f64>,
}

/// An exported geometry: the reply plus the scratch directory that holds its file until dropped.
pub struct ExportedGeometry {
    pub reply: GeometryOutput,
    pub scratch: tempfile::TempDir,
}

impl RenderService {
    pub fn new(cfg: WorkerConfig) -> Self {
        Self {
            cfg,
            worker: None,
            restarts: 0,
            started_s: None,
        }
    }

    fn ensure_worker(&mut self) -> Result<&mut Worker, WorkerError> {
        if self.worker.is_none() {
            let t0 = std::time::Instant::now();
            self.worker = Some(Worker::spawn(&self.cfg)?);
            self.started_s = Some(t0.elapsed().as_secs_f64());
        }
        Ok(self.worker.as_mut().expect("just set"))
    }

    /// Renders `spec`, retrying on crashes and hangs. `fault` picks an injected failure per attempt.
    pub fn render(
        &mut self,
        spec: &SceneSpec,
        fault: impl Fn(u32) -> Option<Fault>,
    ) -> Result<Rendered, WorkerError> {
        self.started_s = None;
        let (reply, scratch) = self.with_retries(spec, |worker, dir, attempt, timeout| {
            worker.render(spec, dir, fault(attempt), timeout)
        })?;
        Ok(Rendered {
            reply,
            scratch,
            worker_start_s: self.started_s.take(),
        })
    }

    /// Writes the evaluated geometry of `spec` (no render), retrying on crashes and hangs.
    pub fn export_geometry(&mut self, spec: &SceneSpec) -> Result<ExportedGeometry, WorkerError> {
        let (reply, scratch) = self.with_retries(spec, |worker, dir, _, timeout| {
            worker.export_geometry(spec, dir, timeout)
        })?;
        Ok(ExportedGeometry { reply, scratch })
    }

    /// Runs `request` on the worker with a fresh scratch directory, restarting the worker and
    /// retrying after a crash, hang or garbled reply.
    fn with_retries<T>(
        &mut self,
        spec: &SceneSpec,
        request: impl Fn(&mut Worker, &Path, u32, Duration) -> Result<T, WorkerError>,
    ) -> Result<(T, tempfile::TempDir), WorkerError> {
        let mut attempt = 0;
        loop {
            if self.cfg.stop.is_set() {
                return Err(WorkerError::Interrupted);
            }
            let scratch = scratch::create(&self.cfg.scratch).map_err(|e| {
                WorkerError::Scratch(format!("{}: {e}", self.cfg.scratch.display()))
            })?;
            let timeout = self.cfg.render_timeout;
            let outcome = self
                .ensure_worker()
                .and_then(|w| request(w, scratch.path(), attempt, timeout));
            match outcome {
                Ok(reply) => return Ok((reply, scratch)),
                Err(WorkerError::Interrupted) => {
                    if let Some(mut w) = self.worker.take() {
                        w.kill();
                    }
                    return Err(WorkerError::Interrupted);
                }
                Err(e) if e.is_fatal() => return Err(e),
                Err(e @ WorkerError::Scene { .. }) => return Err(e),
                Err(e) => {
                    // Crash, hang or garbage: this worker is no longer trusted.
                    if let Some(mut w) = self.worker.take() {
                        w.kill();
                    }
                    self.restarts += 1;
                    if self.cfg.stop.is_set() {
                        // A worker killed by the same signal that stops the run.
                        return Err(WorkerError::Interrupted);
                    }
                    if attempt >= self.cfg.retries {
                        return Err(e);
                    }
                    tracing::warn!(
                        "sample {}: {e}; restarting the worker (attempt {} of {})",
                        spec.id,
                        attempt + 2,
                        self.cfg.retries + 1
                    );
                    attempt += 1;
                }
            }
        }
    }

    pub fn shutdown(&mut self) {
        if let Some(w) = self.worker.take() {
            w.shutdown();
        }
    }
}

impl Drop for RenderService {
    fn drop(&mut self) {
        self.shutdown();
    }
}
