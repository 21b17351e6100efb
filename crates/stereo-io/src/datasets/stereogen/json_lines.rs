//! The one rule for reading our JSON-lines files (the manifest and the sidecar logs).
//!
//! **An unfinished last line.** Every line that ends in a newline is a finished record (blank
//! lines are ignored); a finished line that is not a record is an error naming the file and the
//! line. A last line *without* its newline is an append still in progress (readers may run
//! while `generate` writes) or one torn by a kill: it is never a record, whatever it holds. The
//! readers leave it out and report its length; only a writer, holding the dataset's lock, cuts
//! it off the file.
//!
//! **A line longer than [`MAX_LINE_BYTES`]** (finished or not) is an error naming the line: no
//! record of ours comes near it, and reading on would hold a file's worth of bytes.

use std::io::{BufRead, Read};
use std::path::Path;

use crate::error::{Error, Result};
use crate::limits::{MAX_LINE_BYTES, bytes_text};

/// Calls `record(number, text)` for each finished, non-blank line of `reader` (1-based line
/// numbers, the text without its newline); returns the bytes of an unfinished last line left
/// out (0 when none).
pub(crate) fn read_finished_lines(
    mut reader: impl BufRead,
    path: &Path,
    mut record: impl FnMut(usize, &str) -> Result<()>,
) -> Result<u64> {
    let mut line = Vec::new();
    for number in 1.. {
        line.clear();
        // One byte past the limit tells a line over it from one exactly at it, and bounds what a
        // file without newlines can make the reader hold.
        let n = (&mut reader)
            .take(MAX_LINE_BYTES + 1)
            .read_until(b'\n', &mut line)
            .map_err(|e| Error::io(path, e))?;
        if n == 0 {
            break;
        }
        if n as u64 > MAX_LINE_BYTES {
            return Err(Error::format(
                path,
                format!(
                    "line {number} is longer than the limit of {} for one line",
                    bytes_text(MAX_LINE_BYTES)
                ),
            ));
        }
        if line.last() != Some(&b'\n') {
            return Ok(n as u64);
        }
        let text = std::str::from_utf8(&line)
            .map_err(|_| Error::format(path, format!("line {number} is not UTF-8 text")))?;
        let text = text.trim_end_matches(['\n', '\r']);
        if !text.trim().is_empty() {
            record(number, text)?;
        }
    }
    Ok(0)
}
