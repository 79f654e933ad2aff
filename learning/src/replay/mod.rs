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
//! uniformly drawn entry (random eviction, seeded). Camera images sit in one contiguous u8 array per store: D+'s
//! always, D?'s when a camera policy clones D? too (`training.clone_uncertain`); both go to the same image log.

mod log;
mod migrate;
mod persist;
mod read;
mod store;

pub use log::ImageLog;
pub(crate) use persist::{Saved, MAGIC, VERSION};
pub use read::ReplaySnapshot;
pub(crate) use store::NOT_LOGGED;
pub use store::{ImageStore, Store, STEP_BYTES};

use cabc_proto::config::{ObservationKind, RunConfig};
use cabc_proto::messages::{image_bytes, Image, Outcome, Segment, Step, STATE_DIM};
use rand::SeedableRng;
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
    #[error("image log: {0}")]
    Log(String),
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

    /// The images of `image`, as a step carries them: its size, or none.
    fn of_image(image: Option<&Image>) -> Self {
        image.map_or(Frames::None, |i| Frames::Rgb {
            width: i.width,
            height: i.height,
        })
    }

    /// The one check of an image against the run's size: `width` x `height` and exactly that many RGB bytes (the
    /// codec leaves the bytes' count to this check), or no image in a full-state run. Everything behind it (the
    /// stores, their image arrays, the log) takes an image's size as given.
    fn check(self, image: Option<&Image>) -> Result<(), ReplayError> {
        match (self, image) {
            (Frames::Any, _) | (Frames::None, None) => Ok(()),
            (Frames::Rgb { width, height }, Some(i))
                if i.width == width
                    && i.height == height
                    && i.rgb.len() == image_bytes(width.into(), height.into()) =>
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
    /// `replay.dynamics_only` (not saved: it is the configuration's): whether unfinished laps and the points
    /// auto-labelling removes are kept for f_hat, or dropped (the reference).
    keep_dynamics_only: bool,
    /// Where the last D_new's rows begin ([`Replay::begin_epoch`]; not saved: after a resume nothing is fresh).
    fresh: Fresh,
}

/// The stores at the start of an epoch, to find the rows D_new adds ([`Replay::fresh_plus`],
/// [`Replay::fresh_uncertain`]): the rows the critic has not trained on yet, its held-out set.
#[derive(Clone, Copy, Debug, Default)]
struct Fresh {
    /// D+'s length and its steps ever added.
    plus: (usize, usize),
    /// D?'s, likewise.
    uncertain: (usize, usize),
    /// D?'s first row from this epoch after this epoch's labelling, once it labelled.
    labelled_from: Option<usize>,
}

/// The first row a store gained since `(len, added)`, when it gained them at its end (no eviction since).
fn appended_from(then: (usize, usize), len: usize, added: usize) -> Option<usize> {
    (len.checked_sub(then.0) == added.checked_sub(then.1)).then_some(then.0)
}

/// A segment the replay has checked ([`Replay::checked`]): it is stored whole by [`Replay::add_checked`].
#[derive(Debug)]
pub struct Checked(Segment);

impl Checked {
    pub fn segment(&self) -> &Segment {
        &self.0
    }
}

impl Replay {
    /// Empty buffers of `capacity` steps each.
    pub fn new(capacity: usize, seed: u64) -> Self {
        Self::with_capacities(capacity, capacity, seed)
    }

    /// Empty buffers: D+ of `plus` steps, the others of `capacity` steps. Only D+ keeps images (only the policy's
    /// training reads them), unless [`Replay::with_uncertain_images`].
    pub fn with_capacities(plus: usize, capacity: usize, seed: u64) -> Self {
        Replay {
            frames: Frames::Any,
            plus: Store::new(plus, true),
            uncertain: Store::new(capacity, false),
            dynamics_only: Store::new(capacity, false),
            minus: Vec::new(),
            rng: ChaCha8Rng::seed_from_u64(seed),
            added: AddCounts::default(),
            keep_dynamics_only: true,
            fresh: Fresh::default(),
        }
    }

    /// Capacity `replay.capacity` (D+: within `replay.max_bytes`, [`RunConfig::plus_capacity`]), seed derived
    /// from `run.seed`, images of `observation` ([`Frames::of`]), D?'s too where the policy reads them
    /// ([`RunConfig::uncertain_images`]).
    pub fn from_config(config: &RunConfig) -> Self {
        let seed = config.run.seed ^ 0x5245_504c_4159;
        Replay::with_capacities(config.plus_capacity(), config.replay.capacity, seed)
            .with_frames(Frames::of(config))
            .with_dynamics_only(config.replay.dynamics_only)
            .with_uncertain_images(config.uncertain_images())
    }

    /// The same replay (still empty), D? keeping its steps' images as D+ does, or dropping them: a camera policy
    /// that clones D?'s states too (`training.clone_uncertain`) reads them. The points auto-labelling moves to the
    /// dynamics-only store leave their images behind.
    pub fn with_uncertain_images(mut self, keep: bool) -> Self {
        debug_assert!(self.uncertain.is_empty(), "before any step is added");
        self.uncertain = Store::new(self.uncertain.capacity(), keep);
        self
    }

    /// The same replay, keeping a dynamics-only store (`replay.dynamics_only`, ours) or dropping what would go
    /// there (the reference).
    pub fn with_dynamics_only(mut self, keep: bool) -> Self {
        self.keep_dynamics_only = keep;
        self
    }

    /// Memory the steps hold (arrays and images) across the stores and D-.
    pub fn bytes(&self) -> usize {
        self.plus.bytes()
            + self.uncertain.bytes()
            + self.dynamics_only.bytes()
            + self.minus.len() * STATE_DIM * 4
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
        Ok(self.add_unchecked(segment))
    }

    /// `segment` checked once ([`Replay::check_segment`]), to be added later with [`Replay::add_checked`] (the
    /// learner checks a segment when it arrives and stores it when the epoch's data is partitioned).
    pub fn checked(&self, segment: Segment) -> Result<Checked, ReplayError> {
        self.check_segment(&segment)?;
        Ok(Checked(segment))
    }

    /// Adds a segment [`Replay::checked`] took, without checking it again. The images' sizes are the run's
    /// ([`Frames`]), so a segment that passed when its store was empty still fits it.
    pub fn add_checked(&mut self, segment: &Checked) -> AddCounts {
        self.add_unchecked(&segment.0)
    }

    fn add_unchecked(&mut self, segment: &Segment) -> AddCounts {
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
                Which::DynamicsOnly if !self.keep_dynamics_only => continue,
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
        counts
    }

    /// Whether [`Replay::add_segment`] would take `segment`: every image of the run's size ([`Frames`]). A replay
    /// made without a configuration ([`Frames::Any`]) holds a segment to the images its stores already keep, or,
    /// while they keep none, to its own first step's.
    pub fn check_segment(&self, segment: &Segment) -> Result<(), ReplayError> {
        let frames = self.frames_for(segment);
        segment
            .steps
            .iter()
            .try_for_each(|step| frames.check(step.image.as_ref()))
    }

    /// The images `segment` must carry: the run's, or, in a replay without a configuration, those of the stores
    /// that keep images (the first one holding steps), else those of its first step.
    fn frames_for(&self, segment: &Segment) -> Frames {
        if self.frames != Frames::Any {
            return self.frames;
        }
        let held = [&self.plus, &self.uncertain]
            .into_iter()
            .find(|s| s.keeps_images() && !s.is_empty());
        match held {
            Some(store) => store.frames(),
            None => Frames::of_image(segment.steps.first().and_then(|s| s.image.as_ref())),
        }
    }

    fn which(outcome: Outcome, step: &Step) -> Which {
        match outcome {
            Outcome::Lap if step.expert_ok => Which::Plus,
            Outcome::Incomplete if step.expert_ok => Which::DynamicsOnly,
            _ => Which::Uncertain,
        }
    }

    /// Marks the start of an epoch's data, right before D_new is added: the rows added from here on are
    /// [`Replay::fresh_plus`] and [`Replay::fresh_uncertain`], until the next epoch's data (under
    /// `collection.overlap` the next epoch trains before its D_new comes in, on these rows as its held-out set).
    pub fn begin_epoch(&mut self) {
        self.fresh = Fresh {
            plus: (self.plus.len(), self.added.plus),
            uncertain: (self.uncertain.len(), self.added.uncertain),
            labelled_from: None,
        };
    }

    /// D+'s rows added since [`Replay::begin_epoch`]; empty when eviction scattered them.
    pub fn fresh_plus(&self) -> std::ops::Range<usize> {
        let len = self.plus.len();
        appended_from(self.fresh.plus, len, self.added.plus).map_or(0..0, |from| from..len)
    }

    /// D?'s rows added since [`Replay::begin_epoch`] (the epoch's failures), without those this epoch's labelling
    /// removed, when it labelled (then they are also D-'s last rows); empty when eviction scattered them.
    pub fn fresh_uncertain(&self) -> std::ops::Range<usize> {
        let len = self.uncertain.len();
        let from = self
            .fresh
            .labelled_from
            .or_else(|| appended_from(self.fresh.uncertain, len, self.added.uncertain));
        from.map_or(0..0, |from| from.min(len)..len)
    }

    /// Applies an auto-labelling pass (eq. (19)), Algorithm 1's "remove x from D?": the D? entries at
    /// `removed` (an auto-labelling report's `removed`: indices into D? as it was labelled) leave D? (as in the reference they are not labelled
    /// safe; they stay available to the dynamics model unless `replay.dynamics_only` is off, where, as in the
    /// reference, they are deleted), and D- becomes what D? then holds, until the next labelling.
    pub fn apply_labels(&mut self, removed: &[usize]) {
        let mut keep = vec![true; self.uncertain.len()];
        let fresh_from = appended_from(
            self.fresh.uncertain,
            self.uncertain.len(),
            self.added.uncertain,
        );
        let mut removed_before_fresh = 0;
        for &i in removed {
            if i < keep.len() && keep[i] {
                keep[i] = false;
                removed_before_fresh += usize::from(fresh_from.is_some_and(|from| i < from));
                if self.keep_dynamics_only {
                    self.uncertain
                        .copy_entry(i, &mut self.dynamics_only, &mut self.rng);
                }
            }
        }
        self.uncertain.retain(&keep);
        self.minus = self.uncertain.states.clone();
        // D? keeps its order, so what is left of this epoch's rows is its tail.
        self.fresh.labelled_from = fresh_from.map(|from| from - removed_before_fresh);
    }
}

#[derive(Clone, Copy)]
enum Which {
    Plus,
    Uncertain,
    DynamicsOnly,
}
