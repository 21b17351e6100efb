//! Writing a PyTorch state dict: the file `torch.save(model.state_dict(), path)` would be, for
//! named float32 tensors (the trainer's `crestereo export pytorch` passes the reference network's
//! key names).
//!
//! The format is PyTorch's zip serialization (the default of `torch.save` since 1.6), written
//! here without PyTorch:
//!
//! - a zip archive of *stored* (uncompressed) entries under one folder, `archive/` (the name
//!   `torch.save` gives when it writes to a buffer), each entry's data aligned to 64 bytes, as
//!   PyTorch aligns them (so `torch.load(..., mmap=True)` can map the storages in place);
//! - `archive/data.pkl`: a protocol-2 pickle of a `collections.OrderedDict` from key to
//!   `torch._utils._rebuild_tensor_v2(storage, 0, shape, stride, False, OrderedDict())`, where
//!   `storage` is the persistent id `('storage', torch.FloatStorage, '<n>', 'cpu', numel)`;
//! - `archive/data/<n>`: the raw little-endian float32 values of storage `n`, one storage per
//!   tensor, contiguous (row-major strides);
//! - the small records PyTorch writes beside them: `.format_version` (`1`), `.storage_alignment`
//!   (`64`), `byteorder` (`little`), `version` (`3`) and `.data/serialization_id`.
//!
//! The pickle uses only plain opcodes (no `_metadata` attribute of a module's state dict, which
//! `load_state_dict` does not need), so `torch.load(path, weights_only=True)` reads it, and so do
//! the checks of [`super::check_state_dict`] and Burn's PyTorch reader. The bytes depend only on
//! the tensors: the same model gives the same file.

use std::io::Write;
use std::path::Path;

use super::NamedArray;
use crate::error::{Error, Result};

/// A problem with the tensors given, or of the zip writer (in memory: never an I/O error).
type EncodeResult<T> = std::result::Result<T, String>;

/// The folder inside the archive (PyTorch's name when it saves to a buffer).
const ARCHIVE: &str = "archive";
/// PyTorch's alignment of every record's data.
const ALIGNMENT: u16 = 64;

/// Writes `tensors` (reference keys and layout) to `path` as a PyTorch state dict, durably;
/// returns the file's size in bytes.
pub fn write_state_dict(tensors: &[NamedArray], path: &Path) -> Result<u64> {
    let bytes = encode_state_dict(tensors).map_err(|m| Error::format(path, m))?;
    crate::atomic::write_bytes_atomically(path, &bytes)?;
    Ok(bytes.len() as u64)
}

/// The bytes of a `torch.save` zip file holding `tensors` as an ordered state dict, in order.
pub fn encode_state_dict(tensors: &[NamedArray]) -> EncodeResult<Vec<u8>> {
    let mut seen = std::collections::HashSet::new();
    for t in tensors {
        if t.name.is_empty() {
            return Err("a tensor has an empty name".into());
        }
        if !seen.insert(t.name.as_str()) {
            return Err(format!("tensor {} appears twice", t.name));
        }
        let numel: usize = t.shape.iter().product();
        if numel != t.data.len() {
            return Err(format!(
                "tensor {}: shape {:?} holds {numel} values, but {} were given",
                t.name,
                t.shape,
                t.data.len()
            ));
        }
    }
    let pickle = state_dict_pickle(tensors);
    let data_bytes: usize = tensors.iter().map(|t| 4 * t.data.len()).sum();
    let mut zip = zip::ZipWriter::new(std::io::Cursor::new(Vec::with_capacity(
        data_bytes + pickle.len() + 256 * (tensors.len() + 8),
    )));
    let mut id = SerializationId::default();
    add_record(&mut zip, &mut id, "data.pkl", &pickle)?;
    add_record(&mut zip, &mut id, ".format_version", b"1")?;
    let alignment = ALIGNMENT.to_string();
    add_record(
        &mut zip,
        &mut id,
        ".storage_alignment",
        alignment.as_bytes(),
    )?;
    add_record(&mut zip, &mut id, "byteorder", b"little")?;
    let mut storage = Vec::new();
    for (n, t) in tensors.iter().enumerate() {
        storage.clear();
        storage.extend(t.data.iter().flat_map(|v| v.to_le_bytes()));
        add_record(&mut zip, &mut id, &format!("data/{n}"), &storage)?;
    }
    add_record(&mut zip, &mut id, "version", b"3\n")?;
    let serialization_id = id.finish();
    add_record(
        &mut zip,
        &mut id,
        ".data/serialization_id",
        serialization_id.as_bytes(),
    )?;
    Ok(zip
        .finish()
        .map_err(|e| format!("finishing the zip archive: {e}"))?
        .into_inner())
}

