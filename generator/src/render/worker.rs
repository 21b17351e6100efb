//! One Blender worker process, and a service that keeps one alive across crashes and hangs.

use std::collections::VecDeque;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Stdio};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use super::protocol::{Device, Fault, Hello, RenderReply, RenderRequest};
use super::runtime::{BLENDER_SERIES, BlenderRuntime};
use crate::plan::SceneSpec;

const STDERR_TAIL_LINES: usize = 30;

#[derive(Debug, Clone)]
pub struct WorkerConfig {
    pub runtime: BlenderRuntime,
    /// Path of `worker.py` (see [`super::scripts::install_scripts`]).
    pub script: PathBuf,
    /// Cycles CPU threads of this worker.
    pub threads: u32,
    pub device: Device,
    /// Time allowed for Blender to start and import `bpy`.
    pub startup_timeout: Duration,
    /// Time allowed for one spec, build and both views.
    pub render_timeout: Duration,
    /// Attempts after the first when a worker crashes or hangs.
    pub retries: u32,
}

#[derive(Debug, thiserror::Error)]
pub enum WorkerError {
    #[error("cannot start Blender ({runtime}): {message}")]
    Start { runtime: String, message: String },
    #[error("Blender ({runtime}) reports version {found}; stereogen needs Blender {BLENDER_SERIES} LTS")]
    WrongVersion { runtime: String, found: String },
    #[error("Blender worker died ({status}){tail}")]
    Crashed { status: String, tail: String },
    #[error("Blender worker gave no answer within {0:?} and was killed")]
    Timeout(Duration),
    #[error("Blender worker broke the protocol: {0}")]
    Protocol(String),
    #[error("scene failed in Blender: {0}")]
    Scene(String),
    #[error("cannot create a scratch directory in {0}")]
    Scratch(String),
}

impl WorkerError {
    /// Errors that will happen again for every sample: the whole run should stop.
    pub fn is_fatal(&self) -> bool {
        matches!(self, WorkerError::Start { .. } | WorkerError::WrongVersion { .. } | WorkerError::Scratch(_))
    }
}

/// A running worker. Killed when dropped.
pub struct Worker {
    child: Child,
    stdin: ChildStdin,
    replies: Receiver<String>,
    stderr_tail: Arc<Mutex<VecDeque<String>>>,
    pub hello: Hello,
}

/// Calls `f` with every line of `stream` until it returns false or the stream ends.
///
/// Lines are decoded lossily: Blender echoes file contents and paths that need not be UTF-8, and
/// a reader that stopped at the first bad byte would close the pipe, and the worker would die on
/// its next write.
fn for_each_line(stream: impl std::io::Read, mut f: impl FnMut(String) -> bool) {
    let mut reader = BufReader::new(stream);
    let mut buf = Vec::new();
    loop {
        buf.clear();
        match reader.read_until(b'\n', &mut buf) {
            Ok(0) | Err(_) => break,
            Ok(_) => {
                let line = String::from_utf8_lossy(&buf).trim_end_matches(['\n', '\r']).to_string();
                if !f(line) {
                    break;
                }
            }
        }
    }
}

fn tail_text(tail: &Mutex<VecDeque<String>>) -> String {
    let lines = tail.lock().map(|t| t.iter().cloned().collect::<Vec<_>>()).unwrap_or_default();
    let interesting: Vec<&String> = lines.iter().filter(|l| !l.starts_with("Fra:")).collect();
    if interesting.is_empty() { String::new() } else { format!("; last output: {}", interesting.iter().rev().take(6).rev().map(|s| s.as_str()).collect::<Vec<_>>().join(" | ")) }
}

