//! The learner's policy publications held for its queryable (`policy`, `policy?version=<v>`): the latest for late
//! joiners, and each version not evaluated yet for an evaluator that missed it, at most [`HELD_BYTES`].
//!
//! The answers go out from a thread of their own, not from zenoh's callback: an answer (a policy, up to megabytes)
//! waits for room on the link like any reliable put, and a zenoh thread waiting there reads nothing meanwhile. Through
//! a standalone router at saturation that was a deadlock (issue 73, `cabc bench-bus`): the router's threads waited
//! to hand the learner more segments, the learner's waited to hand the router an answer, until zenoh closed the link.

use crate::{encoding_of, Bus};
use bytes::Bytes;
use cabc_proto::messages::{EvalReport, PolicyUpdate};
use cabc_proto::ports::PortError;
use std::collections::BTreeMap;
use std::sync::mpsc::{sync_channel, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use zenoh::query::{Query, Queryable};
use zenoh::Wait;

/// The publications the policy queryable holds, at most this many bytes (always the latest).
const HELD_BYTES: usize = 256 << 20;

/// Queries waiting for their answer; past it a query goes unanswered (the asker asks again, `crate::ports`).
const PENDING_QUERIES: usize = 1024;

/// The encoded publications held, by version, and the queryable that answers from them.
pub(crate) struct Publications {
    held: Arc<Mutex<BTreeMap<u64, Bytes>>>,
    /// Dropped before the answering thread's channel, which ends it.
    _queryable: Queryable<()>,
}

fn lock(held: &Mutex<BTreeMap<u64, Bytes>>) -> std::sync::MutexGuard<'_, BTreeMap<u64, Bytes>> {
    held.lock().unwrap_or_else(|e| e.into_inner())
}

impl Publications {
    /// Declares the queryable on `bus`'s `policy` key, answered by a thread of its own.
    pub(crate) fn declare(bus: &Bus) -> Result<Publications, PortError> {
        let held: Arc<Mutex<BTreeMap<u64, Bytes>>> = Arc::default();
        let (to_answer, queries) = sync_channel::<Query>(PENDING_QUERIES);
        let answer = held.clone();
        std::thread::Builder::new()
            .name("policy-answers".into())
            .spawn(move || {
                // Ends when the queryable, and with it the sender, is dropped.
                while let Ok(query) = queries.recv() {
                    reply(&answer, &query);
                }
            })
            .map_err(|e| PortError::Transport(format!("the policy queryable's thread: {e}")))?;
        let queryable = bus
            .session
            .declare_queryable(bus.keys.policy())
            .callback(move |query| hand_over(&to_answer, query))
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

/// Hands a query to the answering thread without waiting: with [`PENDING_QUERIES`] waiting it goes unanswered.
fn hand_over(to_answer: &SyncSender<Query>, query: Query) {
    if let Err(TrySendError::Full(_)) = to_answer.try_send(query) {
        tracing::warn!(
            "too many policy queries waiting: one goes unanswered (its asker asks again)"
        );
    }
}

/// Answers `query` from `held`: the latest publication, or the version asked for.
fn reply(held: &Mutex<BTreeMap<u64, Bytes>>, query: &Query) {
    let bytes = {
        let held = lock(held);
        match query.parameters().get("version").map(str::parse::<u64>) {
            None => held.last_key_value().map(|(_, b)| b.clone()),
            Some(Ok(version)) => held.get(&version).cloned(),
            Some(Err(_)) => None,
        }
    };
    // No reply: nothing published yet, or a version no longer held (the asker logs it).
    let Some(bytes) = bytes else {
        return;
    };
    let key = query.key_expr().clone();
    if let Err(e) = query
        .reply(key, bytes)
        .encoding(encoding_of::<PolicyUpdate>())
        .wait()
    {
        tracing::warn!("answering a policy query: {e}");
    }
}
