//! The replay on disk: `replay.bin` (magic, version, bincode of the stores, D-, the eviction RNG and the counts),
//! with D+'s (and D?'s) images in the run's image log ([`ImageLog`]). This module writes and reads the current
//! version; `super::migrate` reads the older ones into it.

use super::AddCounts;
use super::{store, Frames, Fresh, ImageLog, ImageStore, Replay, ReplayError, Store};
use cabc_proto::messages::STATE_DIM;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Where D+'s images are in the run's image log (version 3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub(crate) struct LogRef {
    pub(super) generation: u64,
    /// Records the log holds at this checkpoint (later ones are cut off on resume).
    pub(super) records: u64,
    pub(super) record_len: usize,
}

/// What the bytes hold, besides the magic and the version (version 3: images in the log, not in the file).
#[derive(Serialize)]
struct SavedRef<'a> {
    plus: &'a Store,
    uncertain: &'a Store,
    dynamics_only: &'a Store,
    minus: &'a [[f32; STATE_DIM]],
    rng_seed: [u8; 32],
    rng_stream: u64,
    rng_word_pos: u128,
    added: AddCounts,
    image_log: Option<LogRef>,
}

/// The replay as the current version reads back (every version is decoded by `super::migrate`, `Saved::decode`).
#[derive(Deserialize)]
pub(crate) struct Saved {
    pub(crate) plus: Store,
    pub(crate) uncertain: Store,
    pub(crate) dynamics_only: Store,
    pub(crate) minus: Vec<[f32; STATE_DIM]>,
    pub(crate) rng_seed: [u8; 32],
    pub(crate) rng_stream: u64,
    pub(crate) rng_word_pos: u128,
    pub(crate) added: AddCounts,
    pub(crate) image_log: Option<LogRef>,
}

pub(crate) const MAGIC: &[u8; 8] = b"CABCRPLY";
pub(crate) const VERSION: u32 = 3;

impl Replay {
    /// The replay as bytes for the checkpoint (magic, version, bincode), after appending the images written since
    /// the last checkpoint (D+'s, then D?'s when it keeps them) to the image log in `dir` (`log`: the one open,
    /// created on the first images; compacted into a new generation first when mostly dead; see [`ImageLog`]).
    /// Nothing of the replay is copied.
    pub fn checkpoint_bytes(
        &mut self,
        dir: &Path,
        log: &mut Option<ImageLog>,
    ) -> Result<Vec<u8>, ReplayError> {
        let mut stores: Vec<&mut ImageStore> =
            [self.plus.images.as_mut(), self.uncertain.images.as_mut()]
                .into_iter()
                .flatten()
                .collect();
        let image_log = match stores.first().map(|s| s.image_len()) {
            None => None,
            Some(len) => {
                if stores.iter().any(|s| s.image_len() != len) {
                    return Err(ReplayError::Log(
                        "D+ and D? hold images of different sizes".into(),
                    ));
                }
                if log.is_none() {
                    *log = Some(ImageLog::create(dir, 0, len)?);
                }
                let log = log.as_mut().expect("set above");
                let live: u64 = stores.iter().map(|s| s.records.len() as u64).sum();
                let compact = log.wants_compaction(live);
                if compact {
                    let dir = log.dir().to_path_buf();
                    *log = ImageLog::create(&dir, log.generation() + 1, len)?;
                }
                for images in &mut stores {
                    for (i, record) in images.records.iter_mut().enumerate() {
                        if compact || *record == store::NOT_LOGGED {
                            *record = log.append(&images.bytes[i * len..(i + 1) * len])?;
                        }
                    }
                }
                log.sync()?;
                Some(LogRef {
                    generation: log.generation(),
                    records: log.records(),
                    record_len: len,
                })
            }
        };
        let saved = SavedRef {
            plus: &self.plus,
            uncertain: &self.uncertain,
            dynamics_only: &self.dynamics_only,
            minus: &self.minus,
            rng_seed: self.rng.get_seed(),
            rng_stream: self.rng.get_stream(),
            rng_word_pos: self.rng.get_word_pos(),
            added: self.added,
            image_log,
        };
        let mut bytes = MAGIC.to_vec();
        bytes.extend_from_slice(&VERSION.to_le_bytes());
        bincode::serde::encode_into_std_write(&saved, &mut bytes, bincode::config::standard())
            .expect("writing into a Vec does not fail");
        Ok(bytes)
    }

