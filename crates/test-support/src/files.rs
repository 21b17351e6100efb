//! Reading a folder back in tests, and writing an edited copy of a file.

use std::path::{Path, PathBuf};

/// Every entry of a folder, with its bytes, sorted by name (a subfolder fails the read).
pub fn files_with_bytes(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out: Vec<_> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("read {}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect();
    out.sort();
    out
}

/// Every file below `dir`, at any depth, in no particular order.
pub fn walk(dir: &Path) -> Vec<PathBuf> {
    walkdir::WalkDir::new(dir)
        .into_iter()
        .map(|e| e.unwrap_or_else(|e| panic!("read {}: {e}", dir.display())))
        .filter(|e| !e.file_type().is_dir())
        .map(walkdir::DirEntry::into_path)
        .collect()
}

/// Writes `to`: the text file `from` with every `pattern` replaced by `with` (a file made
/// invalid, or different, in one place).
pub fn write_replaced(from: &Path, to: &Path, pattern: &str, with: &str) {
    let text = std::fs::read_to_string(from)
        .unwrap_or_else(|e| panic!("read {}: {e}", from.display()))
        .replace(pattern, with);
    std::fs::write(to, text).unwrap_or_else(|e| panic!("write {}: {e}", to.display()));
}

/// Copies folder `from` with everything below it to `to` (created).
pub fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let target = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &target);
        } else {
            std::fs::copy(e.path(), target).unwrap();
        }
    }
}
