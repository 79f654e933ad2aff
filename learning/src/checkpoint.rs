//! The one checkpoint writer: the trainer, the replay and the learner's state hand it named bytes, and it owns the
//! atomic scheme.
//!
//! A commit writes every file into `checkpoint.tmp/` (each fsynced, then the folder), moves the current
//! `checkpoint/` aside to `checkpoint.old/`, renames `checkpoint.tmp/` to `checkpoint/`, fsyncs the parent and only
//! then deletes `checkpoint.old/`. A crash at any point leaves a complete checkpoint: `checkpoint/`, or, between the
//! two renames, `checkpoint.old/`, which [`Checkpoint::open`] falls back to. Nothing is lost beyond the epoch in flight.
//!
//! The learner's checkpointer of a run folder (`InFolder`, beside the port) writes `checkpoint/` by this scheme.

use crate::replay::ReplayError;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: no checkpoint (nor {path}.old)")]
    Missing { path: PathBuf },
    #[error("checkpoint file name {0:?}: a plain file name is expected")]
    BadName(String),
    /// `doing`: "saving" or "loading".
    #[error("{doing} the replay: {source}")]
    Replay {
        doing: &'static str,
        source: ReplayError,
    },
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> CheckpointError + '_ {
    move |source| CheckpointError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// `dir` with `suffix` appended to its last component (`checkpoint` -> `checkpoint.tmp`).
fn sibling(dir: &Path, suffix: &str) -> PathBuf {
    let mut name = dir.file_name().unwrap_or_default().to_os_string();
    name.push(suffix);
    dir.with_file_name(name)
}

fn sync_dir(dir: &Path) -> Result<(), CheckpointError> {
    File::open(dir).and_then(|d| d.sync_all()).map_err(io(dir))
}

/// Collects the files of one checkpoint, then writes them atomically with [`CheckpointWriter::commit`].
#[derive(Debug)]
pub struct CheckpointWriter {
    dir: PathBuf,
    files: Vec<(String, Vec<u8>)>,
}

impl CheckpointWriter {
    /// A checkpoint that will replace `dir` (e.g. `runs/<run>/checkpoint`).
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        CheckpointWriter {
            dir: dir.into(),
            files: Vec::new(),
        }
    }

    /// Adds one file (a plain name, no folders); a later file of the same name replaces the earlier one.
    pub fn file(&mut self, name: &str, bytes: Vec<u8>) -> &mut Self {
        self.files.retain(|(n, _)| n != name);
        self.files.push((name.to_string(), bytes));
        self
    }

    /// Adds several files, e.g. [`Trainer::to_checkpoint`](crate::Trainer::to_checkpoint).
    pub fn files<N: AsRef<str>>(
        &mut self,
        files: impl IntoIterator<Item = (N, Vec<u8>)>,
    ) -> &mut Self {
        for (name, bytes) in files {
            self.file(name.as_ref(), bytes);
        }
        self
    }

    /// Writes the files and puts them in place of the previous checkpoint (see the module doc). On an error the
    /// previous checkpoint stays.
    pub fn commit(&self) -> Result<(), CheckpointError> {
        for (name, _) in &self.files {
            if name.is_empty() || name.contains(['/', '\\']) || name == "." || name == ".." {
                return Err(CheckpointError::BadName(name.clone()));
            }
        }
        let tmp = sibling(&self.dir, ".tmp");
        let old = sibling(&self.dir, ".old");
        let _ = std::fs::remove_dir_all(&tmp);
        std::fs::create_dir_all(&tmp).map_err(io(&tmp))?;
        for (name, bytes) in &self.files {
            let path = tmp.join(name);
            let mut f = File::create(&path).map_err(io(&path))?;
            f.write_all(bytes).map_err(io(&path))?;
            f.sync_all().map_err(io(&path))?;
        }
        sync_dir(&tmp)?;
        if self.dir.exists() {
            // A complete checkpoint.old/ is only left behind by a crash between the renames, when checkpoint/ is
            // missing; here checkpoint/ exists, so checkpoint.old/ is stale.
            let _ = std::fs::remove_dir_all(&old);
            std::fs::rename(&self.dir, &old).map_err(io(&self.dir))?;
        }
        crate::fault::point("checkpoint-between-renames");
        std::fs::rename(&tmp, &self.dir).map_err(io(&tmp))?;
        if let Some(parent) = self.dir.parent().filter(|p| !p.as_os_str().is_empty()) {
            sync_dir(parent)?;
        }
        let _ = std::fs::remove_dir_all(&old);
        Ok(())
    }
}

