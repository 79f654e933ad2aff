//! The replay buffers of Algorithm 1 (algorithm.md 2 and 4).
//!
//! * **D+** (`plus`): steps of completed laps (every state safe, eq. (18)) whose expert answered: the policy's
//!   labels and the critic's positives.
//! * **D?** (`uncertain`): steps of truncated episodes and steps where the expert failed (the reference sends those
//!   straight to D_neg; simulator.md 6). Auto-labelling removes likely-safe ones.
//! * **D-** (`minus`): what D? held right after the last auto-labelling (eq. (19)), a snapshot of its states, held
//!   until the next labelling: the critic's negatives. D? points that arrive after a labelling stay out of D- until
//!   the next one, whatever the schedules (a snapshot rather than indices into D?, which eviction would invalidate).
//! * **dynamics-only**: steps of segments cut by the step budget (never labelled), and the states auto-labelling
//!   removed from D? (still good (x, u, x') samples for f_hat).
//!
//! Each store is a structure of arrays with a fixed capacity (`replay.capacity`); once full, a new step overwrites a
//! uniformly drawn entry (random eviction, seeded). Camera images sit in one contiguous u8 array per store.

use crate::autolabel::AutolabelReport;
use cabc_proto::config::{ObservationKind, RunConfig};
use cabc_proto::messages::{Image, Outcome, Segment, Step, ACTION_DIM, STATE_DIM};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Why the replay could not take a step or be saved or loaded.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error(
        "image of {got_w}x{got_h} ({bytes} bytes) in a buffer of {want_w}x{want_h} RGB images"
    )]
    ImageSize {
        want_w: u16,
        want_h: u16,
        got_w: u16,
        got_h: u16,
        bytes: usize,
    },
    #[error("a step without an image in a buffer of images (or the other way round)")]
    ImagePresence,
    #[error("not a replay file (bad magic)")]
    BadMagic,
    #[error("replay file version {found}, this build reads versions 1 to {expected}")]
    Version { found: u32, expected: u32 },
    #[error("replay file: {0}")]
    Decode(String),
}

/// Images of one size, contiguous: entry i is `bytes[i * len .. (i + 1) * len]`, HWC RGB.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ImageStore {
    pub width: u16,
    pub height: u16,
    pub bytes: Vec<u8>,
}

impl ImageStore {
    /// Bytes of one image.
    pub fn image_len(&self) -> usize {
        self.width as usize * self.height as usize * 3
    }

    pub fn get(&self, i: usize) -> &[u8] {
        let n = self.image_len();
        &self.bytes[i * n..(i + 1) * n]
    }
}

/// One buffer, structure of arrays; entry i of every array belongs to the same step.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Store {
    capacity: usize,
    pub states: Vec<[f32; STATE_DIM]>,
    pub expert_actions: Vec<[f32; ACTION_DIM]>,
    pub applied_actions: Vec<[f32; ACTION_DIM]>,
    pub next_states: Vec<[f32; STATE_DIM]>,
    /// Present once the first step with an image arrives; then every step must carry one of the same size.
    pub images: Option<ImageStore>,
}

impl Store {
    pub fn new(capacity: usize) -> Self {
        Store {
            capacity,
            ..Default::default()
        }
    }

    pub fn len(&self) -> usize {
        self.states.len()
    }

    pub fn is_empty(&self) -> bool {
        self.states.is_empty()
    }

    pub fn capacity(&self) -> usize {
        self.capacity
    }

    fn check_image(&self, image: Option<&Image>) -> Result<(), ReplayError> {
        match (&self.images, image) {
            (None, None) => Ok(()),
            (None, Some(_)) if self.is_empty() => Ok(()),
            (Some(store), Some(img))
                if img.width == store.width
                    && img.height == store.height
                    && img.rgb.len() == store.image_len() =>
            {
                Ok(())
            }
            (Some(store), Some(img)) => Err(ReplayError::ImageSize {
                want_w: store.width,
                want_h: store.height,
                got_w: img.width,
                got_h: img.height,
                bytes: img.rgb.len(),
            }),
            _ => Err(ReplayError::ImagePresence),
        }
    }

