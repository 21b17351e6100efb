//! The liveness channel of a multi-process run: one TCP connection from every process to rank 0,
//! held open for the whole run, so that a process that ends is noticed by the others at once.
//!
//! Burn's collective has no failure detection: a peer that dies leaves the others blocked in
//! their all-reduce for ever. The kernel closes a dead process's sockets, so an end of stream on
//! this channel before the run's orderly end means the peer is gone: rank 0 then stops (and so
//! closes every other connection), and each rank that sees rank 0's connection end stops too —
//! one clear line each, exit status [`EXIT_PEER_LOST`], within a second or two. (A process that
//! hangs while alive is caught by the collective's timeout instead: see `collective.rs`.)
//!
//! The channel also checks at start-up that the processes agree (rank numbers, devices per
//! process, the run's identity), so a mismatched launch fails before any work. It carries no
//! tensors.
//!
//! Text lines: a rank sends `HELLO rank devices identity`; rank 0 answers `OK` or `ERR reason`
//! once all have joined. At the end each rank sends `DONE`; rank 0 answers `FINISH` when every
//! rank has, and only then exits, so no one mistakes an orderly end for a death.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{Shutdown, TcpListener, TcpStream, ToSocketAddrs};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};

/// Exit status of a rank stopped because another one ended or stopped answering (69,
/// `EX_UNAVAILABLE` of `sysexits.h`).
pub const EXIT_PEER_LOST: i32 = 69;

/// What a process tells rank 0 when it joins.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Hello {
    pub rank: usize,
    /// Devices (replicas) of this process.
    pub devices: usize,
    /// Hash of what the processes must agree on (config, run directory, resumed step).
    pub identity: u64,
}

impl Hello {
    fn line(&self) -> String {
        format!(
            "HELLO {} {} {:016x}\n",
            self.rank, self.devices, self.identity
        )
    }

    fn parse(line: &str) -> Option<Self> {
        let mut parts = line.split_whitespace();
        if parts.next()? != "HELLO" {
            return None;
        }
        let rank = parts.next()?.parse().ok()?;
        let devices = parts.next()?.parse().ok()?;
        let identity = u64::from_str_radix(parts.next()?, 16).ok()?;
        Some(Self {
            rank,
            devices,
            identity,
        })
    }
}

/// Ends the process: another rank is gone.
fn peer_lost(message: &str) -> ! {
    eprintln!("error: {message}");
    std::process::exit(EXIT_PEER_LOST);
}

/// This process's end of the channel.
pub enum Liveness {
    /// Rank 0: a connection to every other rank.
    Server {
        peers: Vec<(usize, TcpStream)>,
        done: Arc<AtomicUsize>,
        finishing: Arc<AtomicBool>,
    },
    /// Any other rank: its connection to rank 0.
    Client {
        stream: TcpStream,
        finished: Arc<AtomicBool>,
        ended: Arc<(Mutex<bool>, std::sync::Condvar)>,
    },
}

impl Liveness {
    /// Rank 0: listens on `port` until the `size - 1` other ranks have joined (at most
    /// `timeout`), checks they agree with `own`, and watches them from then on.
    pub fn serve(port: u16, size: usize, own: Hello, timeout: Duration) -> Result<Self> {
        let listener = TcpListener::bind(("0.0.0.0", port))
            .with_context(|| format!("rank 0 cannot listen on port {port} (liveness channel)"))?;
        listener.set_nonblocking(true)?;
        let deadline = Instant::now() + timeout;
        let mut peers: Vec<(Hello, TcpStream)> = Vec::new();
        while peers.len() + 1 < size {
            match listener.accept() {
                Ok((stream, addr)) => {
                    stream.set_nonblocking(false)?;
                    stream.set_read_timeout(Some(Duration::from_secs(30)))?;
                    let mut line = String::new();
                    BufReader::new(stream.try_clone()?)
                        .take(256)
                        .read_line(&mut line)
                        .with_context(|| format!("reading the greeting of {addr}"))?;
                    let Some(hello) = Hello::parse(&line) else {
                        tracing::warn!(
                            "liveness port {port}: ignored a connection from {addr} that is not a rank"
                        );
                        continue;
                    };
                    stream.set_read_timeout(None)?;
                    peers.push((hello, stream));
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                    if Instant::now() > deadline {
                        let joined: Vec<usize> = peers.iter().map(|(h, _)| h.rank).collect();
                        bail!(
                            "only {} of {size} processes joined within {} s (ranks joined besides 0: {joined:?}); check that every rank was started with the same --master-addr/--master-port",
                            peers.len() + 1,
                            timeout.as_secs()
                        );
                    }
                    std::thread::sleep(Duration::from_millis(20));
                }
                Err(e) => return Err(e).context("accepting a rank on the liveness channel"),
            }
        }
        // Every rank once, all agreeing with rank 0.
        let mut problem = None;
        let mut seen = vec![false; size];
        seen[0] = true;
        for (h, _) in &peers {
            let p = if h.rank == 0 || h.rank >= size || seen[h.rank] {
                Some(format!(
                    "rank {} joined twice or out of range 1..{size}",
                    h.rank
                ))
            } else if h.devices != own.devices {
                Some(format!(
                    "rank {} has {} devices, rank 0 has {}: every process must hold the same number",
                    h.rank, h.devices, own.devices
                ))
            } else if h.identity != own.identity {
                Some(format!(
                    "rank {} runs another config, run directory or checkpoint than rank 0: start every rank with the same arguments on a shared run directory",
                    h.rank
                ))
            } else {
                None
            };
            if h.rank < size {
                seen[h.rank] = true;
            }
            problem = problem.or(p);
        }
        let answer = match &problem {
            Some(p) => format!("ERR {p}\n"),
            None => "OK\n".to_string(),
        };
        for (_, s) in &mut peers {
            let _ = s.write_all(answer.as_bytes());
        }
        if let Some(p) = problem {
            bail!("{p}");
        }
        let done = Arc::new(AtomicUsize::new(0));
        let finishing = Arc::new(AtomicBool::new(false));
        let peers: Vec<(usize, TcpStream)> = peers.into_iter().map(|(h, s)| (h.rank, s)).collect();
        for (rank, stream) in &peers {
            let (rank, reader) = (*rank, stream.try_clone()?);
            let (done, finishing) = (done.clone(), finishing.clone());
            std::thread::Builder::new()
                .name(format!("liveness-{rank}"))
                .spawn(move || watch_rank(rank, size, reader, &done, &finishing))?;
        }
        Ok(Self::Server {
            peers,
            done,
            finishing,
        })
    }

