//! Scalar summaries as TensorBoard event files (`events.out.tfevents.*`), so `tensorboard
//! --logdir <run>/tensorboard` plots a run without any Python in the training process.
//!
//! The format is TFRecord framing around `tensorflow.Event` protobuf messages. Only the fields a
//! scalar needs are written (wall_time, step, file_version, summary.value{tag, simple_value}),
//! encoded by hand: pulling a protobuf stack in for five fields would be most of the work.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};

/// Appends scalars to one new event file.
pub struct EventWriter {
    path: PathBuf,
    out: BufWriter<File>,
}

fn masked_crc(data: &[u8]) -> u32 {
    let crc = crc32c::crc32c(data);
    crc.rotate_right(15).wrapping_add(0xa282_ead8)
}

fn varint(mut v: u64, out: &mut Vec<u8>) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

fn length_delimited(field: u32, bytes: &[u8], out: &mut Vec<u8>) {
    varint(u64::from(field << 3 | 2), out);
    varint(bytes.len() as u64, out);
    out.extend_from_slice(bytes);
}

fn event_header(wall_time: f64, step: i64, out: &mut Vec<u8>) {
    out.push(1 << 3 | 1); // wall_time: double
    out.extend_from_slice(&wall_time.to_le_bytes());
    out.push(2 << 3); // step: int64 varint (two's complement for negatives)
    varint(step as u64, out);
}

/// One `Event{wall_time, step, summary{value{tag, simple_value}}}` message.
pub fn scalar_event(wall_time: f64, step: i64, tag: &str, value: f32) -> Vec<u8> {
    let mut val = Vec::new();
    length_delimited(1, tag.as_bytes(), &mut val);
    val.push(2 << 3 | 5); // simple_value: float
    val.extend_from_slice(&value.to_le_bytes());
    let mut summary = Vec::new();
    length_delimited(1, &val, &mut summary);
    let mut event = Vec::new();
    event_header(wall_time, step, &mut event);
    length_delimited(5, &summary, &mut event);
    event
}

fn now() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

impl EventWriter {
    /// Creates `dir/events.out.tfevents.<time>.<host>.<pid>` and writes the version record.
    pub fn create(dir: &Path) -> Result<Self> {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        let host = std::fs::read_to_string("/etc/hostname")
            .map(|h| h.trim().to_string())
            .unwrap_or_else(|_| "localhost".into());
        let path = dir.join(format!(
            "events.out.tfevents.{}.{host}.{}",
            now() as u64,
            std::process::id()
        ));
        let file =
            File::create(&path).with_context(|| format!("cannot create {}", path.display()))?;
        let mut w = Self {
            path,
            out: BufWriter::new(file),
        };
        let mut event = Vec::new();
        event_header(now(), 0, &mut event);
        length_delimited(3, b"brain.Event:2", &mut event);
        w.record(&event)?;
        w.flush()?;
        Ok(w)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    fn record(&mut self, data: &[u8]) -> Result<()> {
        let len = (data.len() as u64).to_le_bytes();
        self.out.write_all(&len)?;
        self.out.write_all(&masked_crc(&len).to_le_bytes())?;
        self.out.write_all(data)?;
        self.out.write_all(&masked_crc(data).to_le_bytes())?;
        Ok(())
    }

    pub fn scalar(&mut self, tag: &str, step: u64, value: f64) -> Result<()> {
        self.record(&scalar_event(now(), step as i64, tag, value as f32))
            .with_context(|| format!("cannot write {}", self.path.display()))
    }

    /// Writes out what is buffered and makes it durable. An event file is an append-only log
    /// (TensorBoard reads it while it grows), so it cannot take the temp-and-rename path of
    /// finished files; instead every write and this flush are checked, and a record torn by a
    /// crash is one TensorBoard's reader drops by its checksum.
    pub fn flush(&mut self) -> Result<()> {
        self.out
            .flush()
            .and_then(|()| self.out.get_ref().sync_data())
            .with_context(|| format!("cannot write {}", self.path.display()))
    }
}

/// One scalar of an event file.
#[derive(Debug, Clone, PartialEq)]
pub struct Scalar {
    pub step: i64,
    pub tag: String,
    pub value: f32,
}

/// Reads the scalars back, one per summary value. Checks both CRCs of every record (the tests'
/// independent check of what the writer produced).
pub fn read_scalars(path: &Path) -> Result<Vec<Scalar>> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut out = Vec::new();
    let mut at = 0;
    let bad = |what: &str| anyhow::anyhow!("{}: {what}", path.display());
    while at < bytes.len() {
        let header = bytes
            .get(at..at + 12)
            .ok_or_else(|| bad("truncated record header"))?;
        let len = u64::from_le_bytes(header[..8].try_into().unwrap()) as usize;
        if masked_crc(&header[..8]) != u32::from_le_bytes(header[8..12].try_into().unwrap()) {
            return Err(bad("record length CRC mismatch"));
        }
        let data = bytes
            .get(at + 12..at + 12 + len)
            .ok_or_else(|| bad("truncated record"))?;
        let crc = bytes
            .get(at + 12 + len..at + 16 + len)
            .ok_or_else(|| bad("truncated record CRC"))?;
        if masked_crc(data) != u32::from_le_bytes(crc.try_into().unwrap()) {
            return Err(bad("record data CRC mismatch"));
        }
        decode_event(data, &mut out).map_err(|e| bad(&e))?;
        at += 16 + len;
    }
    Ok(out)
}

