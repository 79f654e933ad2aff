//! The readers of `replay.bin`'s older versions, into today's [`Saved`] (1: before D- was held, its D- is the whole
//! of its D?; 2: images inline in every store; 3, the current one, is `super::persist`'s), so that old run folders
//! resume and old results load. A format that changes gets its reader here; `super::persist` knows only the current
//! one. (The records of `state.json` have theirs beside them, `crate::record::rows`; the trainer's files need none: an
//! optimiser state missing from an older checkpoint restarts its moments, `train/state.rs`.)

use super::{AddCounts, ImageStore, ReplayError, Saved, Store, MAGIC, NOT_LOGGED, VERSION};
use cabc_proto::messages::{image_bytes, ACTION_DIM, STATE_DIM};
use serde::Deserialize;

impl Saved {
    /// The saved replay in `bytes` (magic, version, bincode; versions 1 and 2 upgraded), images not read.
    pub(crate) fn decode(bytes: &[u8]) -> Result<Saved, ReplayError> {
        let body = bytes.strip_prefix(MAGIC).ok_or(ReplayError::BadMagic)?;
        let (version, body) = body
            .split_first_chunk::<4>()
            .ok_or_else(|| ReplayError::Decode("truncated header".into()))?;
        let decode_err = |e: bincode::error::DecodeError| ReplayError::Decode(e.to_string());
        let config = bincode::config::standard();
        let saved = match u32::from_le_bytes(*version) {
            VERSION => {
                bincode::serde::decode_from_slice(body, config)
                    .map_err(decode_err)?
                    .0
            }
            2 => {
                let v2: SavedV2 = bincode::serde::decode_from_slice(body, config)
                    .map_err(decode_err)?
                    .0;
                Saved {
                    plus: v2.plus.upgrade(true),
                    uncertain: v2.uncertain.upgrade(false),
                    dynamics_only: v2.dynamics_only.upgrade(false),
                    minus: v2.minus,
                    rng_seed: v2.rng_seed,
                    rng_stream: v2.rng_stream,
                    rng_word_pos: v2.rng_word_pos,
                    added: v2.added,
                    image_log: None,
                }
            }
            1 => {
                let v1: SavedV1 = bincode::serde::decode_from_slice(body, config)
                    .map_err(decode_err)?
                    .0;
                Saved {
                    minus: v1.uncertain.states.clone(),
                    plus: v1.plus.upgrade(true),
                    uncertain: v1.uncertain.upgrade(false),
                    dynamics_only: v1.dynamics_only.upgrade(false),
                    rng_seed: v1.rng_seed,
                    rng_stream: v1.rng_stream,
                    rng_word_pos: v1.rng_word_pos,
                    added: v1.added,
                    image_log: None,
                }
            }
            found => {
                return Err(ReplayError::Version {
                    found,
                    expected: VERSION,
                })
            }
        };
        Ok(saved)
    }
}

/// A store as versions 1 and 2 saved it: images inline, in every store.
#[derive(Deserialize)]
struct LegacyStore {
    capacity: usize,
    states: Vec<[f32; STATE_DIM]>,
    expert_actions: Vec<[f32; ACTION_DIM]>,
    applied_actions: Vec<[f32; ACTION_DIM]>,
    next_states: Vec<[f32; STATE_DIM]>,
    images: Option<(u16, u16, Vec<u8>)>,
}

impl LegacyStore {
    /// The store of this version; D+ keeps its images (to be logged at the next checkpoint), the others drop them.
    fn upgrade(self, keeps_images: bool) -> Store {
        let mut store = Store::new(self.capacity, keeps_images);
        store.states = self.states;
        store.expert_actions = self.expert_actions;
        store.applied_actions = self.applied_actions;
        store.next_states = self.next_states;
        store.images = self
            .images
            .filter(|_| keeps_images)
            .map(|(width, height, bytes)| ImageStore {
                width,
                height,
                records: vec![
                    NOT_LOGGED;
                    bytes.len() / image_bytes(width.into(), height.into()).max(1)
                ],
                bytes,
            });
        store
    }
}

/// Version 2: D- held, images inline.
#[derive(Deserialize)]
struct SavedV2 {
    plus: LegacyStore,
    uncertain: LegacyStore,
    dynamics_only: LegacyStore,
    minus: Vec<[f32; STATE_DIM]>,
    rng_seed: [u8; 32],
    rng_stream: u64,
    rng_word_pos: u128,
    added: AddCounts,
}

/// Version 1, before D- was held: its D- is the whole of its D? (what the learner of then trained the critic on).
#[derive(Deserialize)]
struct SavedV1 {
    plus: LegacyStore,
    uncertain: LegacyStore,
    dynamics_only: LegacyStore,
    rng_seed: [u8; 32],
    rng_stream: u64,
    rng_word_pos: u128,
    added: AddCounts,
}
