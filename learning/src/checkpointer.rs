//! The port the learner keeps its checkpoint through ([`Checkpointer`]), as it writes its outputs through a
//! [`crate::sink::Sink`] (Acme injects both): save a checkpoint's parts, load the latest. The run folder's is
//! [`InFolder`] (`checkpoint/`, written atomically, and D+'s image log beside it); [`InMemory`]
//! keeps them in memory, for tests.

use crate::checkpoint::{Checkpoint, CheckpointError, CheckpointWriter, Parts};
use crate::replay::{ImageLog, Replay};
use crate::state::CHECKPOINT;
use std::cell::RefCell;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::rc::Rc;

/// A checkpoint's parts besides the replay, by name: the trainer's files and the learner state's.
pub type Files = Vec<(&'static str, Vec<u8>)>;

/// Where the learner keeps its checkpoint: one whole checkpoint at any moment, the previous one until the next is
/// saved whole. Displays as where it keeps it (the run folder), for messages.
pub trait Checkpointer: std::fmt::Display {
    /// Whether there is a checkpoint to [`Checkpointer::load`].
    fn exists(&self) -> bool;
    /// The latest checkpoint: its parts and its replay.
    fn load(&mut self) -> Result<(Box<dyn Parts>, Replay), CheckpointError>;
    /// Saves `files` and `replay` as the latest checkpoint; on an error the previous one stays.
    fn save(&mut self, files: Files, replay: &mut Replay) -> Result<(), CheckpointError>;
}

/// Checkpoints in memory (tests). Clones share them: a learner made with a clone after another was dropped resumes
/// from what that one saved. A replay with images is refused (a run folder keeps them in its image log).
#[derive(Clone, Default)]
pub struct InMemory(Rc<RefCell<Option<Kept>>>);

/// The checkpoint an [`InMemory`] holds.
#[derive(Clone)]
struct Kept {
    files: BTreeMap<&'static str, Vec<u8>>,
    replay: Vec<u8>,
}

/// Where an [`InMemory`]'s parts are, in messages.
const MEMORY: &str = "memory";

impl Parts for Kept {
    fn read(&self, name: &str) -> Result<Vec<u8>, CheckpointError> {
        self.files
            .get(name)
            .cloned()
            .ok_or_else(|| CheckpointError::Io {
                path: Path::new(MEMORY).join(name),
                source: std::io::ErrorKind::NotFound.into(),
            })
    }

    fn path(&self) -> &Path {
        Path::new(MEMORY)
    }
}

impl std::fmt::Display for InMemory {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(MEMORY)
    }
}

impl Checkpointer for InMemory {
    fn exists(&self) -> bool {
        self.0.borrow().is_some()
    }

    fn load(&mut self) -> Result<(Box<dyn Parts>, Replay), CheckpointError> {
        let kept = self.0.borrow().clone().ok_or(CheckpointError::Missing {
            path: PathBuf::from(MEMORY),
        })?;
        let replay =
            Replay::from_bytes(&kept.replay).map_err(|source| CheckpointError::Replay {
                doing: "loading",
                source,
            })?;
        Ok((Box::new(kept), replay))
    }

    fn save(&mut self, files: Files, replay: &mut Replay) -> Result<(), CheckpointError> {
        let replay = replay
            .to_bytes()
            .map_err(|source| CheckpointError::Replay {
                doing: "saving",
                source,
            })?;
        let files = files.into_iter().collect();
        *self.0.borrow_mut() = Some(Kept { files, replay });
        Ok(())
    }
}

/// The replay's part of a checkpoint.
const REPLAY: &str = "replay.bin";

/// The learner's checkpoint in a run folder: `folder/checkpoint` (written atomically, [`CheckpointWriter`]; read
/// back from `checkpoint.old/` after a crash between its renames, [`Checkpoint::open`]) with the replay as
/// `replay.bin`, and D+'s images in `folder/replay-images-<generation>.log` ([`ImageLog`]), appended to at each
/// checkpoint.
pub struct InFolder {
    folder: PathBuf,
    /// The image log open for appending: the one the loaded checkpoint names, or the one the first images made.
    image_log: Option<ImageLog>,
}

impl InFolder {
    /// The checkpoint of the run folder `folder`.
    pub fn new(folder: PathBuf) -> Self {
        InFolder {
            folder,
            image_log: None,
        }
    }
}

impl std::fmt::Display for InFolder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.folder.display())
    }
}

impl Checkpointer for InFolder {
    fn exists(&self) -> bool {
        Checkpoint::exists(&self.folder.join(CHECKPOINT))
    }

    fn load(&mut self) -> Result<(Box<dyn Parts>, Replay), CheckpointError> {
        let checkpoint = Checkpoint::open(&self.folder.join(CHECKPOINT))?;
        let bytes = checkpoint.read(REPLAY)?;
        let (replay, log) = Replay::from_checkpoint(&bytes, &self.folder).map_err(|source| {
            CheckpointError::Replay {
                doing: "loading",
                source,
            }
        })?;
        self.image_log = log;
        Ok((Box::new(checkpoint), replay))
    }

    /// D+'s images go to the image log first (only those new since the last checkpoint); a generation the
    /// committed checkpoint no longer names is removed after the commit.
    fn save(&mut self, files: Files, replay: &mut Replay) -> Result<(), CheckpointError> {
        let bytes = replay
            .checkpoint_bytes(&self.folder, &mut self.image_log)
            .map_err(|source| CheckpointError::Replay {
                doing: "saving",
                source,
            })?;
        CheckpointWriter::new(self.folder.join(CHECKPOINT))
            .files(files)
            .file(REPLAY, bytes)
            .commit()?;
        if let Some(log) = &self.image_log {
            if let Err(e) = log.prune() {
                tracing::warn!("removing an old image log: {e}");
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cabc_proto::messages::Outcome;

    #[test]
    fn a_clone_loads_what_was_saved_last() {
        let mut saving = InMemory::default();
        let mut loading = saving.clone();
        assert!(!loading.exists());
        assert!(matches!(
            loading.load(),
            Err(CheckpointError::Missing { .. })
        ));
        let mut replay = Replay::new(10, 1);
        let step = cabc_fixtures::step_ahead(None);
        let lap = cabc_fixtures::segment("actor-0", 0, Outcome::Lap, vec![step]);
        replay.add_segment(&lap).unwrap();
        saving
            .save(vec![("a", b"1".to_vec())], &mut replay)
            .unwrap();
        saving
            .save(vec![("a", b"2".to_vec())], &mut replay)
            .unwrap();
        let (parts, back) = loading.load().unwrap();
        assert_eq!(parts.read("a").unwrap(), b"2");
        assert_eq!(back.len_plus(), 1);
        let missing = parts.read("b").unwrap_err();
        assert!(
            matches!(&missing, CheckpointError::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound),
            "{missing}"
        );
    }
}