/// A checkpoint's parts as read back, by name: a folder's ([`Checkpoint`]) or a checkpointer's in memory.
pub trait Parts {
    /// The bytes of part `name` (an `Io` error of kind `NotFound` when the checkpoint has no such part).
    fn read(&self, name: &str) -> Result<Vec<u8>, CheckpointError>;
    /// Where the parts are (the folder read from), for messages.
    fn path(&self) -> &Path;
}

/// A checkpoint to read: `dir`, or `dir.old` when a crash came between the two renames of a commit.
#[derive(Clone, Debug)]
pub struct Checkpoint {
    dir: PathBuf,
}

impl Checkpoint {
    /// The checkpoint at `dir` (falling back to `dir.old`); `Missing` when neither exists.
    pub fn open(dir: &Path) -> Result<Self, CheckpointError> {
        Self::find(dir).ok_or_else(|| CheckpointError::Missing {
            path: dir.to_path_buf(),
        })
    }

    /// Whether [`Checkpoint::open`] would find one.
    pub fn exists(dir: &Path) -> bool {
        Self::find(dir).is_some()
    }

    fn find(dir: &Path) -> Option<Self> {
        [dir.to_path_buf(), sibling(dir, ".old")]
            .into_iter()
            .find(|d| d.is_dir())
            .map(|dir| Checkpoint { dir })
    }

    /// The folder read from.
    pub fn path(&self) -> &Path {
        &self.dir
    }

    /// The bytes of one file.
    pub fn read(&self, name: &str) -> Result<Vec<u8>, CheckpointError> {
        let path = self.dir.join(name);
        std::fs::read(&path).map_err(io(&path))
    }

    /// Removes `dir` and what a commit leaves beside it (`.tmp`, `.old`).
    pub fn remove(dir: &Path) -> Result<(), CheckpointError> {
        for d in [
            dir.to_path_buf(),
            sibling(dir, ".tmp"),
            sibling(dir, ".old"),
        ] {
            if d.exists() {
                std::fs::remove_dir_all(&d).map_err(io(&d))?;
            }
        }
        Ok(())
    }
}

impl Parts for Checkpoint {
    fn read(&self, name: &str) -> Result<Vec<u8>, CheckpointError> {
        Checkpoint::read(self, name)
    }

    fn path(&self) -> &Path {
        Checkpoint::path(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn commit_replaces_and_a_crash_between_renames_falls_back_to_old() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("checkpoint");
        assert!(!Checkpoint::exists(&dir));
        CheckpointWriter::new(&dir)
            .file("a", b"1".to_vec())
            .file("b", b"x".to_vec())
            .commit()
            .unwrap();
        CheckpointWriter::new(&dir)
            .files([("a", b"2".to_vec())])
            .commit()
            .unwrap();
        let ck = Checkpoint::open(&dir).unwrap();
        assert_eq!(ck.read("a").unwrap(), b"2");
        assert!(ck.read("b").is_err(), "a commit replaces the whole folder");
        assert!(!sibling(&dir, ".old").exists() && !sibling(&dir, ".tmp").exists());
        // A crash after checkpoint/ moved aside and before checkpoint.tmp/ took its place.
        std::fs::rename(&dir, sibling(&dir, ".old")).unwrap();
        let ck = Checkpoint::open(&dir).unwrap();
        assert_eq!(ck.path(), sibling(&dir, ".old"));
        assert_eq!(ck.read("a").unwrap(), b"2");
        // The next commit puts checkpoint/ back and drops the old one.
        CheckpointWriter::new(&dir)
            .file("a", b"3".to_vec())
            .commit()
            .unwrap();
        assert_eq!(Checkpoint::open(&dir).unwrap().path(), dir);
        assert!(!sibling(&dir, ".old").exists());
        assert!(CheckpointWriter::new(&dir)
            .file("../x", vec![])
            .commit()
            .is_err());
        assert_eq!(Checkpoint::open(&dir).unwrap().read("a").unwrap(), b"3");
        Checkpoint::remove(&dir).unwrap();
        assert!(matches!(
            Checkpoint::open(&dir),
            Err(CheckpointError::Missing { .. })
        ));
    }
}