    /// Any rank but 0: joins rank 0 at `addr:port` (retrying until `timeout`: rank 0 may start
    /// later) and watches the connection from then on.
    pub fn join(addr: &str, port: u16, own: Hello, size: usize, timeout: Duration) -> Result<Self> {
        let deadline = Instant::now() + timeout;
        let mut stream = loop {
            let attempt = (addr, port)
                .to_socket_addrs()
                .with_context(|| format!("cannot resolve the master address {addr}"))?
                .find_map(|a| TcpStream::connect_timeout(&a, Duration::from_secs(2)).ok());
            match attempt {
                Some(s) => break s,
                None if Instant::now() > deadline => bail!(
                    "rank 0 did not answer at {addr}:{port} within {} s (liveness channel); is rank 0 running, with the same --master-addr/--master-port?",
                    timeout.as_secs()
                ),
                None => std::thread::sleep(Duration::from_millis(100)),
            }
        };
        stream.write_all(own.line().as_bytes())?;
        let mut reader = BufReader::new(stream.try_clone()?);
        let mut answer = String::new();
        // Rank 0 answers when every rank has joined.
        stream.set_read_timeout(Some(
            deadline
                .saturating_duration_since(Instant::now())
                .max(Duration::from_secs(1)),
        ))?;
        reader
            .by_ref()
            .take(4096)
            .read_line(&mut answer)
            .context("waiting for rank 0 to accept this rank")?;
        stream.set_read_timeout(None)?;
        match answer.trim_end().split_once(' ') {
            _ if answer.trim_end() == "OK" => {}
            Some(("ERR", reason)) => bail!("rank 0 refused the run: {reason}"),
            _ => bail!(
                "rank 0 closed the liveness channel before every rank of {size} joined (it stopped: see its log)"
            ),
        }
        let finished = Arc::new(AtomicBool::new(false));
        let ended = Arc::new((Mutex::new(false), std::sync::Condvar::new()));
        {
            let (finished, ended) = (finished.clone(), ended.clone());
            let rank = own.rank;
            std::thread::Builder::new()
                .name("liveness".into())
                .spawn(move || watch_master(rank, size, reader, &finished, &ended))?;
        }
        Ok(Self::Client {
            stream,
            finished,
            ended,
        })
    }

    /// The orderly end: every rank says it is done; rank 0 returns once all have (at most
    /// `timeout`), the others once rank 0 confirms — after which no end of stream is a death.
    pub fn finish(self, timeout: Duration) -> Result<()> {
        match self {
            Self::Server {
                peers,
                done,
                finishing,
            } => {
                let deadline = Instant::now() + timeout;
                while done.load(Ordering::SeqCst) < peers.len() {
                    if Instant::now() > deadline {
                        bail!(
                            "{} of {} ranks did not reach the end of the run within {} s",
                            peers.len() - done.load(Ordering::SeqCst),
                            peers.len() + 1,
                            timeout.as_secs()
                        );
                    }
                    std::thread::sleep(Duration::from_millis(20));
                }
                finishing.store(true, Ordering::SeqCst);
                for (_, mut s) in peers {
                    let _ = s.write_all(b"FINISH\n");
                    let _ = s.shutdown(Shutdown::Write);
                }
                Ok(())
            }
            Self::Client {
                mut stream,
                finished,
                ended,
            } => {
                stream
                    .write_all(b"DONE\n")
                    .context("telling rank 0 this rank is done")?;
                let (lock, cv) = &*ended;
                let guard = lock.lock().unwrap();
                let (_guard, wait) = cv
                    .wait_timeout_while(guard, timeout, |ended| !*ended)
                    .unwrap();
                if wait.timed_out() || !finished.load(Ordering::SeqCst) {
                    bail!(
                        "rank 0 did not confirm the end of the run within {} s",
                        timeout.as_secs()
                    );
                }
                Ok(())
            }
        }
    }
}