/// One stored record `archive/<name>`, its data aligned as PyTorch aligns it.
fn add_record<W: std::io::Write + std::io::Seek>(
    zip: &mut zip::ZipWriter<W>,
    id: &mut SerializationId,
    name: &str,
    data: &[u8],
) -> EncodeResult<()> {
    let options = zip::write::SimpleFileOptions::DEFAULT
        .compression_method(zip::CompressionMethod::Stored)
        .with_alignment(ALIGNMENT)
        .unix_permissions(0o644)
        .large_file(data.len() as u64 >= u64::from(u32::MAX));
    zip.start_file(format!("{ARCHIVE}/{name}"), options)
        .map_err(|e| format!("writing the zip entry {name}: {e}"))?;
    zip.write_all(data)
        .map_err(|e| format!("writing the zip entry {name}: {e}"))?;
    id.add(data);
    Ok(())
}

/// PyTorch's `.data/serialization_id`: 40 decimal digits that tell one saved file from another.
/// PyTorch draws part of it at random; here it is a hash (FNV-1a, 64 bit) of the records, so the
/// same tensors give the same file.
struct SerializationId {
    hash: u64,
    records: u64,
}

impl Default for SerializationId {
    fn default() -> Self {
        Self {
            hash: 0xcbf2_9ce4_8422_2325,
            records: 0,
        }
    }
}

impl SerializationId {
    fn add(&mut self, data: &[u8]) {
        for &b in data.iter().chain(&[0xff]) {
            self.hash = (self.hash ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3);
        }
        self.records += 1;
    }

    fn finish(&self) -> String {
        format!(
            "{:020}{:020}",
            self.hash,
            self.hash.rotate_left(32) ^ self.records
        )
    }
}

/// The pickle (protocol 2) of the ordered state dict, byte for byte what `torch.save` writes for
/// an `OrderedDict` of these tensors (its pickler memoizes every string, tuple and object once,
/// takes globals and repeated strings from the memo, and sets the items 1000 per `SETITEMS`;
/// `crestereo-train/tests/integration/export_pytorch.rs` compares with `torch.save`).
fn state_dict_pickle(tensors: &[NamedArray]) -> Vec<u8> {
    const BATCH: usize = 1000;
    let mut p = Pickler::default();
    p.proto2();
    // OrderedDict()
    p.global("collections", "OrderedDict");
    p.op(op::EMPTY_TUPLE);
    p.op(op::REDUCE);
    p.memoize();
    for (b, batch) in tensors.chunks(BATCH).enumerate() {
        p.op(op::MARK);
        for (i, t) in batch.iter().enumerate() {
            let storage = b * BATCH + i; // the storage's record: data/<storage>
            p.unicode(&t.name);
            p.memoize();
            p.global("torch._utils", "_rebuild_tensor_v2");
            p.op(op::MARK);
            {
                // persistent_load(('storage', torch.FloatStorage, '<n>', 'cpu', numel))
                p.op(op::MARK);
                p.memoized_unicode("storage");
                p.global("torch", "FloatStorage");
                p.unicode(&storage.to_string());
                p.memoize();
                p.memoized_unicode("cpu");
                p.int(t.data.len() as i64);
                p.op(op::TUPLE);
                p.memoize();
                p.op(op::BINPERSID);
                // storage_offset, size, stride, requires_grad, backward_hooks
                p.int(0);
                p.int_tuple(t.shape.iter().map(|&d| d as i64));
                p.int_tuple(contiguous_strides(&t.shape));
                p.op(op::NEWFALSE);
                p.global("collections", "OrderedDict");
                p.op(op::EMPTY_TUPLE);
                p.op(op::REDUCE);
                p.memoize();
            }
            p.op(op::TUPLE);
            p.memoize();
            p.op(op::REDUCE);
            p.memoize();
        }
        p.op(op::SETITEMS);
    }
    p.op(op::STOP);
    p.out
}

