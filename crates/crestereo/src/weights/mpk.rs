//! Burn records (`.mpk`: named MessagePack) checked before Burn decodes them. Burn builds each
//! tensor from its record on trust: a tensor whose `shape` disagrees with its `bytes`, or has a
//! rank its parameter does not, ends the process in an assertion, and one of the right rank but
//! the wrong shape loads and fails later inside the network. The check walks the MessagePack
//! once, holding nothing of it but the tensors' shapes: every tensor must hold exactly its
//! shape's bytes, and (for a model record) sit at a parameter's path with that parameter's shape.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Result, bail};
use rmp::Marker;
use rmp::decode::read_marker;

/// A tensor found in a record: its path of map keys and array indices, and its shape.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct RecordTensor {
    pub path: String,
    pub shape: Vec<u64>,
}

/// Nesting deeper than any record of ours (a module tree is a few levels deep).
const MAX_DEPTH: usize = 64;
/// Dimensions of one tensor.
const MAX_DIMS: usize = 16;

/// The tensors of the record in `bytes`, each checked against its own bytes; `path` names the
/// file in errors.
pub(crate) fn record_tensors(bytes: &[u8], path: &Path) -> Result<Vec<RecordTensor>> {
    let mut walk = Walk {
        rd: bytes,
        len: bytes.len(),
        tensors: Vec::new(),
    };
    walk.value("", 0)
        .and_then(|_| match walk.rd.is_empty() {
            true => Ok(()),
            false => Err("bytes after the record".into()),
        })
        .map_err(|m: String| {
            anyhow::anyhow!(
                "{} is not a Burn record (.mpk) of this network: {m}",
                path.display()
            )
        })?;
    Ok(walk.tensors)
}

/// Refuses a record whose tensors do not sit at the model's parameters with their shapes
/// (`expected`: parameter path → shape, paths as the record nests them).
pub(crate) fn check_against(
    tensors: &[RecordTensor],
    expected: &BTreeMap<String, Vec<u64>>,
    path: &Path,
) -> Result<()> {
    for t in tensors {
        let Some(shape) = expected.get(&t.path) else {
            bail!(
                "{} is not a record of this network: it holds a tensor at {:?}, which is no parameter of it",
                path.display(),
                t.path
            );
        };
        if *shape != t.shape {
            bail!(
                "{} is not a record of this network: {} has shape {:?}, the network's is {:?}",
                path.display(),
                t.path,
                t.shape,
                shape
            );
        }
    }
    Ok(())
}

struct Walk<'a> {
    rd: &'a [u8],
    len: usize,
    tensors: Vec<RecordTensor>,
}

/// What a value is, as far as finding tensors needs: a string (a map key, a dtype), the length
/// of a byte string, a short list of integers (a shape), or something else.
enum Seen<'a> {
    Str(&'a str),
    Bin(usize),
    Ints(Vec<u64>),
    Other,
}

impl<'a> Walk<'a> {
    fn at(&self) -> usize {
        self.len - self.rd.len()
    }

