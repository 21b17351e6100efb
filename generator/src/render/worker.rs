//! One Blender worker process: started, spoken to over the protocol, watched for crashes and
//! hangs. [`super::service`] keeps one alive across them.

use std::collections::VecDeque;
use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStderr, ChildStdin, ChildStdout, Stdio};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::Context;

use super::protocol::{
    Device, Fault, GeometryOutput, Hello, RenderOutput, Reply, Request, WORKER_TIMINGS,
};
use super::runtime::{BLENDER_SERIES, BlenderRuntime, discover_or_install, stereogen_home};
use super::scratch;
use super::scripts::install_scripts;
use crate::interrupt::StopFlag;
use crate::plan::SceneSpec;
use crate::plan::spec::SPEC_FORMAT_VERSION;

const STDERR_TAIL_LINES: usize = 30;

/// How workers are found, started and supervised: what `--blender`, `--device`, `--threads`,
/// `--timeout` and `--retries` set. [`WorkerOptions::resolve`] turns it into a [`WorkerConfig`].
#[derive(Debug, Clone, PartialEq)]
pub struct WorkerOptions {
    /// A Blender executable; `None`: `$STEREOGEN_PYTHON`, then the managed environment.
    pub blender: Option<PathBuf>,
    pub device: Device,
    /// Cycles threads per worker; `None` splits the machine's cores between the workers.
    pub threads: Option<u32>,
    /// Time allowed for Blender to start and import `bpy`.
    pub startup_timeout: Duration,
    /// Time allowed for one spec, build and both views.
    pub render_timeout: Duration,
    /// Attempts after the first when a worker crashes or hangs.
    pub retries: u32,
}

impl WorkerOptions {
    pub const DEFAULT_RENDER_TIMEOUT_S: u64 = 900;
    pub const DEFAULT_STARTUP_TIMEOUT_S: u64 = 120;
    pub const DEFAULT_RETRIES: u32 = 2;

    /// Finds (or installs) the Blender runtime, installs the worker scripts, and gives each of
    /// `workers` workers its share of the cores unless `threads` is set.
    pub fn resolve(&self, workers: usize) -> anyhow::Result<WorkerConfig> {
        let home = stereogen_home();
        let runtime = discover_or_install(self.blender.as_deref(), &home)?;
        let script = install_scripts(&home).with_context(|| {
            format!("cannot write the Blender scripts under {}", home.display())
        })?;
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get()) as u32;
        Ok(WorkerConfig {
            runtime,
            script,
            threads: self
                .threads
                .unwrap_or_else(|| (cores / workers.max(1) as u32).max(1)),
            device: self.device,
            startup_timeout: self.startup_timeout,
            render_timeout: self.render_timeout,
            retries: self.retries,
            scratch: scratch::default_base(),
            stop: StopFlag::new(),
        })
    }
}

impl Default for WorkerOptions {
    fn default() -> Self {
        Self {
            blender: None,
            device: Device::Cpu,
            threads: None,
            startup_timeout: Duration::from_secs(Self::DEFAULT_STARTUP_TIMEOUT_S),
            render_timeout: Duration::from_secs(Self::DEFAULT_RENDER_TIMEOUT_S),
            retries: Self::DEFAULT_RETRIES,
        }
    }
}

/// A resolved worker setup: the runtime and scripts to run, and how to supervise them.
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
    /// Where each render's scratch folder is made (see [`scratch::choose_base`]).
    pub scratch: PathBuf,
    /// Set: start nothing more, kill the worker and abandon its render ([`WorkerError::Interrupted`]).
    pub stop: StopFlag,
}

#[derive(Debug, thiserror::Error)]
pub enum WorkerError {
    #[error("cannot start Blender ({runtime}): {message}")]
    Start { runtime: String, message: String },
    #[error(
        "Blender ({runtime}) reports version {found}; stereogen needs Blender {BLENDER_SERIES} LTS"
    )]
    WrongVersion { runtime: String, found: String },
    #[error("the Blender worker script {script} understands SceneSpec version {}, this stereogen writes version {ours}; \
             the script and the binary come from different builds", .worker.map_or("(none stated)".to_string(), |v| v.to_string()))]
    SpecVersion {
        script: PathBuf,
        worker: Option<u32>,
        ours: u32,
    },
    #[error("Blender worker died ({status}){tail}")]
    Crashed { status: String, tail: String },
    #[error("Blender worker gave no answer within {0:?} and was killed")]
    Timeout(Duration),
    #[error("Blender worker broke the protocol: {0}")]
    Protocol(String),
    #[error("scene failed in Blender: {message}")]
    Scene {
        message: String,
        traceback: Option<String>,
    },
    #[error("cannot create a scratch directory in {0}")]
    Scratch(String),
    #[error("the render was abandoned: the run is stopping")]
    Interrupted,
}