/// Row-major strides of `shape`.
fn contiguous_strides(shape: &[usize]) -> Vec<i64> {
    let mut strides = vec![1i64; shape.len()];
    for i in (0..shape.len().saturating_sub(1)).rev() {
        strides[i] = strides[i + 1] * shape[i + 1] as i64;
    }
    strides
}

/// The few pickle opcodes (protocol 2) a state dict needs.
#[derive(Default)]
struct Pickler {
    out: Vec<u8>,
    /// Memo index of each memoized global (`module\nname`) and string.
    memo: std::collections::HashMap<String, u32>,
    next_memo: u32,
}

/// The opcodes that take no argument, by their names in Python's `pickletools`.
mod op {
    pub const STOP: u8 = b'.';
    pub const MARK: u8 = b'(';
    pub const EMPTY_TUPLE: u8 = b')';
    pub const TUPLE: u8 = b't';
    pub const REDUCE: u8 = b'R';
    pub const SETITEMS: u8 = b'u';
    pub const BINPERSID: u8 = b'Q';
    pub const NEWFALSE: u8 = 0x89;
}

impl Pickler {
    fn proto2(&mut self) {
        self.out.extend([0x80, 2]); // PROTO 2
    }

    /// An opcode that takes no argument ([`op`]).
    fn op(&mut self, code: u8) {
        self.out.push(code);
    }

    /// Stores the top of the stack in the next memo slot (BINPUT / LONG_BINPUT); returns the slot.
    fn memoize(&mut self) -> u32 {
        let i = self.next_memo;
        self.next_memo += 1;
        if let Ok(b) = u8::try_from(i) {
            self.out.extend([b'q', b]); // BINPUT
        } else {
            self.out.push(b'r'); // LONG_BINPUT
            self.out.extend(i.to_le_bytes());
        }
        i
    }

    fn get(&mut self, i: u32) {
        if let Ok(b) = u8::try_from(i) {
            self.out.extend([b'h', b]); // BINGET
        } else {
            self.out.push(b'j'); // LONG_BINGET
            self.out.extend(i.to_le_bytes());
        }
    }

    /// `module.name` (GLOBAL the first time, then from the memo).
    fn global(&mut self, module: &str, name: &str) {
        self.once(format!("global {module}\n{name}"), |p| {
            p.out.push(b'c'); // GLOBAL
            p.out.extend(module.as_bytes());
            p.out.push(b'\n');
            p.out.extend(name.as_bytes());
            p.out.push(b'\n');
        });
    }

    /// Writes what `write` writes and memoizes it the first time `key` comes, then takes it
    /// from the memo.
    fn once(&mut self, key: String, write: impl FnOnce(&mut Self)) {
        if let Some(&i) = self.memo.get(&key) {
            self.get(i);
            return;
        }
        write(self);
        let i = self.memoize();
        self.memo.insert(key, i);
    }

    fn unicode(&mut self, s: &str) {
        self.out.push(b'X'); // BINUNICODE
        self.out.extend((s.len() as u32).to_le_bytes());
        self.out.extend(s.as_bytes());
    }

    /// A string written once and then taken from the memo.
    fn memoized_unicode(&mut self, s: &str) {
        self.once(format!("str {s}"), |p| p.unicode(s));
    }

    fn int(&mut self, v: i64) {
        if let Ok(b) = u8::try_from(v) {
            self.out.extend([b'K', b]); // BININT1
        } else if let Ok(w) = u16::try_from(v) {
            self.out.push(b'M'); // BININT2
            self.out.extend(w.to_le_bytes());
        } else if let Ok(d) = i32::try_from(v) {
            self.out.push(b'J'); // BININT
            self.out.extend(d.to_le_bytes());
        } else {
            // LONG1: little-endian two's complement, shortest length
            let bytes = v.to_le_bytes();
            let mut n = 8;
            while n > 1 {
                let (top, next) = (bytes[n - 1], bytes[n - 2]);
                if (top == 0 && next & 0x80 == 0) || (top == 0xff && next & 0x80 != 0) {
                    n -= 1;
                } else {
                    break;
                }
            }
            self.out.extend([0x8a, n as u8]);
            self.out.extend(&bytes[..n]);
        }
    }

