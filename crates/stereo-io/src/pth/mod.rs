//! PyTorch state dicts (`torch.save` files, `.pt`/`.pth`): written here ([`write_state_dict`])
//! and checked here before any loader touches them ([`check_state_dict`]).
//!
//! Weights travel like datasets, and a `torch.save` file is a zip archive around a pickle, both
//! of which a loader would otherwise take on trust: a record whose deflated bytes expand without
//! end, a size field that asks for terabytes, a tensor whose shape asks for more than its storage
//! holds, a pickle that names code to run. The check reads the whole file once, within the
//! limits policy ([`crate::limits`]), and accepts only what `torch.save` writes for a dict of
//! float tensors:
//!
//! - a zip archive ending in its end-of-archive record (no trailing comment), whose central
//!   directory can hold the entries it claims; entries stored or deflated, not encrypted, names
//!   unique, each expanding to exactly the size its header states (read with a cap of that size,
//!   so a bomb costs no more than its claim) and all together at most [`MAX_ALLOC`];
//! - one `data.pkl` (at the top or in one folder) of at most [`MAX_DOCUMENT_BYTES`], read by a
//!   pickle machine that knows only a state dict's opcodes and classes (`pickle.rs`);
//! - for every tensor, one record `data/<key>` beside the pickle holding exactly the storage's
//!   element count of its type, and a shape and strides that stay inside that storage.

mod pickle;
mod write;

use std::collections::HashMap;
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

pub use pickle::Dtype;
pub use write::{encode_state_dict, write_state_dict};

use crate::error::{Error, Result};
use crate::limits::{MAX_ALLOC, MAX_DOCUMENT_BYTES, bytes_text};

/// A named float tensor in the reference layout (Linear weights as (out, in)), row-major.
#[derive(Debug, Clone)]
pub struct NamedArray {
    pub name: String,
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

/// A tensor of a checked state dict: its dotted name, element type and shape.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TensorListing {
    pub name: String,
    pub dtype: Dtype,
    pub shape: Vec<u64>,
}

/// Checks the state dict file at `path` (see the module notes) and lists its tensors. Nothing in
/// the file is run or trusted; errors name the file and what was refused.
pub fn check_state_dict(path: &Path) -> Result<Vec<TensorListing>> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if !meta.is_file() {
        return Err(Error::format(
            path,
            "not a regular file (a folder, device or pipe): not read",
        ));
    }
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    check_state_dict_from(std::io::BufReader::new(file), len, path)
}

