//! The one limits policy for every reader of bytes that may be hostile: datasets, disparity and
//! image files, JSON-lines logs, scene specs, recipes and network weights all travel between
//! sites, so each reader refuses, before it allocates, anything a real file of ours or of a
//! public stereo set never needs. A refusal is an [`Error`] naming the file and the limit.
//!
//! The numbers (also in the README's "Hostile input" section):
//!
//! | limit | value | why this much |
//! |---|---|---|
//! | [`MAX_IMAGE_SIDE`] | 32768 px | 8K video is 7680; the largest public stereo images (Middlebury 2014 full size) are ~3000 |
//! | [`MAX_IMAGE_PIXELS`] | 2^27 (134 M) | 16384×8192; four times a 45 MP photo |
//! | [`MAX_ALLOC`] | 1 GiB | one decoded buffer, one archive member, one tensor: 2^27 px × 8 B (16-bit RGBA) |
//! | [`MAX_LINE_BYTES`] | 16 MiB | one JSON line; our manifest lines are ~2 KB |
//! | [`MAX_DOCUMENT_BYTES`] | 64 MiB | one JSON/TOML/text document read whole; a tree scene's spec is ~3 MB |
//!
//! Beyond these, every length a file states (a tar member's size, a tensor's byte count, a
//! raster's rows) is checked against the bytes that really follow it before anything is
//! allocated for it, so a file can never make a reader hold much more than its own size.

use std::io::Read;
use std::path::Path;

use crate::error::{Error, Result};

/// The largest image width or height any reader decodes.
pub const MAX_IMAGE_SIDE: u64 = 1 << 15;
/// The largest number of pixels (width × height) any reader decodes.
pub const MAX_IMAGE_PIXELS: u64 = 1 << 27;
/// The largest single buffer a reader allocates for what a file asks: a decoded image, an
/// archive member read whole, a tensor.
pub const MAX_ALLOC: u64 = 1 << 30;
/// The longest line of a JSON-lines file (manifest, sidecar logs, scores).
pub const MAX_LINE_BYTES: u64 = 16 << 20;
/// The largest text document read whole: an index, `dataset.json`, `calib.txt`, a scene spec
/// (after decompression), a recipe.
pub const MAX_DOCUMENT_BYTES: u64 = 64 << 20;

/// Human-readable byte counts for messages ("1 GiB", "16 MiB", "123 bytes").
pub fn bytes_text(n: u64) -> String {
    const UNITS: [(u64, &str); 3] = [(1 << 30, "GiB"), (1 << 20, "MiB"), (1 << 10, "KiB")];
    for (unit, name) in UNITS {
        if n >= unit && n.is_multiple_of(unit) {
            return format!("{} {name}", n / unit);
        }
    }
    format!("{n} bytes")
}

/// Refuses an image of `width` × `height` before it is decoded: either side above
/// [`MAX_IMAGE_SIDE`], more than [`MAX_IMAGE_PIXELS`] pixels, or a zero side.
pub fn check_image_size(path: &Path, width: u64, height: u64) -> Result<()> {
    match image_size_problem(width, height) {
        Some(problem) => Err(Error::format(path, problem)),
        None => Ok(()),
    }
}

/// What [`check_image_size`] says of an image of `width` × `height`, if it refuses it.
pub fn image_size_problem(width: u64, height: u64) -> Option<String> {
    if width == 0 || height == 0 {
        return Some(format!("image of {width}x{height} pixels: an empty image"));
    }
    if width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE || width * height > MAX_IMAGE_PIXELS {
        return Some(format!(
            "image of {width}x{height} pixels is over the readers' limits ({MAX_IMAGE_SIDE} px a side, {MAX_IMAGE_PIXELS} pixels): refused before decoding"
        ));
    }
    None
}

/// Refuses a buffer of `bytes` that a file asks for (`what`: "a tar member", "a tensor") above
/// [`MAX_ALLOC`].
pub fn check_alloc(path: &Path, what: &str, bytes: u64) -> Result<()> {
    check_length(path, what, bytes, MAX_ALLOC)
}

