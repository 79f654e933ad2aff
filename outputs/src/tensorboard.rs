//! TensorBoard event files, written by hand (no maintained Rust crate writes them): TFRecord framing (length,
//! masked CRC32C of the length, data, masked CRC32C of the data) around `Event` protobufs, each a wall time, a step
//! and a `Summary` of scalar values. `tensorboard --logdir runs/` reads a run's `tb/` folder; so do W&B and Aim.
//!
//! The encoding follows tensorflow/core/util/event.proto and tensorflow/core/framework/summary.proto: `Event`
//! {1: double wall_time, 2: int64 step, 3: string file_version, 5: Summary summary}, `Summary` {1: repeated Value},
//! `Value` {1: string tag, 2: float simple_value}.

use std::fs::{File, OpenOptions};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

/// CRC-32C (Castagnoli), as TFRecord uses it.
fn crc32c(data: &[u8]) -> u32 {
    const POLY: u32 = 0x82F6_3B78;
    let mut crc = !0u32;
    for &b in data {
        crc ^= b as u32;
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ POLY
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// TFRecord's masked CRC.
fn masked_crc(data: &[u8]) -> u32 {
    let crc = crc32c(data);
    (crc.rotate_right(15)).wrapping_add(0xa282_ead8)
}

fn varint(mut v: u64, out: &mut Vec<u8>) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

/// A length-delimited field.
fn bytes_field(field: u32, data: &[u8], out: &mut Vec<u8>) {
    varint(((field << 3) | 2) as u64, out);
    varint(data.len() as u64, out);
    out.extend_from_slice(data);
}

/// One `Event` with `summary` scalars (tag, value), or with `file_version` when `scalars` is empty and `version`
/// is given.
fn event(wall_time: f64, step: i64, version: Option<&str>, scalars: &[(&str, f32)]) -> Vec<u8> {
    let mut e = Vec::new();
    e.push(0x09);
    e.extend_from_slice(&wall_time.to_le_bytes());
    e.push(0x10);
    varint(step as u64, &mut e);
    if let Some(v) = version {
        bytes_field(3, v.as_bytes(), &mut e);
    }
    if !scalars.is_empty() {
        let mut summary = Vec::new();
        for (tag, value) in scalars {
            let mut v = Vec::new();
            bytes_field(1, tag.as_bytes(), &mut v);
            v.push(0x15);
            v.extend_from_slice(&value.to_le_bytes());
            bytes_field(1, &v, &mut summary);
        }
        bytes_field(5, &summary, &mut e);
    }
    e
}

/// One TFRecord around `data`.
fn record(data: &[u8]) -> Vec<u8> {
    let len = (data.len() as u64).to_le_bytes();
    let mut out = Vec::with_capacity(data.len() + 16);
    out.extend_from_slice(&len);
    out.extend_from_slice(&masked_crc(&len).to_le_bytes());
    out.extend_from_slice(data);
    out.extend_from_slice(&masked_crc(data).to_le_bytes());
    out
}

fn now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// An event file in a run's `tb/` folder: a new file per process (TensorBoard reads every file of the folder, so
/// a resumed run goes on in a second file).
pub struct EventWriter {
    path: PathBuf,
    out: BufWriter<File>,
}

impl EventWriter {
    /// Creates `dir/events.out.tfevents.<seconds>.<host>` with its version record.
    pub fn create(dir: &Path) -> io::Result<Self> {
        std::fs::create_dir_all(dir)?;
        let host = std::fs::read_to_string("/etc/hostname")
            .map(|h| h.trim().to_string())
            .unwrap_or_else(|_| "cabc".into());
        let wall = now();
        let path = dir.join(format!("events.out.tfevents.{}.{host}", wall as u64));
        let file = OpenOptions::new().create(true).append(true).open(&path)?;
        let mut w = EventWriter {
            path,
            out: BufWriter::new(file),
        };
        w.out
            .write_all(&record(&event(wall, 0, Some("brain.Event:2"), &[])))?;
        w.out.flush()?;
        Ok(w)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Writes the scalars (tag, value) of one step and flushes them.
    pub fn scalars(&mut self, step: u64, scalars: &[(&str, f32)]) -> io::Result<()> {
        if scalars.is_empty() {
            return Ok(());
        }
        self.out
            .write_all(&record(&event(now(), step as i64, None, scalars)))?;
        self.out.flush()
    }
}

/// The scalars of an event file, read back: (step, tag, value), checking every record's CRCs. Files from cabc's
/// writer only (the fields it writes); for tests and `cabc show`.
pub fn read_scalars(bytes: &[u8]) -> Result<Vec<(i64, String, f32)>, String> {
    let mut out = Vec::new();
    let mut rest = bytes;
    while !rest.is_empty() {
        let header = rest.get(..12).ok_or("a truncated record header")?;
        let len_bytes: [u8; 8] = header[..8].try_into().expect("8 bytes");
        if u32::from_le_bytes(header[8..12].try_into().expect("4 bytes")) != masked_crc(&len_bytes)
        {
            return Err("a length's CRC does not match".into());
        }
        let len = usize::try_from(u64::from_le_bytes(len_bytes)).map_err(|e| e.to_string())?;
        let data = rest
            .get(12..12usize.saturating_add(len))
            .ok_or("a truncated record")?;
        let crc = rest
            .get(12 + len..16 + len)
            .ok_or("a truncated record CRC")?;
        if u32::from_le_bytes(crc.try_into().expect("4 bytes")) != masked_crc(data) {
            return Err("a record's CRC does not match".into());
        }
        decode_event(data, &mut out)?;
        rest = &rest[16 + len..];
    }
    Ok(out)
}

/// Reads a varint at `*i`.
fn read_varint(data: &[u8], i: &mut usize) -> Result<u64, String> {
    let mut v = 0u64;
    for shift in (0..64).step_by(7) {
        let b = *data.get(*i).ok_or("a truncated varint")?;
        *i += 1;
        v |= ((b & 0x7f) as u64) << shift;
        if b & 0x80 == 0 {
            return Ok(v);
        }
    }
    Err("a varint too long".into())
}

/// The fields of a message: (field number, wire type, payload bytes; varints as their value's bytes).
fn fields(data: &[u8]) -> Result<Vec<(u32, u8, Vec<u8>)>, String> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < data.len() {
        let key = read_varint(data, &mut i)?;
        let (field, wire) = ((key >> 3) as u32, (key & 7) as u8);
        let take = |i: &mut usize, n: usize| -> Result<Vec<u8>, String> {
            let v = data.get(*i..*i + n).ok_or("a truncated field")?.to_vec();
            *i += n;
            Ok(v)
        };
        let payload = match wire {
            0 => read_varint(data, &mut i)?.to_le_bytes().to_vec(),
            1 => take(&mut i, 8)?,
            2 => {
                let n = read_varint(data, &mut i)? as usize;
                take(&mut i, n)?
            }
            5 => take(&mut i, 4)?,
            w => return Err(format!("wire type {w}")),
        };
        out.push((field, wire, payload));
    }
    Ok(out)
}

fn decode_event(data: &[u8], out: &mut Vec<(i64, String, f32)>) -> Result<(), String> {
    let top = fields(data)?;
    let step = top.iter().find(|f| f.0 == 2).map_or(0, |f| {
        i64::from_le_bytes(f.2[..8].try_into().expect("8 bytes"))
    });
    for (_, _, summary) in top.iter().filter(|f| f.0 == 5) {
        for (_, _, value) in fields(summary)?.iter().filter(|f| f.0 == 1) {
            let v = fields(value)?;
            let tag = v.iter().find(|f| f.0 == 1).ok_or("a value without a tag")?;
            let x = v
                .iter()
                .find(|f| f.0 == 2)
                .ok_or("a value without simple_value")?;
            let tag = String::from_utf8(tag.2.clone()).map_err(|e| e.to_string())?;
            let x = f32::from_le_bytes(x.2[..4].try_into().map_err(|_| "a short float")?);
            out.push((step, tag, x));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32c_matches_its_check_value() {
        // The CRC-32C check value of "123456789" (RFC 3720).
        assert_eq!(crc32c(b"123456789"), 0xE306_9283);
    }

    #[test]
    fn what_is_written_reads_back_and_a_flipped_bit_is_caught() {
        let dir = tempfile::tempdir().unwrap();
        let mut w = EventWriter::create(dir.path()).unwrap();
        w.scalars(
            0,
            &[("metrics/imitation_loss", 0.5), ("metrics/d_plus", 1024.0)],
        )
        .unwrap();
        w.scalars(1, &[("metrics/imitation_loss", 0.25)]).unwrap();
        let bytes = std::fs::read(w.path()).unwrap();
        let read = read_scalars(&bytes).unwrap();
        assert_eq!(
            read,
            vec![
                (0, "metrics/imitation_loss".into(), 0.5),
                (0, "metrics/d_plus".into(), 1024.0),
                (1, "metrics/imitation_loss".into(), 0.25)
            ]
        );
        let mut bad = bytes.clone();
        let n = bad.len();
        bad[n - 6] ^= 1;
        assert!(read_scalars(&bad).is_err());
        assert!(read_scalars(&bytes[..bytes.len() - 3]).is_err());
    }
}