/// [`check_state_dict`] of `len` bytes from `reader` (`path` names them in errors).
pub fn check_state_dict_from<R: Read + Seek>(
    mut reader: R,
    len: u64,
    path: &Path,
) -> Result<Vec<TensorListing>> {
    let bad = |m: String| Error::format(path, format!("not a PyTorch state dict: {m}"));
    check_directory_size(&mut reader, len).map_err(bad)?;
    let mut archive = zip::ZipArchive::new(reader)
        .map_err(|e| bad(format!("not a readable zip archive ({e})")))?;
    let mut sizes: HashMap<String, u64> = HashMap::new();
    let mut total = 0u64;
    let mut pickle: Option<(String, Vec<u8>)> = None;
    for i in 0..archive.len() {
        let entry = archive
            .by_index(i)
            .map_err(|e| bad(format!("entry {i} is unreadable ({e})")))?;
        let name = entry.name().to_string();
        if entry.encrypted() {
            return Err(bad(format!("entry {name:?} is encrypted")));
        }
        let size = entry.size();
        total = total.saturating_add(size);
        if size > MAX_ALLOC || total > MAX_ALLOC {
            return Err(bad(format!(
                "entry {name:?} of {} brings the archive over the limit of {} for the weights of one file",
                bytes_text(size),
                bytes_text(MAX_ALLOC)
            )));
        }
        if sizes.insert(name.clone(), size).is_some() {
            return Err(bad(format!("entry {name:?} appears twice")));
        }
        let is_pickle = name.ends_with("data.pkl");
        if is_pickle && pickle.is_some() {
            return Err(bad("more than one data.pkl".into()));
        }
        if is_pickle && size > MAX_DOCUMENT_BYTES {
            return Err(bad(format!(
                "{name:?} of {} is over the limit of {}",
                bytes_text(size),
                bytes_text(MAX_DOCUMENT_BYTES)
            )));
        }
        // Read with a cap one byte past the stated size: a record that expands further (a zip
        // bomb under a small size field) is caught after at most its stated size.
        let mut capped = entry.take(size + 1);
        let mut kept = Vec::new();
        let read = if is_pickle {
            capped.read_to_end(&mut kept).map(|n| n as u64)
        } else {
            std::io::copy(&mut capped, &mut std::io::sink())
        }
        .map_err(|e| bad(format!("entry {name:?} is damaged ({e})")))?;
        if read != size {
            let more = if read > size { "more than " } else { "" };
            return Err(bad(format!(
                "entry {name:?} expands to {more}{} bytes, its header says {size}",
                read.min(size)
            )));
        }
        if is_pickle {
            pickle = Some((name, kept));
        }
    }
    let (pickle_name, pickle_bytes) = pickle.ok_or_else(|| bad("no data.pkl".into()))?;
    let prefix = &pickle_name[..pickle_name.len() - "data.pkl".len()];
    let folder = prefix.strip_suffix('/').unwrap_or(prefix);
    if !prefix.is_empty() && (folder.is_empty() || folder.contains('/') || prefix == folder) {
        return Err(bad(format!(
            "{pickle_name:?} is not data.pkl at the top or in one folder"
        )));
    }
    let tensors = pickle::read_state_dict_pickle(&pickle_bytes)
        .map_err(|m| bad(format!("{pickle_name}: {m}")))?;
    let mut storages: HashMap<&str, (Dtype, u64)> = HashMap::new();
    let mut listing = Vec::with_capacity(tensors.len());
    for (name, t) in &tensors {
        let key = t.storage.key.as_str();
        let record = format!("{prefix}data/{key}");
        let tensor_err = |m: String| bad(format!("tensor {name:?}: {m}"));
        let Some(&size) = sizes.get(&record) else {
            return Err(tensor_err(format!(
                "its storage record {record:?} is missing"
            )));
        };
        // PyTorch's and Burn's loaders find a record by its last path parts: only this one may
        // answer to the key.
        let tail = format!("/data/{key}");
        let answering = sizes
            .keys()
            .filter(|n| {
                n.ends_with(&tail)
                    || n.as_str() == &tail[1..]
                    || (n.contains("/data/") && n.rsplit('/').next() == Some(key))
            })
            .count();
        if answering != 1 {
            return Err(tensor_err(format!(
                "{answering} records answer to its storage key"
            )));
        }
        let (dtype, numel) = (t.storage.dtype, t.storage.numel);
        if *storages.entry(key).or_insert((dtype, numel)) != (dtype, numel) {
            return Err(tensor_err(
                "its storage is named again with another type or size".into(),
            ));
        }
        let need = numel.checked_mul(dtype.bytes());
        if need != Some(size) {
            return Err(tensor_err(format!(
                "its storage of {numel} {dtype:?} elements needs {} bytes, its record {record:?} holds {size}",
                need.map_or("more than 2^64".into(), |n| n.to_string())
            )));
        }
        check_view(t, dtype).map_err(tensor_err)?;
        listing.push(TensorListing {
            name: name.clone(),
            dtype,
            shape: t.shape.clone(),
        });
    }
    Ok(listing)
}

