//! The learner's policy publications held for its queryable (`policy`, `policy?version=<v>`): the latest for late
//! joiners, and each version not evaluated yet for an evaluator that missed it, at most [`HELD_BYTES`].

use crate::{encoding_of, Bus};
use bytes::Bytes;
use cabc_proto::messages::{EvalReport, PolicyUpdate};
use cabc_proto::ports::PortError;
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use zenoh::query::Queryable;
use zenoh::Wait;

/// The publications the policy queryable holds, at most this many bytes (always the latest).
const HELD_BYTES: usize = 256 << 20;

/// The encoded publications held, by version, and the queryable that answers from them.
pub(crate) struct Publications {
    held: Arc<Mutex<BTreeMap<u64, Bytes>>>,
    _queryable: Queryable<()>,
}

fn lock(held: &Mutex<BTreeMap<u64, Bytes>>) -> std::sync::MutexGuard<'_, BTreeMap<u64, Bytes>> {
    held.lock().unwrap_or_else(|e| e.into_inner())
}

impl Publications {
    /// Declares the queryable on `bus`'s `policy` key.
    pub(crate) fn declare(bus: &Bus) -> Result<Publications, PortError> {
        let held: Arc<Mutex<BTreeMap<u64, Bytes>>> = Arc::default();
        let answer = held.clone();
        let queryable = bus
            .session
            .declare_queryable(bus.keys.policy())
            .callback(move |query| {
                let held = lock(&answer);
                let wanted = query.parameters().get("version");
                let bytes = match wanted.map(str::parse::<u64>) {
                    None => held.last_key_value().map(|(_, b)| b.clone()),
                    Some(Ok(version)) => held.get(&version).cloned(),
                    Some(Err(_)) => None,
                };
                drop(held);
                // No reply: nothing published yet, or a version no longer held (the asker logs it).
                let Some(latest) = bytes else {
                    return;
                };
                let key = query.key_expr().clone();
                if let Err(e) = query
                    .reply(key, latest)
                    .encoding(encoding_of::<PolicyUpdate>())
                    .wait()
                {
                    tracing::warn!("answering a policy query: {e}");
                }
            })
            .wait()
            .map_err(|e| PortError::Transport(e.to_string()))?;
        Ok(Publications {
            held,
            _queryable: queryable,
        })
    }

    /// Holds `version`'s publication, dropping the oldest past [`HELD_BYTES`].
    pub(crate) fn hold(&self, version: u64, encoded: Bytes) {
        let mut held = lock(&self.held);
        held.insert(version, encoded);
        let mut bytes: usize = held.values().map(Bytes::len).sum();
        while bytes > HELD_BYTES && held.len() > 1 {
            if let Some((_, dropped)) = held.pop_first() {
                bytes -= dropped.len();
            }
        }
    }

    /// A version with its evaluation is no longer held for evaluators that missed it (the latest stays, for late
    /// joiners): a restarted evaluator takes up the versions not evaluated instead of evaluating them all again.
    pub(crate) fn evaluated(&self, reports: &[EvalReport]) {
        let mut held = lock(&self.held);
        let latest = held.last_key_value().map(|(v, _)| *v);
        for report in reports {
            if Some(report.version) != latest {
                held.remove(&report.version);
            }
        }
    }
}