impl WorkerError {
    /// Errors that will happen again for every sample: the whole run should stop.
    pub fn is_fatal(&self) -> bool {
        matches!(
            self,
            WorkerError::Start { .. }
                | WorkerError::WrongVersion { .. }
                | WorkerError::SpecVersion { .. }
                | WorkerError::Scratch(_)
                | WorkerError::Interrupted
        )
    }

    /// The worker's Python traceback, for a scene that raised.
    pub fn traceback(&self) -> Option<&str> {
        match self {
            WorkerError::Scene { traceback, .. } => traceback.as_deref(),
            _ => None,
        }
    }
}

/// A running worker that has said hello. Killed when dropped.
pub struct Worker {
    process: Process,
    /// What the worker said when it started.
    pub hello: Hello,
}

/// The worker process and its pipes.
struct Process {
    child: Child,
    stdin: ChildStdin,
    replies: Receiver<String>,
    stderr_tail: Arc<Mutex<VecDeque<String>>>,
    stop: StopFlag,
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
                let line = String::from_utf8_lossy(&buf)
                    .trim_end_matches(['\n', '\r'])
                    .to_string();
                if !f(line) {
                    break;
                }
            }
        }
    }
}

fn tail_text(tail: &Mutex<VecDeque<String>>) -> String {
    let lines = tail
        .lock()
        .map(|t| t.iter().cloned().collect::<Vec<_>>())
        .unwrap_or_default();
    let interesting: Vec<&String> = lines.iter().filter(|l| !l.starts_with("Fra:")).collect();
    if interesting.is_empty() {
        String::new()
    } else {
        format!(
            "; last output: {}",
            interesting
                .iter()
                .rev()
                .take(6)
                .rev()
                .map(|s| s.as_str())
                .collect::<Vec<_>>()
                .join(" | ")
        )
    }
}

impl Worker {
    /// Starts a worker and waits for its hello; refuses a wrong Blender or SceneSpec version.
    pub fn spawn(cfg: &WorkerConfig) -> Result<Self, WorkerError> {
        let runtime = cfg.runtime.describe();
        let mut child = start_process(cfg).map_err(|e| WorkerError::Start {
            runtime: runtime.clone(),
            message: e.to_string(),
        })?;
        let stdin = child.stdin.take().expect("piped");
        let replies = read_lines_in_background(child.stdout.take().expect("piped"));
        let stderr_tail = collect_stderr_tail(child.stderr.take().expect("piped"));
        let mut process = Process {
            child,
            stdin,
            replies,
            stderr_tail,
            stop: cfg.stop.clone(),
        };
        let hello = read_hello(&mut process, cfg, &runtime)?;
        tracing::debug!(
            "worker {} ready: Blender {} / Python {}",
            process.child.id(),
            hello.blender,
            hello.python
        );
        Ok(Worker { process, hello })
    }

    /// Renders one spec into `out_dir`.
    pub fn render(
        &mut self,
        spec: &SceneSpec,
        out_dir: &Path,
        fault: Option<Fault>,
        timeout: Duration,
    ) -> Result<RenderOutput, WorkerError> {
        let request = Request::Render {
            spec,
            out_dir,
            fault,
        };
        match self.process.exchange(&request, timeout)? {
            (Reply::Ok(output), _) => Ok(output),
            (_, line) => Err(WorkerError::Protocol(format!("unexpected reply {line:?}"))),
        }
    }

    /// Builds one spec and writes its evaluated geometry into `out_dir` (no render).
    pub fn export_geometry(
        &mut self,
        spec: &SceneSpec,
        out_dir: &Path,
        timeout: Duration,
    ) -> Result<GeometryOutput, WorkerError> {
        let request = Request::ExportGeometry { spec, out_dir };
        match self.process.exchange(&request, timeout)? {
            (Reply::Geometry(output), _) => Ok(output),
            (_, line) => Err(WorkerError::Protocol(format!("unexpected reply {line:?}"))),
        }
    }

    pub fn kill(&mut self) {
        self.process.kill();
    }

    /// Asks the worker to quit, and kills it if it does not within a few seconds.
    pub fn shutdown(mut self) {
        let p = &mut self.process;
        let _ = p.stdin.write_all(Request::Quit.to_line().as_bytes());
        let _ = p.stdin.flush();
        if !matches!(
            wait_timeout::ChildExt::wait_timeout(&mut p.child, Duration::from_secs(5)),
            Ok(Some(_))
        ) {
            p.kill();
        }
    }
}