impl Worker {
    pub fn spawn(cfg: &WorkerConfig) -> Result<Self, WorkerError> {
        let runtime = cfg.runtime.describe();
        let args = vec!["--threads".to_string(), cfg.threads.to_string(), "--device".to_string(), serde_json::to_value(cfg.device).unwrap().as_str().unwrap().to_string()];
        let mut cmd = cfg.runtime.command(&cfg.script, &args);
        cmd.stdin(Stdio::piped()).stdout(Stdio::piped()).stderr(Stdio::piped());
        #[cfg(target_os = "linux")]
        {
            use std::os::unix::process::CommandExt;
            // A worker must not outlive a killed orchestrator (it would keep rendering into a
            // dataset nobody finishes). The signal fires when the spawning thread exits, and
            // every worker is shut down before its thread ends.
            unsafe {
                cmd.pre_exec(|| {
                    if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0 {
                        return Err(std::io::Error::last_os_error());
                    }
                    Ok(())
                });
            }
        }
        let mut child = cmd.spawn().map_err(|e| WorkerError::Start { runtime: runtime.clone(), message: e.to_string() })?;
        let stdin = child.stdin.take().expect("piped");
        let stdout = child.stdout.take().expect("piped");
        let stderr = child.stderr.take().expect("piped");

        let (tx, replies) = mpsc::channel();
        std::thread::spawn(move || {
            for_each_line(stdout, |line| tx.send(line).is_ok());
        });
        let stderr_tail = Arc::new(Mutex::new(VecDeque::with_capacity(STDERR_TAIL_LINES)));
        let tail = Arc::clone(&stderr_tail);
        std::thread::spawn(move || {
            for_each_line(stderr, |line| {
                tracing::trace!(target: "blender", "{line}");
                if let Ok(mut t) = tail.lock() {
                    if t.len() == STDERR_TAIL_LINES {
                        t.pop_front();
                    }
                    t.push_back(line);
                }
                true
            });
        });

        let mut worker = Worker { child, stdin, replies, stderr_tail, hello: Hello { status: String::new(), blender: String::new(), python: String::new(), rss_bytes: None } };
        let line = worker.next_line(cfg.startup_timeout).map_err(|e| match e {
            WorkerError::Crashed { status, tail } => WorkerError::Start { runtime: runtime.clone(), message: format!("exited during start-up ({status}){tail}") },
            WorkerError::Timeout(d) => WorkerError::Start { runtime: runtime.clone(), message: format!("no answer within {d:?} of start-up") },
            other => other,
        })?;
        let hello: Hello = serde_json::from_str(&line).map_err(|e| WorkerError::Start { runtime: runtime.clone(), message: format!("unexpected first line {line:?}: {e}") })?;
        if hello.status != "ready" {
            return Err(WorkerError::Start { runtime, message: format!("worker says {line}") });
        }
        if !hello.blender.starts_with(&format!("{BLENDER_SERIES}.")) {
            return Err(WorkerError::WrongVersion { runtime, found: hello.blender });
        }
        tracing::debug!("worker {} ready: Blender {} / Python {}", worker.child.id(), hello.blender, hello.python);
        worker.hello = hello;
        Ok(worker)
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    fn next_line(&mut self, timeout: Duration) -> Result<String, WorkerError> {
        match self.replies.recv_timeout(timeout) {
            Ok(line) => Ok(line),
            Err(RecvTimeoutError::Timeout) => {
                self.kill();
                Err(WorkerError::Timeout(timeout))
            }
            Err(RecvTimeoutError::Disconnected) => {
                let status = self.child.wait().map(|s| describe_status(&s)).unwrap_or_else(|e| e.to_string());
                // Give the stderr thread a moment to collect the last words.
                std::thread::sleep(Duration::from_millis(50));
                Err(WorkerError::Crashed { status, tail: tail_text(&self.stderr_tail) })
            }
        }
    }

    /// Renders one spec into `out_dir`.
    pub fn render(&mut self, spec: &SceneSpec, out_dir: &Path, fault: Option<Fault>, timeout: Duration) -> Result<RenderReply, WorkerError> {
        let request = RenderRequest { cmd: "render", spec, out_dir: out_dir.to_path_buf(), fault };
        let mut line = serde_json::to_string(&request).expect("requests serialise");
        line.push('\n');
        if self.stdin.write_all(line.as_bytes()).and_then(|()| self.stdin.flush()).is_err() {
            // The pipe is closed: the worker is gone; report how it died.
            return Err(self.next_line(Duration::from_secs(5)).err().unwrap_or_else(|| WorkerError::Protocol("worker closed its input".into())));
        }
        let reply_line = self.next_line(timeout)?;
        let reply: RenderReply = serde_json::from_str(&reply_line).map_err(|e| WorkerError::Protocol(format!("{e} in {reply_line:?}")))?;
        match reply.status.as_str() {
            "ok" if reply.files.is_some() => Ok(reply),
            "error" => Err(WorkerError::Scene(reply.error.unwrap_or_else(|| "unknown error".into()))),
            _ => Err(WorkerError::Protocol(format!("unexpected reply {reply_line:?}"))),
        }
    }

    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// Asks the worker to quit, and kills it if it does not within a few seconds.
    pub fn shutdown(mut self) {
        let _ = self.stdin.write_all(b"{\"cmd\":\"quit\"}\n");
        let _ = self.stdin.flush();
        if !matches!(wait_timeout::ChildExt::wait_timeout(&mut self.child, Duration::from_secs(5)), Ok(Some(_))) {
            self.kill();
        }
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(None)) {
            self.kill();
        }
    }
}

