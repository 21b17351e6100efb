//! A WebDataset export changed by hand, as a hostile or broken copy would be: tar headers that lie
//! about their size (GNU base-256 and octal), an index naming files outside its folder, shard
//! files that are links or pipes, member names that climb out of a folder, headers that are no
//! tar at all. Each must be one error naming the shard (and member and offset where there is
//! one), never an abort, a read outside the folder or an echo of the file's bytes.

use std::fs;
use std::path::{Path, PathBuf};

use serde_json::Value;
use stereo_io::datasets::webdataset::{ShardIndex, scan_shard};
use stereo_io::*;

use crate::io_fixtures;
use io_fixtures::*;

/// Our 9-sample dataset exported as one `train` shard; returns the export folder.
fn export(dir: &Path) -> PathBuf {
    let source = mkdir(&dir.join("source"));
    our_dataset(&source);
    let out = dir.join("wds");
    let opts = WebDatasetOptions {
        shard_bytes: 1 << 30,
        ..Default::default()
    };
    export_webdataset(&source, &out, None, &ReadOptions::default(), &opts).unwrap();
    out
}

fn shard(out: &Path) -> PathBuf {
    out.join("train-000000.tar")
}

/// Sets the size field of the header at `at` in octal (11 digits and a NUL: up to 8 GiB).
fn set_size_octal(bytes: &mut [u8], at: usize, size: u64) {
    bytes[at + 124..at + 136].copy_from_slice(format!("{size:011o}\0").as_bytes());
    fix_checksum(bytes, at);
}

fn set_name(bytes: &mut [u8], at: usize, name: &str) {
    let field = &mut bytes[at..at + 100];
    field.fill(0);
    field[..name.len()].copy_from_slice(name.as_bytes());
    fix_checksum(bytes, at);
}

/// An export to change by hand: its folder, its shard's bytes and the header offsets of the
/// shard's first and last members (our writer uses no extension headers).
struct Exported {
    _dir: tempfile::TempDir,
    out: PathBuf,
    bytes: Vec<u8>,
    first: usize,
    last: usize,
}

fn exported() -> Exported {
    let dir = tempfile::tempdir().unwrap();
    let out = export(dir.path());
    let members = scan_shard(&shard(&out)).unwrap();
    let at = |m: &datasets::webdataset::ListedMember| m.offset as usize - 512;
    let (first, last) = (at(&members[0]), at(members.last().unwrap()));
    Exported {
        bytes: fs::read(shard(&out)).unwrap(),
        _dir: dir,
        out,
        first,
        last,
    }
}

impl Exported {
    /// Writes the shard with `edit` applied to its bytes (given the first and last header
    /// offsets) and returns the error of opening the export.
    fn refused_after(&mut self, edit: impl FnOnce(&mut [u8], usize, usize)) -> String {
        edit(&mut self.bytes, self.first, self.last);
        fs::write(shard(&self.out), &self.bytes).unwrap();
        open_error(&self.out)
    }
}

fn edit_index(out: &Path, edit: impl FnOnce(&mut Value)) {
    let path = out.join("train.index.json");
    let mut index: Value = serde_json::from_slice(&fs::read(&path).unwrap()).unwrap();
    edit(&mut index);
    fs::write(&path, serde_json::to_vec(&index).unwrap()).unwrap();
}

/// The error of opening the export, checked to be one line.
fn open_error(out: &Path) -> String {
    let e = WebDataset::open(out)
        .err()
        .expect("a hostile export must not open")
        .to_string();
    assert!(!e.contains('\n'), "one line: {e}");
    e
}

#[test]
fn a_member_claiming_4_tib_is_refused_at_open_naming_member_and_offset() {
    let mut x = exported();
    // The file keeps its length, so the index's byte count still agrees.
    let e = x.refused_after(|b, _, last| set_size_base256(b, last, 4 << 40));
    assert!(e.contains("train-000000.tar"), "{e}");
    assert!(
        e.contains(&format!("header at byte offset {}", x.last)),
        "{e}"
    );
    assert!(e.contains("claims 4096 GiB of data"), "{e}");
    // The streaming listing says the same.
    assert!(scan_shard(&shard(&x.out)).is_err());

    // 8 GiB less a byte in the ordinary octal field: the same refusal.
    let e = x.refused_after(|b, _, last| set_size_octal(b, last, (8 << 30) - 1));
    assert!(e.contains("claims 8589934591 bytes of data"), "{e}");
}

#[test]
fn a_member_running_past_the_end_is_refused_even_when_the_index_agrees() {
    let dir = tempfile::tempdir().unwrap();
    let out = export(dir.path());
    let bytes = fs::read(shard(&out)).unwrap();
    let members = scan_shard(&shard(&out)).unwrap();
    let last = members.last().unwrap();
    // Cut inside the last member's data and make the index agree with the cut.
    let cut = (last.offset + last.size / 2) as usize;
    fs::write(shard(&out), &bytes[..cut]).unwrap();
    edit_index(&out, |i| i["shards"][0]["bytes"] = (cut as u64).into());
    let e = open_error(&out);
    assert!(e.contains("the shard holds"), "{e}");
}

