//! One buffer of the replay, a structure of arrays with a fixed capacity and random eviction; the images of the
//! steps that are read with their images (D+), in one contiguous array.

use super::Frames;
use cabc_proto::messages::{image_bytes, Step, ACTION_DIM, STATE_DIM};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// `ImageStore::records` of a slot written since the last checkpoint.
pub(crate) const NOT_LOGGED: u64 = u64::MAX;

/// Images of one size, contiguous: entry i is `bytes[i * len .. (i + 1) * len]`, HWC RGB.
///
/// The bytes are not in the checkpoint's `replay.bin`: a checkpoint appends the images written since the last one
/// to the run's image log ([`super::log::ImageLog`]) and saves, per slot, the log record that holds its image.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ImageStore {
    pub width: u16,
    pub height: u16,
    #[serde(skip)]
    pub bytes: Vec<u8>,
    /// Per slot: its image's record in the image log, [`NOT_LOGGED`] if written since the last checkpoint.
    pub(crate) records: Vec<u64>,
}

impl ImageStore {
    /// Bytes of one image.
    pub fn image_len(&self) -> usize {
        image_bytes(self.width.into(), self.height.into())
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
    /// Whether this store keeps its steps' images (D+, the policy's training set); the others drop them: nothing
    /// reads an image of D?, D- or the dynamics-only store.
    keeps_images: bool,
}

/// Bytes of a step's arrays besides its image: state, expert and applied action, next state (f32).
pub const STEP_BYTES: usize = (2 * STATE_DIM + 2 * ACTION_DIM) * 4;

impl Store {
    /// A store of `capacity` steps that keeps their images or drops them.
    pub fn new(capacity: usize, keeps_images: bool) -> Self {
        Store {
            capacity,
            keeps_images,
            ..Default::default()
        }
    }

    /// Memory held by the steps (arrays and images), not counting spare capacity.
    pub fn bytes(&self) -> usize {
        self.len() * STEP_BYTES + self.images.as_ref().map_or(0, |i| i.bytes.len())
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

    pub(crate) fn keeps_images(&self) -> bool {
        self.keeps_images
    }

    /// The images this store's steps carry (of a store that keeps them).
    pub(crate) fn frames(&self) -> Frames {
        self.images.as_ref().map_or(Frames::None, |i| Frames::Rgb {
            width: i.width,
            height: i.height,
        })
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
        let image = image.filter(|_| self.keeps_images);
        if self.images.is_none() && image.is_some() {
            self.images = Some(ImageStore {
                width: size.0,
                height: size.1,
                ..Default::default()
            });
        }
        if self.len() < self.capacity {
            self.states.push(state);
            self.expert_actions.push(expert);
            self.applied_actions.push(applied);
            self.next_states.push(next);
            if let (Some(store), Some(img)) = (&mut self.images, image) {
                store.bytes.extend_from_slice(img);
                store.records.push(NOT_LOGGED);
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
                store.records[i] = NOT_LOGGED;
            }
        }
    }

    pub(crate) fn push_step(&mut self, step: &Step, rng: &mut ChaCha8Rng) {
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
    pub(crate) fn copy_entry(&self, i: usize, to: &mut Store, rng: &mut ChaCha8Rng) {
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
    pub(crate) fn retain(&mut self, keep: &[bool]) {
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
                    // The same image: its log record still holds it.
                    store.records[j] = store.records[i];
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
            store.records.truncate(j);
        }
    }
}
