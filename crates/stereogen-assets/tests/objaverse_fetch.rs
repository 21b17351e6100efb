//! `assets fetch objaverse` against a loopback HTTP server that serves a miniature Objaverse: the
//! path index, one metadata shard, and GLB files made here. Nothing reaches the internet.

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Write};
use std::net::{TcpListener, TcpStream};
use std::path::Path;
use std::sync::{Arc, Mutex};

use serde_json::json;
use sha2::{Digest, Sha256};
use stereogen_assets::meshes::index_mesh_folder;
use stereogen_assets::objaverse::{FetchOptions, ObjectRecord, fetch};

/// A GLB 2.0 file: header, and a JSON chunk padded to 4 bytes.
fn glb(name: &str) -> Vec<u8> {
    let mut text = json!({"asset": {"version": "2.0", "generator": name}})
        .to_string()
        .into_bytes();
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    let total = 12 + 8 + text.len();
    let mut out = Vec::new();
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&text);
    out
}

fn gz(value: &serde_json::Value) -> Vec<u8> {
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    e.write_all(value.to_string().as_bytes()).unwrap();
    e.finish().unwrap()
}

fn sha(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// What the server saw: (path, Range header).
type Log = Arc<Mutex<Vec<(String, Option<String>)>>>;

struct Server {
    base: String,
    log: Log,
}

/// Serves `files`; `/glbs/...` answers with a redirect to `/cdn/...` that announces the file's
/// SHA-256 (as the Hugging Face hub does), and the paths in `cut_once` lose their connection
/// half-way through the body the first time they are asked for.
fn serve(files: BTreeMap<String, Vec<u8>>, cut_once: Vec<String>) -> Server {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let base = format!("http://{}", listener.local_addr().unwrap());
    let log: Log = Arc::default();
    let cut = Arc::new(Mutex::new(cut_once));
    let seen = log.clone();
    std::thread::spawn(move || {
        for stream in listener.incoming().flatten() {
            let (files, seen, cut) = (files.clone(), seen.clone(), cut.clone());
            std::thread::spawn(move || answer(stream, &files, &seen, &cut));
        }
    });
    Server { base, log }
}

fn answer(
    mut stream: TcpStream,
    files: &BTreeMap<String, Vec<u8>>,
    seen: &Log,
    cut: &Mutex<Vec<String>>,
) {
    let mut reader = BufReader::new(stream.try_clone().unwrap());
    let mut line = String::new();
    reader.read_line(&mut line).unwrap();
    let path = line.split_whitespace().nth(1).unwrap_or("/").to_string();
    let mut range = None;
    loop {
        let mut h = String::new();
        if reader.read_line(&mut h).unwrap() == 0 || h.trim().is_empty() {
            break;
        }
        if let Some((k, v)) = h.split_once(':')
            && k.eq_ignore_ascii_case("range")
        {
            range = Some(v.trim().to_string());
        }
    }
    seen.lock().unwrap().push((path.clone(), range.clone()));
    if let Some(rest) = path.strip_prefix("/glbs/")
        && let Some(bytes) = files.get(&format!("/cdn/{rest}"))
    {
        let head = format!(
            "HTTP/1.1 302 Found\r\nLocation: /cdn/{rest}\r\nX-Linked-Etag: \"{}\"\r\nContent-Length: 0\r\nConnection: close\r\n\r\n",
            sha(bytes)
        );
        let _ = stream.write_all(head.as_bytes());
        return;
    }
    let Some(bytes) = files.get(&path) else {
        let _ = stream
            .write_all(b"HTTP/1.1 404 Not Found\r\nContent-Length: 0\r\nConnection: close\r\n\r\n");
        return;
    };
    let from: usize = range
        .as_deref()
        .and_then(|r| r.strip_prefix("bytes="))
        .and_then(|r| r.trim_end_matches('-').parse().ok())
        .unwrap_or(0);
    let body = &bytes[from.min(bytes.len())..];
    let head = if from > 0 {
        format!(
            "HTTP/1.1 206 Partial Content\r\nContent-Range: bytes {from}-{}/{}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
            bytes.len() - 1,
            bytes.len(),
            body.len()
        )
    } else {
        format!(
            "HTTP/1.1 200 OK\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
            body.len()
        )
    };
    let _ = stream.write_all(head.as_bytes());
    let mut cut = cut.lock().unwrap();
    if let Some(i) = cut.iter().position(|p| *p == path) {
        cut.remove(i);
        let _ = stream.write_all(&body[..body.len() / 2]);
        let _ = stream.flush();
        let _ = stream.shutdown(std::net::Shutdown::Both);
        return;
    }
    let _ = stream.write_all(body);
}

/// The miniature Objaverse: uid → (licence, GLB bytes).
fn objects() -> Vec<(&'static str, &'static str, Vec<u8>)> {
    let mut truncated = glb("broken");
    truncated.truncate(truncated.len() - 4);
    vec![
        ("aaaa0001", "cc0", glb("chair")),
        ("aaaa0002", "by-nc", glb("restricted")),
        (
            "aaaa0003",
            "by",
            glb("table lamp with a long name to make the body longer"),
        ),
        ("aaaa0004", "by", truncated),
        ("aaaa0005", "cc0", glb("mug")),
    ]
}

fn mini_objaverse() -> BTreeMap<String, Vec<u8>> {
    let mut paths = serde_json::Map::new();
    let mut meta = serde_json::Map::new();
    let mut files = BTreeMap::new();
    for (uid, licence, bytes) in objects() {
        paths.insert(uid.into(), json!(format!("glbs/000-000/{uid}.glb")));
        meta.insert(
            uid.into(),
            json!({"name": format!("object {uid}"), "license": licence, "user": {"username": "maker"},
                   "viewerUrl": format!("https://sketchfab.com/3d-models/{uid}"),
                   "categories": [{"name": "Furniture & Home", "slug": "furniture-home"}], "tags": []}),
        );
        files.insert(format!("/cdn/000-000/{uid}.glb"), bytes);
    }
    files.insert(
        "/object-paths.json.gz".into(),
        gz(&serde_json::Value::Object(paths)),
    );
    files.insert(
        "/metadata/000-000.json.gz".into(),
        gz(&serde_json::Value::Object(meta)),
    );
    files
}

fn options(server: &Server, out: &Path, count: usize) -> FetchOptions {
    let mut opts = FetchOptions::new(out, count);
    opts.base_url = server.base.clone();
    opts.licences = vec!["cc0".into(), "cc-by".into()];
    opts.jobs = 3;
    opts.retries = 2;
    opts.timeout = std::time::Duration::from_secs(10);
    opts
}

fn ranges_for(log: &Log, uid: &str) -> Vec<Option<String>> {
    log.lock()
        .unwrap()
        .iter()
        .filter(|(p, _)| p.ends_with(&format!("/{uid}.glb")) && p.starts_with("/cdn/"))
        .map(|(_, r)| r.clone())
        .collect()
}

#[test]
fn fetch_downloads_allowed_licences_resumes_and_reports_corrupt_files() {
    let objects = objects();
    let server = serve(mini_objaverse(), vec!["/cdn/000-000/aaaa0003.glb".into()]);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("objaverse");
    // An earlier run that was killed left half of one object behind.
    std::fs::create_dir_all(&out).unwrap();
    let e = &objects[4].2;
    std::fs::write(out.join("aaaa0005.glb.part"), &e[..e.len() / 2]).unwrap();

    let summary = fetch(&options(&server, &out, 4), &|_| {}).unwrap();
    assert_eq!(summary.selected, 4, "{summary:?}");
    assert_eq!(
        summary.skipped_licence, 1,
        "the by-nc object is passed over: {summary:?}"
    );
    assert_eq!(summary.downloaded, 3, "{summary:?}");
    assert_eq!(summary.failed.len(), 1, "{summary:?}");
    assert_eq!(summary.failed[0].0, "aaaa0004");
    assert!(
        summary.failed[0].1.contains("GLB"),
        "{}",
        summary.failed[0].1
    );
    assert!(
        !out.join("aaaa0004.glb").exists()
            && !out.join("aaaa0004.json").exists()
            && !out.join("aaaa0002.glb").exists()
    );

    for (uid, licence, bytes) in objects
        .iter()
        .filter(|o| ["aaaa0001", "aaaa0003", "aaaa0005"].contains(&o.0))
    {
        assert_eq!(
            &std::fs::read(out.join(format!("{uid}.glb"))).unwrap(),
            bytes,
            "{uid}"
        );
        let record: ObjectRecord =
            serde_json::from_slice(&std::fs::read(out.join(format!("{uid}.json"))).unwrap())
                .unwrap();
        assert_eq!(
            (
                record.uid.as_str(),
                record.licence.as_str(),
                record.sha256.clone()
            ),
            (*uid, *licence, sha(bytes))
        );
        assert_eq!(record.author.as_deref(), Some("maker"));
        assert!(!out.join(format!("{uid}.glb.part")).exists());
    }
    // The connection cut half-way was resumed from where it broke, and the killed run's part too.
    let c = &objects[2].2;
    assert_eq!(
        ranges_for(&server.log, "aaaa0003"),
        vec![None, Some(format!("bytes={}-", c.len() / 2))]
    );
    assert_eq!(
        ranges_for(&server.log, "aaaa0005"),
        vec![Some(format!("bytes={}-", e.len() / 2))]
    );

    // A re-run finds the objects in place and downloads nothing again.
    let before = server.log.lock().unwrap().len();
    let again = fetch(&options(&server, &out, 4), &|_| {}).unwrap();
    assert_eq!(
        (again.present, again.downloaded, again.failed.len()),
        (3, 0, 1),
        "{again:?}"
    );
    assert!(
        server.log.lock().unwrap()[before..]
            .iter()
            .all(|(p, _)| !p.ends_with(".glb") || p.ends_with("aaaa0004.glb"))
    );

    // A GLB damaged after the fetch is reported and left out by the mesh index.
    let a = out.join("aaaa0001.glb");
    let mut bytes = std::fs::read(&a).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 0x5a;
    std::fs::write(&a, bytes).unwrap();
    let home = tempfile::tempdir().unwrap();
    let (found, skipped) = index_mesh_folder(&out, home.path()).unwrap();
    let names: Vec<_> = found
        .iter()
        .map(|m| m.path.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, ["aaaa0003.glb", "aaaa0005.glb"]);
    assert_eq!(skipped.len(), 1);
    assert!(
        skipped[0].path.ends_with("aaaa0001.glb") && skipped[0].reason.starts_with("corrupt"),
        "{:?}",
        skipped[0]
    );
}

#[test]
fn restricted_licences_need_consent_and_a_missing_index_is_one_clear_error() {
    let server = serve(mini_objaverse(), Vec::new());
    let dir = tempfile::tempdir().unwrap();
    let mut opts = options(&server, dir.path(), 1);
    opts.licences = vec!["by-nc".into()];
    let err = fetch(&opts, &|_| {}).unwrap_err().to_string();
    assert!(err.contains("--allow-nc-nd"), "{err}");
    opts.allow_restricted = true;
    let s = fetch(&opts, &|_| {}).unwrap();
    assert_eq!(s.downloaded, 1);
    assert!(dir.path().join("aaaa0002.glb").is_file());

    let mut missing = options(&server, &dir.path().join("elsewhere"), 1);
    missing.base_url = format!("{}/no-such-mirror", server.base);
    let err = format!("{:#}", fetch(&missing, &|_| {}).unwrap_err());
    assert!(
        err.contains("object-paths.json.gz") && err.contains("404"),
        "{err}"
    );
}