fn describe_status(status: &std::process::ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    match (status.code(), status.signal()) {
        (Some(c), _) => format!("exit code {c}"),
        (None, Some(s)) => format!("killed by signal {s}"),
        _ => status.to_string(),
    }
}

/// Where intermediate files go: tmpfs when the machine has one (renders never touch the disk
/// until the finished files are written), otherwise the system temp dir.
pub fn scratch_base() -> PathBuf {
    let shm = Path::new("/dev/shm");
    if shm.is_dir() && tempfile::tempdir_in(shm).is_ok() { shm.to_path_buf() } else { std::env::temp_dir() }
}

/// Keeps one worker alive: starts it lazily, restarts it after a crash or hang, and retries.
pub struct RenderService {
    cfg: WorkerConfig,
    worker: Option<Worker>,
    scratch: PathBuf,
    /// Worker restarts so far (crashes and hangs).
    pub restarts: u32,
}

/// A finished render: the reply plus the scratch directory that holds its files until dropped.
pub struct Rendered {
    pub reply: RenderReply,
    pub scratch: tempfile::TempDir,
}

impl RenderService {
    pub fn new(cfg: WorkerConfig) -> Self {
        Self { cfg, worker: None, scratch: scratch_base(), restarts: 0 }
    }

    pub fn worker_pid(&self) -> Option<u32> {
        self.worker.as_ref().map(Worker::pid)
    }

    fn ensure_worker(&mut self) -> Result<&mut Worker, WorkerError> {
        if self.worker.is_none() {
            self.worker = Some(Worker::spawn(&self.cfg)?);
        }
        Ok(self.worker.as_mut().expect("just set"))
    }

    /// Renders `spec`, retrying on crashes and hangs. `fault` picks an injected failure per attempt.
    pub fn render(&mut self, spec: &SceneSpec, fault: impl Fn(u32) -> Option<Fault>) -> Result<Rendered, WorkerError> {
        let mut attempt = 0;
        loop {
            let scratch = tempfile::Builder::new()
                .prefix("stereogen-")
                .tempdir_in(&self.scratch)
                .map_err(|e| WorkerError::Scratch(format!("{}: {e}", self.scratch.display())))?;
            let timeout = self.cfg.render_timeout;
            let outcome = self.ensure_worker().and_then(|w| w.render(spec, scratch.path(), fault(attempt), timeout));
            match outcome {
                Ok(reply) => return Ok(Rendered { reply, scratch }),
                Err(e) if e.is_fatal() => return Err(e),
                Err(e @ WorkerError::Scene(_)) => return Err(e),
                Err(e) => {
                    // Crash, hang or garbage: this worker is no longer trusted.
                    if let Some(mut w) = self.worker.take() {
                        w.kill();
                    }
                    self.restarts += 1;
                    if attempt >= self.cfg.retries {
                        return Err(e);
                    }
                    tracing::warn!("sample {}: {e}; restarting the worker (attempt {} of {})", spec.id, attempt + 2, self.cfg.retries + 1);
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
