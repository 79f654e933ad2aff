//! The replay's arrays on the training device, uploaded once per epoch ([`Uploaded::of`]) and shared by the three
//! fits of [`Trainer::train_epoch`](super::Trainer::train_epoch): each network's examples are then views and
//! concatenations on the device, not a new host-side copy of the replay per network.

use super::fit::cat_rows;
use super::standardise::Standardiser;
use crate::replay::{Replay, Store};
use cabc_proto::messages::{ACTION_DIM, STATE_DIM};
use tch::{Device, Tensor};

/// One store's arrays: [N, 6] states and next states, [N, 2] actions.
pub(crate) struct Rows {
    pub states: Tensor,
    pub expert_actions: Tensor,
    pub applied_actions: Tensor,
    pub next_states: Tensor,
    pub len: usize,
}

impl Rows {
    fn of(store: &Store, device: Device, standardiser: Option<&Standardiser>) -> Self {
        let states = |rows: &[[f32; STATE_DIM]]| states(rows, device, standardiser);
        Rows {
            states: states(&store.states),
            expert_actions: cat_rows([store.expert_actions.as_flattened()], ACTION_DIM, device),
            applied_actions: cat_rows([store.applied_actions.as_flattened()], ACTION_DIM, device),
            next_states: states(&store.next_states),
            len: store.len(),
        }
    }
}

/// States [N, 6] on the device, standardised when the trainer standardises.
pub(crate) fn states(
    rows: &[[f32; STATE_DIM]],
    device: Device,
    standardiser: Option<&Standardiser>,
) -> Tensor {
    let x = cat_rows([rows.as_flattened()], STATE_DIM, device);
    standardiser.map_or(x.shallow_clone(), |s| s.apply(&x))
}

/// D+, D?, the dynamics-only store and D-, on the device; every state (and next state) standardised when the
/// trainer standardises (`training.standardise`).
pub(crate) struct Uploaded {
    pub plus: Rows,
    pub uncertain: Rows,
    pub dynamics_only: Rows,
    /// D- [N-, 6] (the states of D? at the last labelling).
    pub minus: Tensor,
}

impl Uploaded {
    pub fn of(replay: &Replay, device: Device, standardiser: Option<&Standardiser>) -> Self {
        Uploaded {
            plus: Rows::of(&replay.plus, device, standardiser),
            uncertain: Rows::of(&replay.uncertain, device, standardiser),
            dynamics_only: Rows::of(&replay.dynamics_only, device, standardiser),
            minus: states(replay.minus(), device, standardiser),
        }
    }

    /// Every stored (x, u, x') for f_hat: D+, D? and the dynamics-only store, in that order.
    pub fn transitions(&self) -> (Tensor, Tensor, Tensor, usize) {
        let stores = [&self.plus, &self.uncertain, &self.dynamics_only];
        let cat = |f: fn(&Rows) -> &Tensor| Tensor::cat(&stores.map(f), 0);
        (
            cat(|r| &r.states),
            cat(|r| &r.applied_actions),
            cat(|r| &r.next_states),
            stores.iter().map(|r| r.len).sum(),
        )
    }
}