    /// Appends, or overwrites a random entry when full.
    #[allow(clippy::too_many_arguments)] // one argument per array of the structure
    fn push(
        &mut self,
        state: [f32; STATE_DIM],
        expert: [f32; ACTION_DIM],
        applied: [f32; ACTION_DIM],
        next: [f32; STATE_DIM],
        image: Option<&[u8]>,
        size: (u16, u16),
        rng: &mut ChaCha8Rng,
    ) {
        if self.images.is_none() && image.is_some() {
            self.images = Some(ImageStore {
                width: size.0,
                height: size.1,
                bytes: Vec::new(),
            });
        }
        if self.len() < self.capacity {
            self.states.push(state);
            self.expert_actions.push(expert);
            self.applied_actions.push(applied);
            self.next_states.push(next);
            if let (Some(store), Some(img)) = (&mut self.images, image) {
                store.bytes.extend_from_slice(img);
            }
        } else {
            let i = rng.gen_range(0..self.capacity);
            self.states[i] = state;
            self.expert_actions[i] = expert;
            self.applied_actions[i] = applied;
            self.next_states[i] = next;
            if let (Some(store), Some(img)) = (&mut self.images, image) {
                let n = img.len();
                store.bytes[i * n..(i + 1) * n].copy_from_slice(img);
            }
        }
    }

    fn push_step(&mut self, step: &Step, rng: &mut ChaCha8Rng) {
        let size = step.image.as_ref().map_or((0, 0), |i| (i.width, i.height));
        self.push(
            step.state,
            step.expert_action,
            step.applied_action,
            step.next_state,
            step.image.as_ref().map(|i| i.rgb.as_slice()),
            size,
            rng,
        );
    }

    /// Moves entry `i` into `to` (keeping the order of the others is not needed: callers remove in one batch).
    fn copy_entry(&self, i: usize, to: &mut Store, rng: &mut ChaCha8Rng) {
        let size = self.images.as_ref().map_or((0, 0), |s| (s.width, s.height));
        self.push_to(i, to, size, rng);
    }

    fn push_to(&self, i: usize, to: &mut Store, size: (u16, u16), rng: &mut ChaCha8Rng) {
        to.push(
            self.states[i],
            self.expert_actions[i],
            self.applied_actions[i],
            self.next_states[i],
            self.images.as_ref().map(|s| s.get(i)),
            size,
            rng,
        );
    }

    /// Keeps the entries where `keep[i]`, in order.
    fn retain(&mut self, keep: &[bool]) {
        let mut j = 0;
        for (i, &k) in keep.iter().enumerate().take(self.len()) {
            if k {
                self.states[j] = self.states[i];
                self.expert_actions[j] = self.expert_actions[i];
                self.applied_actions[j] = self.applied_actions[i];
                self.next_states[j] = self.next_states[i];
                if let Some(store) = &mut self.images {
                    let n = store.image_len();
                    store.bytes.copy_within(i * n..(i + 1) * n, j * n);
                }
                j += 1;
            }
        }
        self.states.truncate(j);
        self.expert_actions.truncate(j);
        self.applied_actions.truncate(j);
        self.next_states.truncate(j);
        if let Some(store) = &mut self.images {
            let n = store.image_len();
            store.bytes.truncate(j * n);
        }
    }
}

/// Counts of what [`Replay::add_segment`] did with a segment's steps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct AddCounts {
    pub plus: usize,
    pub uncertain: usize,
    pub dynamics_only: usize,
}

/// The images a run's steps carry: every segment is held to it before anything of it is stored, so a segment
/// from the bus with images of another size (or none, or unasked-for ones) is refused, not stored.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Frames {
    /// Whatever size the first image has (a replay made without a configuration: tests, tools).
    #[default]
    Any,
    /// A full-state run: no step carries an image.
    None,
    /// A camera run: every step carries a `width` x `height` RGB image (`observation.width/height`).
    Rgb { width: u16, height: u16 },
}

impl Frames {
    /// The images of a run configuration's observation.
    pub fn of(config: &RunConfig) -> Self {
        match config.observation.kind {
            ObservationKind::State => Frames::None,
            ObservationKind::Camera => Frames::Rgb {
                width: config.observation.width,
                height: config.observation.height,
            },
        }
    }

    fn check(self, image: Option<&Image>) -> Result<(), ReplayError> {
        match (self, image) {
            (Frames::Any, _) | (Frames::None, None) => Ok(()),
            (Frames::Rgb { width, height }, Some(i))
                if i.width == width
                    && i.height == height
                    && i.rgb.len() == width as usize * height as usize * 3 =>
            {
                Ok(())
            }
            (Frames::Rgb { width, height }, Some(i)) => Err(ReplayError::ImageSize {
                want_w: width,
                want_h: height,
                got_w: i.width,
                got_h: i.height,
                bytes: i.rgb.len(),
            }),
            _ => Err(ReplayError::ImagePresence),
        }
    }
}