#[test]
fn an_index_naming_a_file_outside_its_folder_is_refused_without_reading_it() {
    let dir = tempfile::tempdir().unwrap();
    let out = export(dir.path());
    // A valid shard beside the export, and a text file of "secrets": neither may be read.
    fs::copy(shard(&out), dir.path().join("outside.tar")).unwrap();
    let secret = dir.path().join("secret.txt");
    fs::write(&secret, "root:x:0:0:root:/root:/bin/bash\n").unwrap();
    let secret_abs = secret.to_str().unwrap().to_string();
    for name in [
        "/etc/passwd".to_string(),
        secret_abs.clone(),
        "../outside.tar".to_string(),
        "..".to_string(),
        "sub/../../outside.tar".to_string(),
    ] {
        let bytes = fs::metadata(dir.path().join("outside.tar")).unwrap().len();
        edit_index(&out, |i| {
            i["shards"][0]["name"] = name.clone().into();
            i["shards"][0]["bytes"] = bytes.into();
        });
        let e = open_error(&out);
        assert!(e.contains("train.index.json"), "{name}: {e}");
        assert!(
            e.contains("only name files in its own folder"),
            "{name}: {e}"
        );
        assert!(!e.contains("root:x"), "{name}: {e}");
    }
}

#[test]
fn shard_files_that_are_links_out_of_the_folder_or_pipes_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = export(dir.path());
    let moved = dir.path().join("elsewhere.tar");
    fs::rename(shard(&out), &moved).unwrap();
    std::os::unix::fs::symlink(&moved, shard(&out)).unwrap();
    let e = open_error(&out);
    assert!(e.contains("symbolic link to a file outside"), "{e}");

    // A link that stays inside the folder is followed.
    fs::remove_file(shard(&out)).unwrap();
    fs::rename(&moved, out.join("real.tar")).unwrap();
    std::os::unix::fs::symlink("real.tar", shard(&out)).unwrap();
    assert_eq!(WebDataset::open(&out).unwrap().len(), IDS);

    // A named pipe would block a reader for ever: refused without opening it for data.
    fs::remove_file(shard(&out)).unwrap();
    let status = std::process::Command::new("mkfifo")
        .arg(shard(&out))
        .status()
        .unwrap();
    assert!(status.success());
    let e = open_error(&out);
    assert!(e.contains("not a regular file"), "{e}");
}

#[test]
fn member_names_climbing_out_of_a_folder_are_refused_naming_member_and_shard() {
    for (name, why) in [
        ("../../../0000000.left.png", "`..` component"),
        ("/tmp/0000000.left.png", "is absolute"),
        ("tree/\u{1b}[2J0000000.left.png", "control character"),
    ] {
        let mut x = exported();
        let e = x.refused_after(|b, first, _| set_name(b, first, name));
        assert!(e.contains("train-000000.tar"), "{e}");
        assert!(e.contains(why), "{name:?}: {e}");
        assert!(
            e.contains(&format!("header at byte offset {}", x.first)),
            "{e}"
        );
        // The control character is shown escaped, never sent to the terminal.
        assert!(!e.contains('\u{1b}'), "{e}");
    }
}

#[test]
fn a_file_that_is_not_tar_is_named_without_quoting_it() {
    let mut x = exported();
    // Text where the size digits are: the `tar` crate's own message would quote it.
    let e = x.refused_after(|b, first, _| {
        b[first + 124..first + 136].copy_from_slice(b"root:x:0:0:r");
        fix_checksum(b, first);
    });
    let out = &x.out;
    assert!(e.contains("not a readable tar shard"), "{e}");
    assert!(!e.contains("root:x"), "{e}");

    // A shard that is wholly text, its size in the index.
    let text = b"root:x:0:0:root:/root:/bin/bash\n".repeat(40);
    fs::write(shard(out), &text).unwrap();
    edit_index(out, |i| i["shards"][0]["bytes"] = text.len().into());
    let e = open_error(out);
    assert!(!e.contains("root:x"), "{e}");
}

#[test]
fn non_file_members_and_unreadable_indexes_are_refused() {
    let mut x = exported();
    let e = x.refused_after(|b, first, _| {
        b[first + 156] = b'2'; // a symbolic link
        fix_checksum(b, first);
    });
    let out = &x.out;
    assert!(e.contains("not a regular file"), "{e}");

    fs::write(out.join("train.index.json"), "root:x:0:0:root").unwrap();
    let e = open_error(out);
    assert!(e.contains("unreadable index") && !e.contains("root"), "{e}");
    // The index parser on its own says the same.
    assert!(ShardIndex::parse(b"{", Path::new("i.json")).is_err());
}

/// Found by the `tar_shard` fuzzer: a sample holding `left.png` twice was read with its first
/// copy twice by seeking and with both copies by streaming.
#[test]
fn a_sample_repeating_a_member_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = export(dir.path());
    let mut bytes = fs::read(shard(&out)).unwrap();
    let members = scan_shard(&shard(&out)).unwrap();
    let (first, second) = (&members[0], &members[1]);
    assert_eq!(first.key, second.key);
    let name = format!("{}.{}", first.key, first.suffix);
    set_name(&mut bytes, second.offset as usize - 512, &name);
    fs::write(shard(&out), &bytes).unwrap();
    let e = open_error(&out);
    assert!(e.contains("repeats a member of its sample"), "{e}");
    assert!(e.contains(&format!("{name:?}")), "{e}");
}