    /// A tuple of ints: TUPLE1/2/3 for short ones, as Python writes them.
    fn int_tuple(&mut self, values: impl IntoIterator<Item = i64>) {
        let values: Vec<i64> = values.into_iter().collect();
        if values.is_empty() {
            self.op(op::EMPTY_TUPLE);
        } else if values.len() <= 3 {
            for v in &values {
                self.int(*v);
            }
            self.out.push([0x85, 0x86, 0x87][values.len() - 1]); // TUPLE1..3
        } else {
            self.op(op::MARK);
            for v in &values {
                self.int(*v);
            }
            self.op(op::TUPLE);
        }
        self.memoize();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn named(name: &str, shape: &[usize], data: Vec<f32>) -> NamedArray {
        NamedArray {
            name: name.into(),
            shape: shape.to_vec(),
            data,
        }
    }

    #[test]
    fn strides_are_row_major() {
        assert_eq!(contiguous_strides(&[64, 3, 7, 7]), vec![147, 49, 7, 1]);
        assert_eq!(contiguous_strides(&[5]), vec![1]);
        assert_eq!(contiguous_strides(&[]), Vec::<i64>::new());
    }

    #[test]
    fn ints_take_the_shortest_opcode() {
        let enc = |v: i64| {
            let mut p = Pickler::default();
            p.int(v);
            p.out
        };
        assert_eq!(enc(7), vec![b'K', 7]);
        assert_eq!(enc(9408), vec![b'M', 0xc0, 0x24]);
        assert_eq!(
            enc(442_368),
            [&[b'J'][..], &442_368i32.to_le_bytes()].concat()
        );
        assert_eq!(enc(-1), [&[b'J'][..], &(-1i32).to_le_bytes()].concat());
        assert_eq!(enc(1 << 32), vec![0x8a, 5, 0, 0, 0, 0, 1]);
        assert_eq!(enc(1 << 31), vec![0x8a, 5, 0, 0, 0, 0x80, 0]);
        assert_eq!(enc(-(1 << 40)), vec![0x8a, 6, 0, 0, 0, 0, 0, 0xff]);
    }

    #[test]
    fn records_are_stored_and_aligned_and_the_same_tensors_give_the_same_bytes() {
        let tensors = vec![
            named(
                "a.weight",
                &[2, 3],
                vec![1.0, -2.0, 3.5, f32::MIN_POSITIVE, -0.0, 7.0],
            ),
            named("a.bias", &[2], vec![0.25, 1e-30]),
        ];
        let bytes = encode_state_dict(&tensors).unwrap();
        assert_eq!(bytes, encode_state_dict(&tensors).unwrap());
        let mut zip = zip::ZipArchive::new(std::io::Cursor::new(&bytes)).unwrap();
        let names: Vec<String> = zip.file_names().map(str::to_string).collect();
        for n in [
            "archive/data.pkl",
            "archive/byteorder",
            "archive/version",
            "archive/data/0",
            "archive/data/1",
        ] {
            assert!(names.iter().any(|x| x == n), "{n} missing: {names:?}");
        }
        for i in 0..zip.len() {
            let f = zip.by_index(i).unwrap();
            assert_eq!(f.compression(), zip::CompressionMethod::Stored);
            assert_eq!(f.data_start().unwrap() % 64, 0, "{}", f.name());
        }
        let mut read = |name: &str| {
            let mut v = Vec::new();
            std::io::Read::read_to_end(&mut zip.by_name(name).unwrap(), &mut v).unwrap();
            v
        };
        assert_eq!(read("archive/byteorder"), b"little");
        assert_eq!(read("archive/version"), b"3\n");
        assert_eq!(read("archive/.data/serialization_id").len(), 40);
        let storage = read("archive/data/0");
        let back: Vec<u32> = storage
            .chunks(4)
            .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
            .collect();
        let bits: Vec<u32> = tensors[0].data.iter().map(|v| v.to_bits()).collect();
        assert_eq!(back, bits);
    }

    #[test]
    fn inconsistent_tensors_are_refused() {
        let e = encode_state_dict(&[named("x", &[2, 2], vec![0.0; 3])]).unwrap_err();
        assert!(e.contains("holds 4 values"), "{e}");
        let twice = [named("x", &[1], vec![0.0]), named("x", &[1], vec![1.0])];
        let e = encode_state_dict(&twice).unwrap_err();
        assert!(e.contains("twice"), "{e}");
    }
}