/// Refuses `what` of `bytes` above `limit` (one of the limits above), saying both.
pub fn check_length(path: &Path, what: &str, bytes: u64, limit: u64) -> Result<()> {
    if bytes > limit {
        return Err(Error::format(
            path,
            format!(
                "{what} of {} is over the readers' limit of {}",
                bytes_text(bytes),
                bytes_text(limit)
            ),
        ));
    }
    Ok(())
}

/// The limits for the `image` crate's decoders: the same sides and one buffer of at most
/// [`MAX_ALLOC`] (the PNG decoder checks them against the header, before decoding).
pub fn image_limits() -> image::Limits {
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_IMAGE_SIDE as u32);
    limits.max_image_height = Some(MAX_IMAGE_SIDE as u32);
    limits.max_alloc = Some(MAX_ALLOC);
    limits
}

/// Reads all of `reader` (`path` names it in errors), refusing more than `max` bytes. Reads at
/// most `max + 1` bytes, so a stream that lies about its length (a decompressor, a pipe) costs
/// no more than the limit.
pub fn read_to_end_capped(reader: impl Read, path: &Path, max: u64, what: &str) -> Result<Vec<u8>> {
    let mut bytes = Vec::new();
    reader
        .take(max.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(|e| Error::io(path, e))?;
    if bytes.len() as u64 > max {
        return Err(Error::format(
            path,
            format!("{what} is longer than the limit of {}", bytes_text(max)),
        ));
    }
    Ok(bytes)
}

/// Reads the file at `path` whole, refusing one of more than `max` bytes before reading it.
/// Devices, pipes and folders are refused before they are opened (a FIFO would block, a device
/// never end).
pub fn read_file_capped(path: &Path, max: u64, what: &str) -> Result<Vec<u8>> {
    if !std::fs::metadata(path)
        .map_err(|e| Error::io(path, e))?
        .is_file()
    {
        return Err(Error::format(
            path,
            format!("{what} that is not a regular file (a folder, device or pipe): not read"),
        ));
    }
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    check_length(path, what, len, max)?;
    read_to_end_capped(file, path, max, what)
}

/// [`read_file_capped`] for a text document of at most [`MAX_DOCUMENT_BYTES`], as UTF-8.
pub fn read_document(path: &Path, what: &str) -> Result<String> {
    let bytes = read_file_capped(path, MAX_DOCUMENT_BYTES, what)?;
    String::from_utf8(bytes).map_err(|e| {
        Error::format(
            path,
            format!(
                "{what} is not UTF-8 text (byte offset {})",
                e.utf8_error().valid_up_to()
            ),
        )
    })
}

/// Why `name` is not a plain file name that can only name an entry of the folder it is joined
/// to: empty, `.` or `..`, a path separator, a NUL or another control character.
pub fn plain_file_name_problem(name: &str) -> Option<&'static str> {
    if name.is_empty() {
        Some("is empty")
    } else if name == "." || name == ".." {
        Some("is `.` or `..`")
    } else if name.contains(['/', '\\']) {
        Some("holds a path separator")
    } else if name.chars().any(char::is_control) {
        Some("holds a control character")
    } else {
        None
    }
}

/// Why the `/`-separated relative path `rel` could reach outside the folder it is read from, or
/// is otherwise not a name a dataset file has: absolute, a `..`, `.` or empty component, a
/// backslash, a NUL or another control character.
pub fn relative_path_problem(rel: &str) -> Option<&'static str> {
    if rel.is_empty() {
        return Some("is empty");
    }
    if rel.starts_with('/') {
        return Some("is absolute");
    }
    if rel.chars().any(char::is_control) {
        return Some("holds a control character");
    }
    if rel.contains('\\') {
        return Some("holds a backslash");
    }
    for part in rel.split('/') {
        match part {
            ".." => return Some("has a `..` component"),
            "." | "" => return Some("has an empty or `.` component"),
            _ => {}
        }
    }
    None
}

/// [`relative_path_problem`] for a [`Path`] (a path in a manifest): also refuses one that is not
/// UTF-8.
pub fn relative_path_buf_problem(rel: &Path) -> Option<&'static str> {
    match rel.to_str() {
        Some(s) => relative_path_problem(s),
        None => Some("is not UTF-8"),
    }
}