struct Cursor<'a> {
    b: &'a [u8],
    i: usize,
}

impl Cursor<'_> {
    fn varint(&mut self) -> Result<u64, String> {
        let mut v = 0u64;
        for shift in (0..64).step_by(7) {
            let byte = *self.b.get(self.i).ok_or("truncated varint")?;
            self.i += 1;
            v |= u64::from(byte & 0x7f) << shift;
            if byte < 0x80 {
                return Ok(v);
            }
        }
        Err("varint too long".into())
    }
    fn take(&mut self, n: usize) -> Result<&[u8], String> {
        let s = self.b.get(self.i..self.i + n).ok_or("truncated field")?;
        self.i += n;
        Ok(s)
    }
    /// The next field.
    fn field(&mut self) -> Result<Field, String> {
        let key = self.varint()?;
        let number = key >> 3;
        let (payload, varint) = match key & 7 {
            0 => (Vec::new(), self.varint()?),
            1 => (self.take(8)?.to_vec(), 0),
            2 => {
                let n = self.varint()? as usize;
                (self.take(n)?.to_vec(), 0)
            }
            5 => (self.take(4)?.to_vec(), 0),
            w => return Err(format!("unsupported wire type {w}")),
        };
        Ok(Field {
            number,
            payload,
            varint,
        })
    }

    fn at_end(&self) -> bool {
        self.i >= self.b.len()
    }
}

/// One protobuf field.
struct Field {
    number: u64,
    /// The bytes of a length-delimited or fixed-size field; empty for a varint.
    payload: Vec<u8>,
    /// The value of a varint field; 0 for the others.
    varint: u64,
}

/// The scalars of one `Event` message.
fn decode_event(data: &[u8], out: &mut Vec<Scalar>) -> Result<(), String> {
    let mut c = Cursor { b: data, i: 0 };
    let mut step = 0i64;
    let mut values = Vec::new();
    while !c.at_end() {
        let field = c.field()?;
        match field.number {
            2 => step = field.varint as i64,
            5 => decode_summary(&field.payload, &mut values)?,
            _ => {}
        }
    }
    out.extend(values.into_iter().map(|v| Scalar { step, ..v }));
    Ok(())
}

/// The `value` entries of a `Summary` (their step is the event's, filled in by the caller).
fn decode_summary(summary: &[u8], values: &mut Vec<Scalar>) -> Result<(), String> {
    let mut c = Cursor { b: summary, i: 0 };
    while !c.at_end() {
        let field = c.field()?;
        if field.number == 1 {
            values.push(decode_value(&field.payload)?);
        }
    }
    Ok(())
}

/// One `Summary.Value{tag, simple_value}`.
fn decode_value(value: &[u8]) -> Result<Scalar, String> {
    let mut scalar = Scalar {
        step: 0,
        tag: String::new(),
        value: f32::NAN,
    };
    let mut c = Cursor { b: value, i: 0 };
    while !c.at_end() {
        let field = c.field()?;
        match field.number {
            1 => scalar.tag = String::from_utf8(field.payload).map_err(|_| "tag is not UTF-8")?,
            2 => {
                scalar.value =
                    f32::from_le_bytes(field.payload.try_into().map_err(|_| "bad float")?)
            }
            _ => {}
        }
    }
    Ok(scalar)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn masked_crc_matches_tensorflow() {
        // TFRecord's framing of an empty payload: crc32c("") = 0, masked = 0xa282ead8; and the
        // CRC-32C check value of "123456789" is 0xe3069283 (RFC 3720).
        assert_eq!(masked_crc(b""), 0xa282_ead8);
        assert_eq!(crc32c::crc32c(b"123456789"), 0xe306_9283);
    }

    #[test]
    fn scalar_event_bytes_are_the_protobuf_encoding() {
        let e = scalar_event(0.5, 3, "loss", 1.0);
        let mut want = vec![0x09];
        want.extend_from_slice(&0.5f64.to_le_bytes());
        want.extend_from_slice(&[
            0x10, 3, 0x2a, 13, 0x0a, 11, 0x0a, 4, b'l', b'o', b's', b's', 0x15,
        ]);
        want.extend_from_slice(&1.0f32.to_le_bytes());
        assert_eq!(e, want);
    }

    #[test]
    fn writes_and_reads_back() {
        let dir = tempfile::tempdir().unwrap();
        let mut w = EventWriter::create(dir.path()).unwrap();
        for s in 0..300u64 {
            w.scalar("train/loss", s, 1.0 / (s + 1) as f64).unwrap();
            w.scalar("train/lr", s, 4e-4).unwrap();
        }
        w.flush().unwrap();
        let got = read_scalars(w.path()).unwrap();
        assert_eq!(got.len(), 600);
        assert_eq!(
            got[2 * 299],
            Scalar {
                step: 299,
                tag: "train/loss".to_string(),
                value: (1.0f64 / 300.0) as f32
            }
        );
        // A flipped byte is caught.
        let mut bytes = std::fs::read(w.path()).unwrap();
        let n = bytes.len();
        bytes[n - 6] ^= 1;
        std::fs::write(w.path(), bytes).unwrap();
        assert!(
            read_scalars(w.path())
                .unwrap_err()
                .to_string()
                .contains("CRC")
        );
    }
}