    fn skip(&mut self, n: usize) -> Result<&'a [u8], String> {
        if n > self.rd.len() {
            return Err(format!(
                "a value at byte {} claims {n} bytes, {} remain",
                self.at(),
                self.rd.len()
            ));
        }
        let (head, rest) = self.rd.split_at(n);
        self.rd = rest;
        Ok(head)
    }

    /// The length a marker states: in the marker itself (the fix kinds), or in the 1, 2 or 4
    /// big-endian bytes after it.
    fn len_of(&mut self, m: Marker) -> Result<usize, String> {
        let width = match m {
            Marker::FixMap(n) | Marker::FixArray(n) | Marker::FixStr(n) => return Ok(n.into()),
            Marker::FixExt1 => return Ok(1),
            Marker::FixExt2 => return Ok(2),
            Marker::FixExt4 => return Ok(4),
            Marker::FixExt8 => return Ok(8),
            Marker::FixExt16 => return Ok(16),
            Marker::Str8 | Marker::Bin8 | Marker::Ext8 => 1,
            Marker::Str16 | Marker::Bin16 | Marker::Ext16 | Marker::Array16 | Marker::Map16 => 2,
            _ => 4,
        };
        let bytes = self.skip(width)?;
        Ok(bytes.iter().fold(0usize, |n, &b| n << 8 | usize::from(b)))
    }

    /// Reads one value; records it when it is a tensor (a map with `bytes`, `shape`, `dtype`).
    fn value(&mut self, path: &str, depth: usize) -> Result<Seen<'a>, String> {
        if depth > MAX_DEPTH {
            return Err(format!("values nest deeper than {MAX_DEPTH}"));
        }
        let at = self.at();
        let m = read_marker(&mut self.rd).map_err(|_| format!("the record ends at byte {at}"))?;
        Ok(match m {
            Marker::FixPos(v) => Seen::Ints(vec![v.into()]),
            Marker::U8 => Seen::Ints(vec![self.skip(1)?[0].into()]),
            Marker::U16 => Seen::Ints(vec![
                u16::from_be_bytes(self.skip(2)?.try_into().unwrap()).into(),
            ]),
            Marker::U32 => Seen::Ints(vec![
                u32::from_be_bytes(self.skip(4)?.try_into().unwrap()).into(),
            ]),
            Marker::U64 => Seen::Ints(vec![u64::from_be_bytes(self.skip(8)?.try_into().unwrap())]),
            Marker::Null | Marker::True | Marker::False | Marker::FixNeg(_) => Seen::Other,
            Marker::I8 | Marker::I16 | Marker::I32 | Marker::I64 => {
                let n = [1, 2, 4, 8][[Marker::I8, Marker::I16, Marker::I32, Marker::I64]
                    .iter()
                    .position(|&x| x == m)
                    .unwrap()];
                self.skip(n)?;
                Seen::Other
            }
            Marker::F32 => {
                self.skip(4)?;
                Seen::Other
            }
            Marker::F64 => {
                self.skip(8)?;
                Seen::Other
            }
            Marker::FixStr(_) | Marker::Str8 | Marker::Str16 | Marker::Str32 => {
                let n = self.len_of(m)?;
                let s = self.skip(n)?;
                std::str::from_utf8(s).map_or(Seen::Other, Seen::Str)
            }
            Marker::Bin8 | Marker::Bin16 | Marker::Bin32 => {
                let n = self.len_of(m)?;
                self.skip(n)?;
                Seen::Bin(n)
            }
            Marker::FixArray(_) | Marker::Array16 | Marker::Array32 => {
                let n = self.len_of(m)?;
                // Each element takes a byte at least: a count beyond the bytes left is a lie.
                if n > self.rd.len() {
                    return Err(format!("an array at byte {at} claims {n} elements"));
                }
                let mut ints = Vec::new();
                for i in 0..n {
                    let seen = self.value(&format!("{path}.{i}"), depth + 1)?;
                    if let (Seen::Ints(v), true) = (seen, ints.len() < MAX_DIMS) {
                        ints.extend(v);
                    }
                }
                match ints.len() == n && n <= MAX_DIMS {
                    true => Seen::Ints(ints),
                    false => Seen::Other,
                }
            }
            Marker::FixMap(_) | Marker::Map16 | Marker::Map32 => {
                let n = self.len_of(m)?;
                if n > self.rd.len() / 2 {
                    return Err(format!("a map at byte {at} claims {n} entries"));
                }
                let (mut bytes, mut shape, mut dtype) = (None, None, None);
                for _ in 0..n {
                    let key = match self.value(path, depth + 1)? {
                        Seen::Str(k) => k,
                        _ => "",
                    };
                    let child = if path.is_empty() {
                        key.to_string()
                    } else {
                        format!("{path}.{key}")
                    };
                    match (key, self.value(&child, depth + 1)?) {
                        ("bytes", Seen::Bin(len)) => bytes = Some(len),
                        ("shape", Seen::Ints(dims)) => shape = Some(dims),
                        ("dtype", seen) => dtype = Some(dtype_size(seen)),
                        _ => {}
                    }
                }
                if let (Some(bytes), Some(shape), Some(size)) = (bytes, shape, dtype) {
                    self.tensor(path, bytes, shape, size?)?;
                }
                Seen::Other
            }
            Marker::FixExt1
            | Marker::FixExt2
            | Marker::FixExt4
            | Marker::FixExt8
            | Marker::FixExt16
            | Marker::Ext8
            | Marker::Ext16
            | Marker::Ext32 => {
                let n = self.len_of(m)?;
                self.skip(n + 1)?;
                Seen::Other
            }
            Marker::Reserved => return Err(format!("a reserved marker at byte {at}")),
        })
    }

    fn tensor(
        &mut self,
        path: &str,
        bytes: usize,
        shape: Vec<u64>,
        size: u64,
    ) -> Result<(), String> {
        let need = shape
            .iter()
            .try_fold(size, |n, &d| n.checked_mul(d))
            .ok_or_else(|| format!("the tensor at {path:?} has a shape of more than 2^64 bytes"))?;
        if need != bytes as u64 {
            return Err(format!(
                "the tensor at {path:?} has shape {shape:?}, which needs {need} bytes; it holds {bytes}"
            ));
        }
        self.tensors.push(RecordTensor {
            path: path.to_string(),
            shape,
        });
        Ok(())
    }
}

/// Bytes per element of a tensor's `dtype` (Burn's `DType`, serialised as its variant's name or
/// a one-entry map from it).
fn dtype_size(seen: Seen<'_>) -> Result<u64, String> {
    let name = match seen {
        Seen::Str(s) => s,
        _ => return Err("a tensor's dtype is not one Burn writes for this network".into()),
    };
    Ok(match name {
        "F64" | "I64" | "U64" => 8,
        "F32" | "Flex32" | "I32" | "U32" => 4,
        "F16" | "BF16" | "I16" | "U16" => 2,
        "I8" | "U8" => 1,
        _ => {
            return Err(format!(
                "a tensor of dtype {name:?}, which this network does not store"
            ));
        }
    })
}