/// Opens `root/name` for reading, where `name` is a plain file name (an index's shard, say),
/// only if it is a regular file that lies inside `root`: a symbolic link is followed only when
/// its target resolves inside `root`, and devices, pipes and folders are refused (a FIFO would
/// block the reader for ever). Returns the open file and its length, read from the open file.
pub fn open_inside(root: &Path, name: &str) -> Result<(std::fs::File, u64)> {
    let path = root.join(name);
    if let Some(problem) = plain_file_name_problem(name) {
        return Err(Error::format(
            root,
            format!(
                "the file name {name:?} {problem}: only plain file names inside this folder are read"
            ),
        ));
    }
    let link = std::fs::symlink_metadata(&path).map_err(|e| Error::io(&path, e))?;
    if link.file_type().is_symlink() {
        let target = std::fs::canonicalize(&path).map_err(|e| Error::io(&path, e))?;
        let inside = std::fs::canonicalize(root)
            .map(|root| target.starts_with(root))
            .unwrap_or(false);
        if !inside {
            return Err(Error::format(
                &path,
                "a symbolic link to a file outside the dataset folder: not read",
            ));
        }
    }
    let not_file = || {
        Error::format(
            &path,
            "not a regular file (a folder, device or pipe): not read",
        )
    };
    // Checked before opening too: opening a FIFO for reading blocks until a writer comes.
    if !std::fs::metadata(&path)
        .map_err(|e| Error::io(&path, e))?
        .is_file()
    {
        return Err(not_file());
    }
    let file = std::fs::File::open(&path).map_err(|e| Error::io(&path, e))?;
    let meta = file.metadata().map_err(|e| Error::io(&path, e))?;
    if !meta.is_file() {
        return Err(not_file());
    }
    Ok((file, meta.len()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_and_paths_that_could_leave_the_folder_are_refused() {
        for bad in ["", ".", "..", "a/b", "/etc/passwd", "..\\x", "a\0b", "a\nb"] {
            assert!(plain_file_name_problem(bad).is_some(), "{bad:?}");
        }
        assert_eq!(plain_file_name_problem("train-000000.tar"), None);
        for bad in [
            "",
            "/etc/passwd",
            "../x",
            "a/../../b",
            "a//b",
            "./a",
            "a\u{1b}[2J",
            "a\\b",
        ] {
            assert!(relative_path_problem(bad).is_some(), "{bad:?}");
        }
        assert_eq!(
            relative_path_problem("shards/0000-of-0002/tree/0000001_left.png"),
            None
        );
        assert_eq!(relative_path_problem("tree/0000003"), None);
    }

    #[test]
    fn sizes_over_the_limits_are_refused_before_decoding() {
        let p = Path::new("big.png");
        assert!(check_image_size(p, 960, 540).is_ok());
        assert!(check_image_size(p, 16384, 8192).is_ok());
        let e = check_image_size(p, 30000, 30000).unwrap_err().to_string();
        assert!(e.contains("big.png") && e.contains("30000x30000"), "{e}");
        assert!(check_image_size(p, 40000, 1).is_err());
        assert!(check_image_size(p, 0, 5).is_err());
        assert!(check_alloc(p, "a member", MAX_ALLOC).is_ok());
        let e = check_alloc(p, "a member", 4 << 40).unwrap_err().to_string();
        assert!(
            e.contains("4096 GiB") && e.contains("limit of 1 GiB"),
            "{e}"
        );
        assert_eq!(bytes_text(16 << 20), "16 MiB");
        assert_eq!(bytes_text(1000), "1000 bytes");
    }

    #[test]
    fn capped_reads_stop_at_the_limit() {
        let long = std::io::repeat(7).take(1 << 20);
        let e = read_to_end_capped(long, Path::new("x"), 1000, "a line")
            .unwrap_err()
            .to_string();
        assert!(e.contains("longer than the limit of 1000 bytes"), "{e}");
        let short = read_to_end_capped(&b"abc"[..], Path::new("x"), 3, "a line").unwrap();
        assert_eq!(short, b"abc");
    }
}