/// The worker's first line: its hello, checked for the Blender series and the SceneSpec version.
fn read_hello(
    process: &mut Process,
    cfg: &WorkerConfig,
    runtime: &str,
) -> Result<Hello, WorkerError> {
    let start_error = |message: String| WorkerError::Start {
        runtime: runtime.to_string(),
        message,
    };
    let line = process
        .next_line(cfg.startup_timeout)
        .map_err(|e| match e {
            WorkerError::Crashed { status, tail } => {
                start_error(format!("exited during start-up ({status}){tail}"))
            }
            WorkerError::Timeout(d) => start_error(format!("no answer within {d:?} of start-up")),
            other => other,
        })?;
    let hello = match serde_json::from_str::<Reply>(&line) {
        Ok(Reply::Ready(hello)) => hello,
        Ok(_) => return Err(start_error(format!("worker says {line}"))),
        Err(e) => return Err(start_error(format!("unexpected first line {line:?}: {e}"))),
    };
    if !hello.blender.starts_with(&format!("{BLENDER_SERIES}.")) {
        return Err(WorkerError::WrongVersion {
            runtime: runtime.to_string(),
            found: hello.blender,
        });
    }
    if hello.spec_format_version != Some(SPEC_FORMAT_VERSION) {
        return Err(WorkerError::SpecVersion {
            script: cfg.script.clone(),
            worker: hello.spec_format_version,
            ours: SPEC_FORMAT_VERSION,
        });
    }
    Ok(hello)
}

impl Process {
    /// The worker's next line; checks the stop flag while it waits.
    fn next_line(&mut self, timeout: Duration) -> Result<String, WorkerError> {
        const POLL: Duration = Duration::from_millis(100);
        let deadline = std::time::Instant::now() + timeout;
        let received = loop {
            if self.stop.is_set() {
                self.kill();
                return Err(WorkerError::Interrupted);
            }
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            match self.replies.recv_timeout(left.min(POLL)) {
                Err(RecvTimeoutError::Timeout) if !left.is_zero() => continue,
                other => break other,
            }
        };
        match received {
            Ok(line) => Ok(line),
            Err(RecvTimeoutError::Timeout) => {
                self.kill();
                Err(WorkerError::Timeout(timeout))
            }
            Err(RecvTimeoutError::Disconnected) => {
                let status = self
                    .child
                    .wait()
                    .map(|s| describe_status(&s))
                    .unwrap_or_else(|e| e.to_string());
                // Give the stderr thread a moment to collect the last words.
                std::thread::sleep(Duration::from_millis(50));
                Err(WorkerError::Crashed {
                    status,
                    tail: tail_text(&self.stderr_tail),
                })
            }
        }
    }

    /// Sends one request and reads its reply; an error reply becomes [`WorkerError::Scene`].
    fn exchange(
        &mut self,
        request: &Request<'_>,
        timeout: Duration,
    ) -> Result<(Reply, String), WorkerError> {
        let line = request.to_line();
        if self
            .stdin
            .write_all(line.as_bytes())
            .and_then(|()| self.stdin.flush())
            .is_err()
        {
            // The pipe is closed: the worker is gone; report how it died.
            return Err(self
                .next_line(Duration::from_secs(5))
                .err()
                .unwrap_or_else(|| WorkerError::Protocol("worker closed its input".into())));
        }
        let reply_line = self.next_line(timeout)?;
        match serde_json::from_str::<Reply>(&reply_line) {
            Ok(Reply::Error(failure)) => Err(WorkerError::Scene {
                message: failure.error,
                traceback: failure.traceback,
            }),
            Ok(reply) => Ok((reply, reply_line)),
            Err(e) => Err(WorkerError::Protocol(format!("{e} in {reply_line:?}"))),
        }
    }

    fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts the runtime on `worker.py` with piped stdio, telling it its threads, its device and
/// the names to report its stages under.
fn start_process(cfg: &WorkerConfig) -> std::io::Result<Child> {
    let args = [
        "--threads".to_string(),
        cfg.threads.to_string(),
        "--device".to_string(),
        cfg.device.to_string(),
        "--timing-keys".to_string(),
        WORKER_TIMINGS.to_arg(),
    ];
    let mut cmd = cfg.runtime.command(&cfg.script, &args);
    cmd.stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::process::CommandExt;
        // A worker must not outlive a killed orchestrator (it would keep rendering into a
        // dataset nobody finishes). The signal fires when the spawning thread exits, and
        // every worker is shut down before its thread ends. Its own process group keeps a
        // terminal's Ctrl-C away from it: the orchestrator decides when a worker stops.
        unsafe {
            cmd.pre_exec(|| {
                if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0
                    || libc::setpgid(0, 0) != 0
                {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
    }
    cmd.spawn()
}

/// The worker's protocol lines, as they arrive.
fn read_lines_in_background(stdout: ChildStdout) -> Receiver<String> {
    let (tx, replies) = mpsc::channel();
    std::thread::spawn(move || {
        for_each_line(stdout, |line| tx.send(line).is_ok());
    });
    replies
}

/// The last lines Blender printed, for the error message when it dies.
fn collect_stderr_tail(stderr: ChildStderr) -> Arc<Mutex<VecDeque<String>>> {
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
    stderr_tail
}

impl Drop for Process {
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
