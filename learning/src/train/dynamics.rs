//! Fitting the dynamics model f_hat, eq. (15): min || x' - f_hat(x, u) ||^2 over every stored (x, u, x').

use super::data::Uploaded;
use super::fit::{fit, Budget, Mean, AUX_PRECISION};
use super::Trainer;
use crate::replay::Replay;
use tch::{Reduction, Tensor};

/// The result of a dynamics fit.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Fit {
    /// Eq. (15) MSE, mean over the last pass.
    pub loss: f64,
    /// Samples seen (all passes).
    pub samples: usize,
}

impl Trainer {
    /// One fit call of f_hat, eq. (15), on every stored (x, u_applied, x'): D+, D? and the dynamics-only store.
    /// None (nothing trained, the rng untouched) when they hold fewer than `batch_size` samples.
    pub fn fit_dynamics(&mut self, replay: &Replay, passes: usize) -> Option<Fit> {
        self.fit_dynamics_on(&self.upload(replay), passes)
    }

    /// [`Trainer::fit_dynamics`] on the epoch's uploaded replay.
    pub(crate) fn fit_dynamics_on(&mut self, data: &Uploaded, passes: usize) -> Option<Fit> {
        let (x, u, x_next, n) = data.transitions();
        if n < self.config.training.batch_size {
            return None;
        }
        let dynamics = &self.dynamics;
        // (x, u, x') side by side: one gather a batch.
        let rows = Tensor::cat(&[&x, &u, &x_next], 1);
        let (xs, us) = (x.size()[1], u.size()[1]);
        let (mean, samples) = fit(
            &mut self.dynamics_opt,
            &self.config.training,
            AUX_PRECISION,
            self.device,
            &mut self.rng,
            n,
            Budget {
                passes,
                max_batches: self.config.training.aux_max_batches,
            },
            &[],
            |b, mean: &mut Mean| {
                let batch = rows.index_select(0, &b.idx);
                let pred = dynamics.forward(&batch.narrow(1, 0, xs), &batch.narrow(1, xs, us));
                let loss = pred.mse_loss(&batch.narrow(1, xs + us, xs), Reduction::Mean);
                if b.reported {
                    mean.add(&loss);
                }
                Ok(loss)
            },
        )
        .expect("the dynamics loss does not fail");
        Some(Fit {
            loss: mean.get(),
            samples,
        })
    }
}