    /// The bytes of a replay without images (tests, tools); see [`Replay::checkpoint_bytes`].
    pub fn to_bytes(&mut self) -> Result<Vec<u8>, ReplayError> {
        if self.plus.images.is_some() || self.uncertain.images.is_some() {
            return Err(ReplayError::Log(
                "the replay holds images: use checkpoint_bytes with a folder".into(),
            ));
        }
        self.checkpoint_bytes(Path::new("."), &mut None)
    }

    /// Reads what [`Replay::checkpoint_bytes`] wrote (or versions 1 and 2), with D+'s (and D?'s) images from the
    /// image log in `dir` (the run folder); returns the log to go on appending to.
    pub fn from_checkpoint(
        bytes: &[u8],
        dir: &Path,
    ) -> Result<(Self, Option<ImageLog>), ReplayError> {
        let mut saved = Saved::decode(bytes)?;
        for (name, store) in [("D+", &saved.plus), ("D?", &saved.uncertain)] {
            if store
                .images
                .as_ref()
                .is_some_and(|i| i.records.len() != store.len())
            {
                return Err(ReplayError::Decode(format!(
                    "{name} slots and image records differ"
                )));
            }
        }
        let plus_empty = saved.plus.is_empty();
        let mut stores: Vec<&mut ImageStore> =
            [saved.plus.images.as_mut(), saved.uncertain.images.as_mut()]
                .into_iter()
                .flatten()
                .collect();
        let log = match saved.image_log {
            Some(_) if stores.is_empty() && plus_empty => None,
            Some(_) if stores.is_empty() => {
                return Err(ReplayError::Decode(
                    "an image log for D+ without images".into(),
                ))
            }
            Some(at) => {
                let log = ImageLog::open(dir, at.generation, at.records, at.record_len)?;
                for images in &mut stores {
                    if images.image_len() != at.record_len {
                        return Err(ReplayError::Log(format!(
                            "records of {} bytes for {}x{} images",
                            at.record_len, images.width, images.height
                        )));
                    }
                    images.bytes = vec![0; images.records.len() * at.record_len];
                    for (i, &record) in images.records.iter().enumerate() {
                        log.read(
                            record,
                            &mut images.bytes[i * at.record_len..(i + 1) * at.record_len],
                        )?;
                    }
                }
                Some(log)
            }
            None if stores
                .iter()
                .any(|i| i.records.iter().any(|&r| r != store::NOT_LOGGED)) =>
            {
                return Err(ReplayError::Decode("images without an image log".into()))
            }
            // Versions 1 and 2: D+'s images came inline; they go to a new log at the next checkpoint.
            None => None,
        };
        let mut rng = ChaCha8Rng::from_seed(saved.rng_seed);
        rng.set_stream(saved.rng_stream);
        rng.set_word_pos(saved.rng_word_pos);
        let mut replay = Replay {
            frames: Frames::Any,
            plus: saved.plus,
            uncertain: saved.uncertain,
            dynamics_only: saved.dynamics_only,
            minus: saved.minus,
            rng,
            added: saved.added,
            keep_dynamics_only: true,
            fresh: Fresh::default(),
        };
        // Nothing fresh after a resume: the held-out rows of the last D_new are not known any more.
        replay.begin_epoch();
        Ok((replay, log))
    }

    /// [`Replay::from_checkpoint`] for a replay without images in a log (no log is opened).
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, ReplayError> {
        let (replay, _) = Self::from_checkpoint(bytes, Path::new("/nonexistent"))?;
        Ok(replay)
    }
}