/// A tensor's shape and strides must stay inside its storage, and the tensor within one buffer.
fn check_view(t: &pickle::Tensor, dtype: Dtype) -> std::result::Result<(), String> {
    if t.shape.len() != t.stride.len() {
        return Err(format!(
            "shape {:?} and stride {:?} differ in length",
            t.shape, t.stride
        ));
    }
    let elements = t
        .shape
        .iter()
        .try_fold(1u64, |n, &d| n.checked_mul(d))
        .filter(|&n| n.saturating_mul(dtype.bytes()) <= MAX_ALLOC)
        .ok_or_else(|| {
            format!(
                "shape {:?} is over the readers' limit of {} for one tensor",
                t.shape,
                bytes_text(MAX_ALLOC)
            )
        })?;
    if elements == 0 {
        return Ok(());
    }
    let last = t
        .shape
        .iter()
        .zip(&t.stride)
        .try_fold(t.offset, |at, (&d, &s)| {
            at.checked_add((d - 1).checked_mul(s)?)
        });
    match last {
        Some(last) if last < t.storage.numel => Ok(()),
        _ => Err(format!(
            "shape {:?} with stride {:?} from offset {} reaches past its storage of {} elements",
            t.shape, t.stride, t.offset, t.storage.numel
        )),
    }
}

/// Refuses an archive whose end record claims more entries than its central directory can
/// hold (46 bytes each at least), before the zip reader reserves memory for them; and one whose
/// end record is not at the very end, which `torch.save` never writes.
fn check_directory_size<R: Read + Seek>(
    reader: &mut R,
    len: u64,
) -> std::result::Result<(), String> {
    const EOCD: usize = 22;
    const LOCATOR: usize = 20;
    let read_at = |reader: &mut R, at: u64, buf: &mut [u8]| {
        reader
            .seek(SeekFrom::Start(at))
            .and_then(|_| reader.read_exact(buf))
            .map_err(|e| format!("cannot read the archive's directory ({e})"))
    };
    if len < EOCD as u64 {
        return Err("too short for a zip archive".into());
    }
    let mut eocd = [0u8; EOCD];
    read_at(reader, len - EOCD as u64, &mut eocd)?;
    if eocd[..4] != [0x50, 0x4b, 0x05, 0x06] {
        return Err(
            "no zip end-of-archive record at the end (not a zip file, or one with a comment, which torch.save does not write)"
                .into(),
        );
    }
    let le16 = |b: &[u8]| u64::from(u16::from_le_bytes([b[0], b[1]]));
    let le32 = |b: &[u8]| u64::from(u32::from_le_bytes(b.try_into().unwrap()));
    let le64 = |b: &[u8]| u64::from_le_bytes(b.try_into().unwrap());
    let (mut entries, mut dir_size) = (le16(&eocd[10..12]), le32(&eocd[12..16]));
    if entries == 0xffff || dir_size == 0xffff_ffff || le32(&eocd[16..20]) == 0xffff_ffff {
        // ZIP64: the counts are in the ZIP64 end record, which the locator before this points at.
        let at = len
            .checked_sub((EOCD + LOCATOR) as u64)
            .ok_or("a ZIP64 archive without its locator")?;
        let mut locator = [0u8; LOCATOR];
        read_at(reader, at, &mut locator)?;
        if locator[..4] != [0x50, 0x4b, 0x06, 0x07] {
            return Err("a ZIP64 archive without its locator".into());
        }
        let record_at = le64(&locator[8..16]);
        let mut record = [0u8; 56];
        if record_at.checked_add(56).is_none_or(|end| end > len) {
            return Err("the ZIP64 end record lies outside the file".into());
        }
        read_at(reader, record_at, &mut record)?;
        if record[..4] != [0x50, 0x4b, 0x06, 0x06] {
            return Err("no ZIP64 end record where its locator points".into());
        }
        (entries, dir_size) = (le64(&record[32..40]), le64(&record[40..48]));
    }
    if dir_size > len || entries.saturating_mul(46) > dir_size {
        return Err(format!(
            "the directory claims {entries} entries in {dir_size} bytes of a {len}-byte file"
        ));
    }
    reader
        .seek(SeekFrom::Start(0))
        .map_err(|e| format!("cannot read the archive ({e})"))?;
    Ok(())
}