/// D+, D?, D- and the dynamics-only store, with the eviction RNG.
#[derive(Clone, Debug)]
pub struct Replay {
    /// The images every step must carry (not saved: it is the configuration's).
    frames: Frames,
    pub plus: Store,
    pub uncertain: Store,
    pub dynamics_only: Store,
    /// D-: the states of D? right after the last [`Replay::apply_labels`], in D?'s order.
    minus: Vec<[f32; STATE_DIM]>,
    rng: ChaCha8Rng,
    /// Steps ever added to each store (evicted ones included).
    pub added: AddCounts,
}

/// What the bytes hold, besides the magic and the version (version 2: with D-).
#[derive(Serialize, Deserialize)]
struct Saved {
    plus: Store,
    uncertain: Store,
    dynamics_only: Store,
    minus: Vec<[f32; STATE_DIM]>,
    rng_seed: [u8; 32],
    rng_stream: u64,
    rng_word_pos: u128,
    added: AddCounts,
}

/// Version 1, before D- was held: its D- is the whole of its D? (what the learner of then trained the critic on).
#[derive(Deserialize)]
struct SavedV1 {
    plus: Store,
    uncertain: Store,
    dynamics_only: Store,
    rng_seed: [u8; 32],
    rng_stream: u64,
    rng_word_pos: u128,
    added: AddCounts,
}

const MAGIC: &[u8; 8] = b"CABCRPLY";
const VERSION: u32 = 2;

impl Replay {
    /// Empty buffers of `capacity` steps each.
    pub fn new(capacity: usize, seed: u64) -> Self {
        Replay {
            frames: Frames::Any,
            plus: Store::new(capacity),
            uncertain: Store::new(capacity),
            dynamics_only: Store::new(capacity),
            minus: Vec::new(),
            rng: ChaCha8Rng::seed_from_u64(seed),
            added: AddCounts::default(),
        }
    }

    /// Capacity `replay.capacity`, seed derived from `run.seed`, images of `observation` ([`Frames::of`]).
    pub fn from_config(config: &RunConfig) -> Self {
        Replay::new(config.replay.capacity, config.run.seed ^ 0x5245_504c_4159)
            .with_frames(Frames::of(config))
    }

    /// The same replay, holding every segment to `frames`.
    pub fn with_frames(mut self, frames: Frames) -> Self {
        self.frames = frames;
        self
    }

    pub fn len_plus(&self) -> usize {
        self.plus.len()
    }

    pub fn len_uncertain(&self) -> usize {
        self.uncertain.len()
    }

    pub fn len_dynamics_only(&self) -> usize {
        self.dynamics_only.len()
    }

    /// |D-|.
    pub fn len_minus(&self) -> usize {
        self.minus.len()
    }

    /// D-: the states of D? right after the last labelling (empty before the first).
    pub fn minus(&self) -> &[[f32; STATE_DIM]] {
        &self.minus
    }

    /// Partitions a segment by its outcome (algorithm.md 2): Lap -> D+, Failure / ExpertFailure -> D?,
    /// Incomplete -> dynamics-only. A step whose expert failed never becomes a label: it goes to D? whatever the
    /// outcome (the reference's behaviour). The whole segment is checked before anything is stored
    /// ([`Replay::check_segment`]).
    pub fn add_segment(&mut self, segment: &Segment) -> Result<AddCounts, ReplayError> {
        self.check_segment(segment)?;
        let mut counts = AddCounts::default();
        for step in &segment.steps {
            let which = Self::which(segment.outcome, step);
            let store = match which {
                Which::Plus => {
                    counts.plus += 1;
                    &mut self.plus
                }
                Which::Uncertain => {
                    counts.uncertain += 1;
                    &mut self.uncertain
                }
                Which::DynamicsOnly => {
                    counts.dynamics_only += 1;
                    &mut self.dynamics_only
                }
            };
            store.push_step(step, &mut self.rng);
        }
        self.added.plus += counts.plus;
        self.added.uncertain += counts.uncertain;
        self.added.dynamics_only += counts.dynamics_only;
        Ok(counts)
    }