/// Rank 0's watch over one rank: counts its `DONE`; an end of stream before it stops the run.
fn watch_rank(
    rank: usize,
    size: usize,
    stream: TcpStream,
    done: &AtomicUsize,
    finishing: &AtomicBool,
) {
    let peer = stream
        .peer_addr()
        .map_or_else(|_| "?".to_string(), |a| a.to_string());
    let mut reader = BufReader::new(stream);
    let mut said_done = false;
    loop {
        let mut line = String::new();
        match reader.by_ref().take(256).read_line(&mut line) {
            Ok(0) | Err(_) => {
                if said_done || finishing.load(Ordering::SeqCst) {
                    return;
                }
                peer_lost(&format!(
                    "rank {rank} of {size} ({peer}) disconnected before the end of the run: its process ended (see its log) or the network failed; stopping every rank (the last whole checkpoint is kept; continue with --resume)"
                ));
            }
            Ok(_) if line.trim_end() == "DONE" => {
                if !said_done {
                    said_done = true;
                    done.fetch_add(1, Ordering::SeqCst);
                }
            }
            Ok(_) => {}
        }
    }
}

/// A rank's watch over rank 0: `FINISH` ends the run; an end of stream before it stops this
/// rank.
fn watch_master(
    rank: usize,
    size: usize,
    mut reader: BufReader<TcpStream>,
    finished: &AtomicBool,
    ended: &(Mutex<bool>, std::sync::Condvar),
) {
    loop {
        let mut line = String::new();
        match reader.by_ref().take(256).read_line(&mut line) {
            Ok(0) | Err(_) => {
                if finished.load(Ordering::SeqCst) {
                    let (lock, cv) = ended;
                    *lock.lock().unwrap() = true;
                    cv.notify_all();
                    return;
                }
                peer_lost(&format!(
                    "rank 0 of {size} ended before the run did (seen by rank {rank}): a rank stopped (see rank 0's log) or the network failed; stopping this rank (the last whole checkpoint is kept; continue with --resume)"
                ));
            }
            Ok(_) if line.trim_end() == "FINISH" => {
                finished.store(true, Ordering::SeqCst);
                let (lock, cv) = ended;
                *lock.lock().unwrap() = true;
                cv.notify_all();
                return;
            }
            Ok(_) => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn greetings_round_trip() {
        let h = Hello {
            rank: 3,
            devices: 2,
            identity: 0xDEAD_BEEF_0123_4567,
        };
        assert_eq!(Hello::parse(&h.line()), Some(h));
        assert_eq!(Hello::parse("GET / HTTP/1.1"), None);
        assert_eq!(Hello::parse("HELLO x 1 0"), None);
    }

    fn free_port() -> u16 {
        TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port()
    }

    #[test]
    fn ranks_join_check_identity_and_finish_in_order() {
        let port = free_port();
        let hello = |rank| Hello {
            rank,
            devices: 1,
            identity: 7,
        };
        let server = std::thread::spawn(move || {
            let s = Liveness::serve(port, 3, hello(0), Duration::from_secs(20)).unwrap();
            s.finish(Duration::from_secs(20)).unwrap();
        });
        let clients: Vec<_> = (1..3)
            .map(|r| {
                std::thread::spawn(move || {
                    let c = Liveness::join("127.0.0.1", port, hello(r), 3, Duration::from_secs(20))
                        .unwrap();
                    c.finish(Duration::from_secs(20)).unwrap();
                })
            })
            .collect();
        for c in clients {
            c.join().unwrap();
        }
        server.join().unwrap();
    }

    #[test]
    fn a_rank_with_another_identity_is_refused_by_name() {
        let port = free_port();
        let server = std::thread::spawn(move || {
            let own = Hello {
                rank: 0,
                devices: 1,
                identity: 1,
            };
            Liveness::serve(port, 2, own, Duration::from_secs(20)).map(|_| ())
        });
        let other = Hello {
            rank: 1,
            devices: 1,
            identity: 2,
        };
        let e = Liveness::join("127.0.0.1", port, other, 2, Duration::from_secs(20))
            .err()
            .expect("refused");
        assert!(e.to_string().contains("rank 1 runs another config"), "{e}");
        let e = server.join().unwrap().unwrap_err();
        assert!(e.to_string().contains("rank 1"), "{e}");
    }

    #[test]
    fn rank_0_times_out_waiting_for_the_others() {
        let port = free_port();
        let own = Hello {
            rank: 0,
            devices: 1,
            identity: 1,
        };
        let e = Liveness::serve(port, 2, own, Duration::from_millis(300))
            .err()
            .expect("a timeout");
        assert!(
            e.to_string().contains("only 1 of 2 processes joined"),
            "{e}"
        );
    }
}
