//! The run's image log: D+'s images on disk, so that a checkpoint writes only the images that are new since the
//! last one instead of every image every epoch.
//!
//! `runs/<run>/replay-images-<generation>.log` is a sequence of fixed-size records (one image each). A checkpoint
//! appends the images written since the last one, fsyncs, and `replay.bin` (inside the atomic checkpoint) records
//! the log's generation, its committed length and, per D+ slot, the record holding its image. Records appended by a
//! checkpoint that did not commit are cut off when the run resumes, and a record a committed checkpoint points to
//! is never written again, so a crash at any point leaves the log consistent with the checkpoint that is read back.
//!
//! Evictions leave dead records behind; when the log holds more than twice the live images, the next checkpoint
//! writes the live ones into a new generation (slot order) and the older generation is removed once that checkpoint
//! has committed.

use super::ReplayError;
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

/// Dead records tolerated besides the live ones before a compaction (avoids rewriting a small log often).
const SLACK_RECORDS: u64 = 1024;

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> ReplayError + '_ {
    move |e| ReplayError::Log(format!("{}: {e}", path.display()))
}

/// One generation of the image log, open for appending.
#[derive(Debug)]
pub struct ImageLog {
    dir: PathBuf,
    generation: u64,
    file: File,
    records: u64,
    record_len: usize,
}

impl ImageLog {
    /// The file of `generation` in `dir`.
    pub fn path(dir: &Path, generation: u64) -> PathBuf {
        dir.join(format!("replay-images-{generation}.log"))
    }

    /// A new, empty generation (a fresh run, or a compaction): any file of that name is truncated.
    pub fn create(dir: &Path, generation: u64, record_len: usize) -> Result<Self, ReplayError> {
        let path = Self::path(dir, generation);
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(&path)
            .map_err(io(&path))?;
        Ok(ImageLog {
            dir: dir.to_path_buf(),
            generation,
            file,
            records: 0,
            record_len,
        })
    }

    /// The generation a checkpoint names, holding its `committed` records; records beyond them (written by a
    /// checkpoint that did not commit) are cut off.
    pub fn open(
        dir: &Path,
        generation: u64,
        committed: u64,
        record_len: usize,
    ) -> Result<Self, ReplayError> {
        let path = Self::path(dir, generation);
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .open(&path)
            .map_err(io(&path))?;
        let want = committed * record_len as u64;
        let have = file.metadata().map_err(io(&path))?.len();
        if have < want {
            return Err(ReplayError::Log(format!(
                "{}: {have} bytes, the checkpoint needs {want} ({committed} images)",
                path.display()
            )));
        }
        file.set_len(want).map_err(io(&path))?;
        Ok(ImageLog {
            dir: dir.to_path_buf(),
            generation,
            file,
            records: committed,
            record_len,
        })
    }

    /// The folder the log lives in (the run folder).
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    pub fn generation(&self) -> u64 {
        self.generation
    }

    /// Records in the log (live and dead).
    pub fn records(&self) -> u64 {
        self.records
    }

    pub fn record_len(&self) -> usize {
        self.record_len
    }

    /// Whether a log of `live` images should be compacted before the next checkpoint.
    pub fn wants_compaction(&self, live: u64) -> bool {
        self.records > 2 * live + SLACK_RECORDS
    }

    /// Appends one image; returns its record.
    pub fn append(&mut self, image: &[u8]) -> Result<u64, ReplayError> {
        debug_assert_eq!(image.len(), self.record_len);
        let path = Self::path(&self.dir, self.generation);
        let offset = self.records * self.record_len as u64;
        self.file.write_all_at(image, offset).map_err(io(&path))?;
        self.records += 1;
        Ok(self.records - 1)
    }

    /// Makes what was appended durable.
    pub fn sync(&mut self) -> Result<(), ReplayError> {
        let path = Self::path(&self.dir, self.generation);
        self.file.flush().map_err(io(&path))?;
        self.file.sync_data().map_err(io(&path))
    }

    /// Reads record `record` into `out` (one image).
    pub fn read(&self, record: u64, out: &mut [u8]) -> Result<(), ReplayError> {
        if record >= self.records || out.len() != self.record_len {
            return Err(ReplayError::Log(format!(
                "record {record} of {} in generation {}",
                self.records, self.generation
            )));
        }
        let path = Self::path(&self.dir, self.generation);
        self.file
            .read_exact_at(out, record * self.record_len as u64)
            .map_err(io(&path))
    }

    /// Removes every other generation's file (after a checkpoint naming this one has committed).
    pub fn prune(&self) -> Result<(), ReplayError> {
        let entries = std::fs::read_dir(&self.dir).map_err(io(&self.dir))?;
        for entry in entries.flatten() {
            let name = entry.file_name().to_string_lossy().to_string();
            let generation = name
                .strip_prefix("replay-images-")
                .and_then(|n| n.strip_suffix(".log"))
                .and_then(|n| n.parse::<u64>().ok());
            if generation.is_some_and(|g| g != self.generation) {
                let _ = std::fs::remove_file(entry.path());
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_past_the_committed_length_are_cut_off() {
        let tmp = tempfile::tempdir().unwrap();
        let mut log = ImageLog::create(tmp.path(), 0, 4).unwrap();
        for i in 0..3u8 {
            assert_eq!(log.append(&[i; 4]).unwrap(), i as u64);
        }
        log.sync().unwrap();
        // A checkpoint committed two records; the third belongs to one that did not.
        let log = ImageLog::open(tmp.path(), 0, 2, 4).unwrap();
        assert_eq!(log.records(), 2);
        let mut out = [0u8; 4];
        log.read(1, &mut out).unwrap();
        assert_eq!(out, [1; 4]);
        assert!(log.read(2, &mut out).is_err());
        assert!(
            ImageLog::open(tmp.path(), 0, 5, 4).is_err(),
            "shorter than committed"
        );
        let newer = ImageLog::create(tmp.path(), 1, 4).unwrap();
        newer.prune().unwrap();
        assert!(!ImageLog::path(tmp.path(), 0).exists());
        assert!(ImageLog::path(tmp.path(), 1).exists());
    }
}
