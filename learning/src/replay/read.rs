//! A replay read back without changing its run folder (every version of `replay.bin` is decoded by `migrate`):
//! [`ReplaySnapshot`], the stores as a checkpoint left them with D+'s images left on disk, read one at a time
//! ([`Images`]) by tools that stream a run's data out (`cabc export`). [`Replay::from_checkpoint`] instead loads
//! every image and opens the log for appending, cutting off records of a checkpoint that did not commit: right for
//! the learner that resumes, wrong for a reader beside a live run.

use super::{store, AddCounts, ImageLog, ReplayError, Saved, Store, STATE_DIM};
use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::Path;

/// D+'s images of a snapshot: in the run's image log (version 3), or inline (versions 1 and 2).
#[derive(Debug)]
enum Images {
    Log {
        file: File,
        path: std::path::PathBuf,
        record_len: usize,
        /// Records the checkpoint committed (the log may hold more, from one that did not).
        records: u64,
    },
    Inline,
}

/// The stores of a checkpoint, read-only, with D+'s images where they are (read with [`ReplaySnapshot::plus_image`]).
#[derive(Debug)]
pub struct ReplaySnapshot {
    pub plus: Store,
    pub uncertain: Store,
    pub dynamics_only: Store,
    /// D-: the states of D? right after the last labelling.
    pub minus: Vec<[f32; STATE_DIM]>,
    /// Steps ever added to each store (evicted ones included).
    pub added: AddCounts,
    images: Images,
}

impl ReplaySnapshot {
    /// The replay in `bytes` (a checkpoint's `replay.bin`) of the run folder `dir`; the image log is opened for
    /// reading only, and checked to hold what the checkpoint committed.
    pub fn read(bytes: &[u8], dir: &Path) -> Result<Self, ReplayError> {
        let saved = Saved::decode(bytes)?;
        let images = match (saved.image_log, &saved.plus.images) {
            (Some(at), Some(images)) => {
                if images.image_len() != at.record_len {
                    return Err(ReplayError::Log(format!(
                        "records of {} bytes for {}x{} images",
                        at.record_len, images.width, images.height
                    )));
                }
                for (name, store) in [
                    ("D+", Some(images)),
                    ("D?", saved.uncertain.images.as_ref()),
                ] {
                    let Some(store) = store else { continue };
                    if let Some(&r) = store.records.iter().find(|&&r| r >= at.records) {
                        return Err(ReplayError::Log(format!(
                            "a {name} slot names record {r} of a log of {} committed records",
                            at.records
                        )));
                    }
                }
                let path = ImageLog::path(dir, at.generation);
                let io = |e: std::io::Error| ReplayError::Log(format!("{}: {e}", path.display()));
                let file = File::open(&path).map_err(io)?;
                let have = file.metadata().map_err(io)?.len();
                let want = at.records.saturating_mul(at.record_len as u64);
                if have < want {
                    return Err(ReplayError::Log(format!(
                        "{}: {have} bytes, the checkpoint needs {want} ({} images)",
                        path.display(),
                        at.records
                    )));
                }
                Images::Log {
                    file,
                    path,
                    record_len: at.record_len,
                    records: at.records,
                }
            }
            (None, Some(images)) if images.records.iter().any(|&r| r != store::NOT_LOGGED) => {
                return Err(ReplayError::Decode("D+ images without an image log".into()))
            }
            _ => Images::Inline,
        };
        let plus = &saved.plus;
        let slots = plus.images.as_ref().map_or(plus.len(), |i| i.records.len());
        let inline_ok = plus.images.as_ref().is_none_or(|i| {
            matches!(images, Images::Log { .. }) || i.bytes.len() == slots * i.image_len()
        });
        if slots != plus.len() || !inline_ok {
            return Err(ReplayError::Decode(
                "D+ slots and image records differ".into(),
            ));
        }
        for (name, s) in [
            ("D+", &saved.plus),
            ("D?", &saved.uncertain),
            ("dynamics-only", &saved.dynamics_only),
        ] {
            let n = s.len();
            if s.expert_actions.len() != n
                || s.applied_actions.len() != n
                || s.next_states.len() != n
            {
                return Err(ReplayError::Decode(format!(
                    "{name}: arrays of different lengths"
                )));
            }
        }
        Ok(ReplaySnapshot {
            plus: saved.plus,
            uncertain: saved.uncertain,
            dynamics_only: saved.dynamics_only,
            minus: saved.minus,
            added: saved.added,
            images,
        })
    }

    /// D+'s image size (width, height), if it holds images.
    pub fn image_size(&self) -> Option<(u16, u16)> {
        self.plus.images.as_ref().map(|i| (i.width, i.height))
    }

    /// D+'s image at `slot` into `out` (width x height x 3 bytes, HWC RGB).
    pub fn plus_image(&self, slot: usize, out: &mut [u8]) -> Result<(), ReplayError> {
        let Some(store) = &self.plus.images else {
            return Err(ReplayError::ImagePresence);
        };
        let len = store.image_len();
        if slot >= store.records.len() || out.len() != len {
            return Err(ReplayError::Log(format!(
                "image slot {slot} of {} ({} bytes asked, {len} held)",
                store.records.len(),
                out.len()
            )));
        }
        match &self.images {
            Images::Inline => {
                out.copy_from_slice(&store.bytes[slot * len..(slot + 1) * len]);
                Ok(())
            }
            Images::Log {
                file,
                path,
                record_len,
                records,
            } => {
                let record = store.records[slot];
                if record >= *records {
                    return Err(ReplayError::Log(format!(
                        "record {record} of {records} committed"
                    )));
                }
                file.read_exact_at(out, record * *record_len as u64)
                    .map_err(|e| ReplayError::Log(format!("{}: {e}", path.display())))
            }
        }
    }
}
