//! One file over HTTP(S): resumed from a `.part` file with a `Range` request, redirects followed
//! by hand so the checksum the first hop announces (`X-Linked-Etag`, the SHA-256 of a Hugging Face
//! LFS file) is not lost, and verified before it is renamed into place.

use std::fs::{File, OpenOptions};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::time::Duration;

use stereo_io::digest::sha256_file_with_len;

/// Redirect hops followed per request.
const MAX_REDIRECTS: usize = 8;

pub fn agent(timeout: Duration) -> ureq::Agent {
    ureq::AgentBuilder::new()
        .timeout_connect(timeout)
        .timeout_read(timeout)
        .redirects(0)
        .user_agent(concat!("stereogen/", env!("CARGO_PKG_VERSION")))
        .build()
}

/// A SHA-256 announced in an ETag-like header (`"<64 hex>"`, possibly weak `W/`).
fn sha256_of_etag(value: &str) -> Option<String> {
    let v = value
        .trim()
        .trim_start_matches("W/")
        .trim_matches('"')
        .to_ascii_lowercase();
    (v.len() == 64 && v.chars().all(|c| c.is_ascii_hexdigit())).then_some(v)
}

/// Why a download did not finish; `retry` says whether trying again may help.
#[derive(Debug)]
pub struct DownloadError {
    pub message: String,
    pub retry: bool,
}

fn fail(message: impl Into<String>, retry: bool) -> DownloadError {
    DownloadError {
        message: message.into(),
        retry,
    }
}

/// The response to `GET url` (from byte `offset` on), after redirects, and any SHA-256 a hop
/// announced.
fn get(
    agent: &ureq::Agent,
    url: &str,
    offset: u64,
) -> Result<(ureq::Response, Option<String>), DownloadError> {
    let mut url = url.to_string();
    let mut announced = None;
    for _ in 0..=MAX_REDIRECTS {
        let mut req = agent.get(&url);
        if offset > 0 {
            req = req.set("Range", &format!("bytes={offset}-"));
        }
        let resp = match req.call() {
            Ok(r) => r,
            Err(ureq::Error::Status(code, r)) => {
                if code == 416 {
                    return Ok((r, announced));
                }
                return Err(fail(
                    format!("HTTP {code} from {url}"),
                    code >= 500 || code == 429,
                ));
            }
            Err(e) => return Err(fail(format!("{url}: {e}"), true)),
        };
        if announced.is_none() {
            announced = resp.header("x-linked-etag").and_then(sha256_of_etag);
        }
        if (300..400).contains(&resp.status()) {
            let location = resp.header("location").ok_or_else(|| {
                fail(
                    format!("HTTP {} from {url} without a Location", resp.status()),
                    false,
                )
            })?;
            url = join_location(resp.get_url(), location);
            continue;
        }
        return Ok((resp, announced));
    }
    Err(fail(
        format!("{url}: more than {MAX_REDIRECTS} redirects"),
        false,
    ))
}

/// A `Location` header resolved against the URL it answered.
fn join_location(base: &str, location: &str) -> String {
    if location.contains("://") {
        return location.to_string();
    }
    let scheme_end = base.find("://").map_or(0, |i| i + 3);
    let host_end = base[scheme_end..]
        .find('/')
        .map_or(base.len(), |i| scheme_end + i);
    if location.starts_with('/') {
        return format!("{}{location}", &base[..host_end]);
    }
    let dir_end = base
        .rfind('/')
        .filter(|&i| i >= host_end)
        .map_or(base.len(), |i| i + 1);
    format!("{}{location}", &base[..dir_end])
}

/// Where the body of a response starts, from its `Content-Range` (206) or 0 (200).
fn body_start(resp: &ureq::Response) -> u64 {
    if resp.status() != 206 {
        return 0;
    }
    resp.header("content-range")
        .and_then(|v| v.trim().strip_prefix("bytes "))
        .and_then(|v| v.split('-').next())
        .and_then(|s| s.trim().parse().ok())
        .unwrap_or(0)
}