    /// Whether [`Replay::add_segment`] would take `segment`: every image of the run's size ([`Frames`]) and of the
    /// size its store already holds, all of the segment's images alike.
    pub fn check_segment(&self, segment: &Segment) -> Result<(), ReplayError> {
        for step in &segment.steps {
            self.frames.check(step.image.as_ref())?;
            self.store_for(segment.outcome, step)
                .check_image(step.image.as_ref())?;
        }
        // A segment's images must also agree with each other when a store is still empty.
        if let Some(first) = segment.steps.iter().find_map(|s| s.image.as_ref()) {
            for step in &segment.steps {
                match &step.image {
                    Some(i)
                        if i.width == first.width
                            && i.height == first.height
                            && i.rgb.len() == first.rgb.len() => {}
                    Some(i) => {
                        return Err(ReplayError::ImageSize {
                            want_w: first.width,
                            want_h: first.height,
                            got_w: i.width,
                            got_h: i.height,
                            bytes: i.rgb.len(),
                        })
                    }
                    None => return Err(ReplayError::ImagePresence),
                }
            }
        }
        Ok(())
    }

    fn which(outcome: Outcome, step: &Step) -> Which {
        match outcome {
            Outcome::Lap if step.expert_ok => Which::Plus,
            Outcome::Incomplete if step.expert_ok => Which::DynamicsOnly,
            _ => Which::Uncertain,
        }
    }

    fn store_for(&self, outcome: Outcome, step: &Step) -> &Store {
        match Self::which(outcome, step) {
            Which::Plus => &self.plus,
            Which::Uncertain => &self.uncertain,
            Which::DynamicsOnly => &self.dynamics_only,
        }
    }

    /// Applies an auto-labelling pass (eq. (19)), Algorithm 1's "remove x from D?": the D? entries at
    /// `report.removed` (indices into D? as it was labelled) leave D? (as in the reference they are not labelled
    /// safe, but stay available to the dynamics model), and D- becomes what D? then holds, until the next labelling.
    pub fn apply_labels(&mut self, report: &AutolabelReport) {
        let mut keep = vec![true; self.uncertain.len()];
        for &i in &report.removed {
            if i < keep.len() && keep[i] {
                keep[i] = false;
                self.uncertain
                    .copy_entry(i, &mut self.dynamics_only, &mut self.rng);
            }
        }
        self.uncertain.retain(&keep);
        self.minus = self.uncertain.states.clone();
    }

    /// The replay as bytes for the checkpoint: magic, version, bincode.
    pub fn to_bytes(&self) -> Vec<u8> {
        let saved = Saved {
            plus: self.plus.clone(),
            uncertain: self.uncertain.clone(),
            dynamics_only: self.dynamics_only.clone(),
            minus: self.minus.clone(),
            rng_seed: self.rng.get_seed(),
            rng_stream: self.rng.get_stream(),
            rng_word_pos: self.rng.get_word_pos(),
            added: self.added,
        };
        let mut bytes = MAGIC.to_vec();
        bytes.extend_from_slice(&VERSION.to_le_bytes());
        bincode::serde::encode_into_std_write(&saved, &mut bytes, bincode::config::standard())
            .expect("writing into a Vec does not fail");
        bytes
    }

    /// Reads what [`Replay::to_bytes`] wrote (this version or version 1).
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, ReplayError> {
        let body = bytes.strip_prefix(MAGIC).ok_or(ReplayError::BadMagic)?;
        let (version, body) = body
            .split_first_chunk::<4>()
            .ok_or_else(|| ReplayError::Decode("truncated header".into()))?;
        let decode_err = |e: bincode::error::DecodeError| ReplayError::Decode(e.to_string());
        let config = bincode::config::standard();
        let saved: Saved = match u32::from_le_bytes(*version) {
            VERSION => {
                bincode::serde::decode_from_slice(body, config)
                    .map_err(decode_err)?
                    .0
            }
            1 => {
                let v1: SavedV1 = bincode::serde::decode_from_slice(body, config)
                    .map_err(decode_err)?
                    .0;
                Saved {
                    minus: v1.uncertain.states.clone(),
                    plus: v1.plus,
                    uncertain: v1.uncertain,
                    dynamics_only: v1.dynamics_only,
                    rng_seed: v1.rng_seed,
                    rng_stream: v1.rng_stream,
                    rng_word_pos: v1.rng_word_pos,
                    added: v1.added,
                }
            }
            found => {
                return Err(ReplayError::Version {
                    found,
                    expected: VERSION,
                })
            }
        };
        let mut rng = ChaCha8Rng::from_seed(saved.rng_seed);
        rng.set_stream(saved.rng_stream);
        rng.set_word_pos(saved.rng_word_pos);
        Ok(Replay {
            frames: Frames::Any,
            plus: saved.plus,
            uncertain: saved.uncertain,
            dynamics_only: saved.dynamics_only,
            minus: saved.minus,
            rng,
            added: saved.added,
        })
    }
}

#[derive(Clone, Copy)]
enum Which {
    Plus,
    Uncertain,
    DynamicsOnly,
}
