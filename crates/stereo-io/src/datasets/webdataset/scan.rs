//! Listing a shard's members from its tar headers, trusting none of them: shards travel between
//! sites and teams, so a header may lie about its size, name a path outside any folder, or be
//! no tar header at all.
//!
//! Every member must be a regular file whose data lies inside the file as it is on disk (its
//! offset plus its size within the real length, which is what bounds every later read and
//! allocation), no larger than [`MAX_ALLOC`], named `<key>.<suffix>` with a key that is a
//! relative path without `..` (a key becomes a file name when a shard is converted). Errors name
//! the shard, the member and the byte offset of its header; they never quote the bytes of a
//! header that could not be parsed (the `tar` crate's own messages do, so they are replaced).

use std::io::{Read, Seek};
use std::path::Path;

use crate::error::{Error, Result};
use crate::limits::{MAX_ALLOC, bytes_text, relative_path_problem};

/// One member of a shard, as its checked header states it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ListedMember {
    /// The sample key: the member name up to the first dot after its last `/`.
    pub key: String,
    /// The rest of the name after `<key>.` (`left.png`, `disp_left.exr`, `json`).
    pub suffix: String,
    /// Byte offset of the member's data in the shard.
    pub offset: u64,
    /// Bytes of data; `offset + size` is within the shard's length.
    pub size: u64,
}

/// Lists the members of the shard file at `path` (tar headers only; nothing is read but them).
pub fn scan_shard(path: &Path) -> Result<Vec<ListedMember>> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    scan_tar(std::io::BufReader::new(file), len, path)
}

/// Lists the members of a tar stream of `len` bytes (`path` names it in errors).
pub fn scan_tar<R: Read + Seek>(reader: R, len: u64, path: &Path) -> Result<Vec<ListedMember>> {
    let mut archive = tar::Archive::new(reader);
    // Where the next header should start: what an error that the `tar` crate reports while
    // parsing a header points at.
    let mut next_header = 0u64;
    let damaged = |at: u64, e: std::io::Error| {
        // An error of the file itself (EIO) is an I/O error; anything else is the tar parser
        // refusing a header, whose message may quote the header's bytes.
        if e.raw_os_error().is_some() {
            Error::io(path, e)
        } else {
            Error::format(
                path,
                format!(
                    "not a readable tar shard: the header at byte offset {at} or an extension header after it is damaged"
                ),
            )
        }
    };
    let entries = archive
        .entries_with_seek()
        .map_err(|e| damaged(next_header, e))?;
    let mut members = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| damaged(next_header, e))?;
        let header_at = entry.raw_header_position();
        let (offset, size) = (entry.raw_file_position(), entry.size());
        let name_bytes = entry.path_bytes().into_owned();
        let name = String::from_utf8_lossy(&name_bytes).into_owned();
        let at = |what: String| {
            Error::format(
                path,
                format!("member {name:?} (header at byte offset {header_at}) {what}"),
            )
        };
        let end = offset.checked_add(size).filter(|&end| end <= len);
        let Some(end) = end else {
            return Err(at(format!(
                "claims {} of data, but the shard holds {} after the header: the header lies or the shard is cut short",
                bytes_text(size),
                bytes_text(len.saturating_sub(offset))
            )));
        };
        next_header = end.div_ceil(512) * 512;
        let kind = entry.header().entry_type();
        if kind.is_dir() {
            // Tools that tar a folder store its folders too; they hold no sample.
            continue;
        }
        if !(kind.is_file() || kind.is_contiguous()) {
            return Err(at(format!(
                "is a {kind:?} entry, not a regular file: shards hold files only"
            )));
        }
        if size > MAX_ALLOC {
            return Err(at(format!(
                "is {} long, over the readers' limit of {} for one member",
                bytes_text(size),
                bytes_text(MAX_ALLOC)
            )));
        }
        if std::str::from_utf8(&name_bytes).is_err() {
            return Err(at("has a name that is not UTF-8".into()));
        }
        let (key, suffix) = split_name(&name).map_err(at)?;
        members.push(ListedMember {
            key: key.to_string(),
            suffix: suffix.to_string(),
            offset,
            size,
        });
    }
    Ok(members)
}

/// Splits a member name at WebDataset's rule (the key ends at the first dot after the last
/// `/`), refusing a key that could name a path outside a folder it is written to.
fn split_name(name: &str) -> std::result::Result<(&str, &str), String> {
    if name.chars().any(char::is_control) {
        return Err("has a name with a control character".into());
    }
    let dir_end = name.rfind('/').map_or(0, |i| i + 1);
    let Some(dot) = name[dir_end..].find('.').map(|i| dir_end + i) else {
        return Err("has no extension (a member is named <key>.<suffix>)".into());
    };
    let (key, suffix) = (&name[..dot], &name[dot + 1..]);
    if let Some(problem) = relative_path_problem(key) {
        return Err(format!(
            "has a key that {problem}: a key must be a relative path inside the dataset"
        ));
    }
    Ok((key, suffix))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_that_could_leave_a_folder_are_refused() {
        assert_eq!(
            split_name("tree/0000003.left.png"),
            Ok(("tree/0000003", "left.png"))
        );
        assert_eq!(split_name("a.b.c.json"), Ok(("a", "b.c.json")));
        for (bad, why) in [
            ("../../../x.left.png", "`..`"),
            ("/etc/x.left.png", "is absolute"),
            ("a/../b.left.png", "`..`"),
            ("a\u{1b}[31m.left.png", "control"),
            ("x.left\npng", "control"),
            (".json", "is empty"),
            ("noext", "no extension"),
        ] {
            let e = split_name(bad).unwrap_err();
            assert!(e.contains(why), "{bad:?}: {e}");
        }
    }
}
