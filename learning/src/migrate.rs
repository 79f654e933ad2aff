//! The readers of old checkpoint formats, in one place: what a checkpoint written by an earlier cabc holds, read into
//! today's types, so that old run folders resume and old results load (`outputs/tests/records.rs` resumes one of
//! 2f28af3). The current types' modules know only the current format; a format that changes gets its reader here.
//!
//! * `replay.bin`: [`Saved::decode`] reads every version (1: before D- was held, its D- is the whole of its D?; 2:
//!   images inline in every store; 3: the current one, D+'s images in the image log);
//! * `state.json`'s rows: [`rows`] reads the records, and the rows of checkpoints up to 2f28af3, objects of
//!   `EpochRow`'s fields, through [`LEGACY`]'s frozen columns.
//!
//! The trainer's files need no reader here: an optimiser state missing from an older checkpoint restarts its
//! moments (`train/state.rs`).

use crate::record::{Legacy, Record, Value, LEGACY};
use crate::replay::{AddCounts, ImageStore, ReplayError, Saved, Store, MAGIC, NOT_LOGGED, VERSION};
use cabc_proto::messages::{ACTION_DIM, STATE_DIM};
use serde::de::Error as _;
use serde::{Deserialize, Deserializer};

/// `state.json`'s `rows`: each a record (a list of entries), or an old checkpoint's object of `EpochRow`'s fields.
pub(crate) fn rows<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<Record>, D::Error> {
    Vec::<serde_json::Value>::deserialize(d)?
        .into_iter()
        .map(|row| match row {
            serde_json::Value::Object(row) => legacy_row(&row).map_err(D::Error::custom),
            entries => serde_json::from_value(entries).map_err(D::Error::custom),
        })
        .collect()
}

/// A row of an old checkpoint (an object of `EpochRow`'s fields), through [`LEGACY`].
fn legacy_row(row: &serde_json::Map<String, serde_json::Value>) -> Result<Record, String> {
    let mut record = Record::default();
    for (name, kind) in LEGACY {
        let field = row.get(name).filter(|v| !v.is_null());
        let count = |v: &serde_json::Value| v.as_u64().ok_or(format!("{name}: {v} is not a count"));
        // serde_json writes a NaN as null: read back as NaN.
        let real = |v: Option<&serde_json::Value>| match v {
            None => Ok(f64::NAN),
            Some(v) => v.as_f64().ok_or(format!("{name}: {v} is not a number")),
        };
        let value = match kind {
            Legacy::Count => Value::Count(field.map_or(Ok(0), count)?),
            Legacy::OptCount => match field {
                Some(v) => Value::Count(count(v)?),
                None => continue,
            },
            Legacy::Real(decimals) => Value::Real(
                if row.contains_key(name) {
                    real(field)?
                } else {
                    0.0
                },
                Some(decimals),
            ),
            Legacy::Exact => Value::Real(
                if row.contains_key(name) {
                    real(field)?
                } else {
                    0.0
                },
                None,
            ),
            Legacy::OptReal(decimals) => match field {
                Some(v) => Value::Real(real(Some(v))?, Some(decimals)),
                None => continue,
            },
            Legacy::Flag => match field {
                Some(v) => Value::Flag(v.as_bool().ok_or(format!("{name}: {v} is not a flag"))?),
                None => Value::Flag(false),
            },
            Legacy::IncompleteShare => {
                let steps = |n| record.u64(n).unwrap_or(0);
                let share =
                    steps("incomplete_steps") as f64 / steps("steps_collected").max(1) as f64;
                Value::Real(share, Some(4))
            }
        };
        record.put(name, value);
    }
    Ok(record)
}

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
                    bytes.len() / (width as usize * height as usize * 3).max(1)
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