/// Downloads `url` into `dest` through `dest.part`, resuming what an earlier attempt left, with
/// up to `retries` further attempts. `check` vets the finished bytes (e.g. a GLB header).
/// Returns the file's SHA-256 and length; on failure nothing is left at `dest`.
pub fn download(
    agent: &ureq::Agent,
    url: &str,
    dest: &Path,
    retries: u32,
    on_bytes: &dyn Fn(u64),
    check: &dyn Fn(&Path) -> Result<(), String>,
) -> Result<(String, u64), String> {
    let part = PathBuf::from(format!("{}.part", dest.display()));
    let mut last = String::new();
    for _ in 0..=retries {
        match attempt(agent, url, &part, on_bytes) {
            Ok(announced) => {
                let (sha, bytes) = sha256_file_with_len(&part)
                    .map_err(|e| format!("cannot read {}: {e}", part.display()))?;
                if let Some(expected) = announced
                    && expected != sha
                {
                    let _ = std::fs::remove_file(&part);
                    last = format!(
                        "checksum mismatch: got SHA-256 {sha}, the server announced {expected}"
                    );
                    continue;
                }
                if let Err(reason) = check(&part) {
                    let _ = std::fs::remove_file(&part);
                    return Err(reason);
                }
                std::fs::rename(&part, dest)
                    .map_err(|e| format!("cannot move {} into place: {e}", part.display()))?;
                return Ok((sha, bytes));
            }
            Err(e) if e.retry => last = e.message,
            Err(e) => return Err(e.message),
        }
    }
    Err(format!("gave up after {} attempts: {last}", retries + 1))
}

/// One request: appends to `part` from where it ends. Returns the announced SHA-256, if any.
fn attempt(
    agent: &ureq::Agent,
    url: &str,
    part: &Path,
    on_bytes: &dyn Fn(u64),
) -> Result<Option<String>, DownloadError> {
    let have = part.metadata().map(|m| m.len()).unwrap_or(0);
    let (resp, announced) = get(agent, url, have)?;
    if resp.status() == 416 {
        // The part holds more than the file: start over.
        let _ = std::fs::remove_file(part);
        return Err(fail(
            format!("{url}: the partial download is longer than the file"),
            true,
        ));
    }
    let start = body_start(&resp);
    let mut file = if start == have && have > 0 {
        OpenOptions::new().append(true).open(part)
    } else {
        File::create(part)
    }
    .map_err(|e| fail(format!("cannot write {}: {e}", part.display()), false))?;
    let mut reader = resp.into_reader();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let k = reader
            .read(&mut buf)
            .map_err(|e| fail(format!("{url}: connection lost: {e}"), true))?;
        if k == 0 {
            break;
        }
        file.write_all(&buf[..k])
            .map_err(|e| fail(format!("cannot write {}: {e}", part.display()), false))?;
        on_bytes(k as u64);
    }
    file.sync_all()
        .map_err(|e| fail(format!("cannot write {}: {e}", part.display()), false))?;
    Ok(announced)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn etags_and_locations() {
        let sha = "a".repeat(64);
        assert_eq!(sha256_of_etag(&format!("\"{sha}\"")), Some(sha.clone()));
        assert_eq!(sha256_of_etag("\"abc\""), None);
        let base = "http://127.0.0.1:8/resolve/main/glbs/x.glb";
        assert_eq!(
            join_location(base, "/cdn/x.glb"),
            "http://127.0.0.1:8/cdn/x.glb"
        );
        assert_eq!(
            join_location(base, "y.glb"),
            "http://127.0.0.1:8/resolve/main/glbs/y.glb"
        );
        assert_eq!(
            join_location(base, "https://cdn.example/z"),
            "https://cdn.example/z"
        );
    }
}
