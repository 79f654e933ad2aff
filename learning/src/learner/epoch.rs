//! The learner's epoch in progress.

use crate::ledger::Ledger;
use crate::provenance::Provenance;
use crate::record::Record;
use std::time::Instant;

/// The epoch in progress, from [`Learner::begin_epoch`] to [`Learner::end_epoch`]: its record and its counts.
pub(super) struct Epoch {
    pub(super) record: Record,
    pub(super) started: Instant,
    /// The ledger's stored steps and segments when the epoch began.
    pub(super) stored_before: (u64, u64),
    /// Steps in incomplete segments.
    pub(super) incomplete_steps: u64,
    /// Where the epoch's D? steps came from.
    pub(super) provenance: Provenance,
}

impl Epoch {
    pub(super) fn new(epoch: u64, ledger: &Ledger) -> Self {
        Epoch {
            record: Record::new(epoch),
            started: Instant::now(),
            stored_before: (ledger.stored_steps, ledger.stored_segments),
            incomplete_steps: 0,
            provenance: Provenance::default(),
        }
    }
}
