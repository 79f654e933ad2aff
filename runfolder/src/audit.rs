//! `cabc audit RUN`: every segment an actor journalled ([`crate::journal`]), accounted for against the learner's
//! final ledger (the checkpoint's `state.json`), one by one (issue 74).
//!
//! Each published segment has one fate:
//! * **stored**: in the final ledger (once: the ledger is a set, and its step count is checked against the
//!   journals' steps of the same segments, so a segment counted twice shows);
//! * **refused**: the learner refused it and says why in its journal (a policy version it has not published, images
//!   of the wrong size);
//! * **never sent**: the actor journalled it and did not put it on the wire (stopped with no router up, or its full
//!   outbox dropped it unacknowledged);
//! * **in flight at its actor's end**: not received by any learner, and its actor ended without the learner's stop
//!   (killed: no last line; or interrupted by a signal), its outbox with it;
//! * **held by a learner that stopped**: received only by learner processes that ended before the last one began
//!   (killed, or interrupted), never committed, and its actor ended without the learner's stop too: a learner
//!   receives a segment on arrival and commits it with the checkpoint that holds it; the actor keeps it until then,
//!   and publishes it again to the next learner process, unless the actor is gone as well (a job's requeue stops
//!   every process at once);
//! * **after the run's end**: the last learner says it held it unstored when its last epoch closed;
//! * **lost**: none of these (a segment committed, or received by the last learner, or whose actor lived to the
//!   run's end, and not stored). A run that lost nothing has none; the audit fails on one.
//!
//! Beside the segments: the steps each actor took and never published (the unfinished laps staged at its end, or
//! what was in flight at a kill), from its `.taken` tally.

use crate::journal::{self, ActorEvent, LearnerEvent};
use crate::{Table, CHECKPOINT, CHECKPOINT_OLD, METRICS};
use serde::Serialize;
use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet};
use std::path::{Path, PathBuf};

/// What became of a published segment (the module's doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Fate {
    Stored,
    Refused,
    NeverSent,
    InFlightAtItsActorsEnd,
    HeldByALearnerThatStopped,
    AfterTheRunsEnd,
    Lost,
}

impl Fate {
    pub const ALL: [Fate; 7] = [
        Fate::Stored,
        Fate::Refused,
        Fate::NeverSent,
        Fate::InFlightAtItsActorsEnd,
        Fate::HeldByALearnerThatStopped,
        Fate::AfterTheRunsEnd,
        Fate::Lost,
    ];

    pub fn label(self) -> &'static str {
        match self {
            Fate::Stored => "stored once",
            Fate::Refused => "refused by the learner",
            Fate::NeverSent => "never sent",
            Fate::InFlightAtItsActorsEnd => "in flight at its actor's end",
            Fate::HeldByALearnerThatStopped => "held by a learner that stopped",
            Fate::AfterTheRunsEnd => "after the run's end",
            Fate::Lost => "LOST",
        }
    }
}

/// Segments and their steps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Count {
    pub segments: u64,
    pub steps: u64,
}

impl Count {
    fn add(&mut self, steps: u64) {
        self.segments += 1;
        self.steps += steps;
    }
}

/// One actor process, as its journal tells it.
#[derive(Clone, Debug, Serialize)]
pub struct ActorProcess {
    pub actor: String,
    pub incarnation: u64,
    /// Its last line's reason when it ended on its own; None when it was killed.
    pub ended: Option<String>,
    /// The segments it published, by fate.
    pub fates: BTreeMap<Fate, Count>,
    /// The seqs of its lost segments (at most [`MAX_LISTED`]).
    pub lost: Vec<u64>,
    /// Steps it took (its `.taken` tally) and the steps of the segments it published.
    pub taken: u64,
    pub published_steps: u64,
    /// A damaged line that ended the reading of its journal.
    pub damaged: Option<String>,
}

/// One learner process, as `learner.jsonl` tells it.
#[derive(Clone, Debug, Serialize)]
pub struct LearnerProcess {
    pub incarnation: u64,
    pub resumed: bool,
    pub ended: Option<String>,
}

/// The final ledger (the checkpoint's `state.json`) against the journals.
#[derive(Clone, Debug, Default, Serialize)]
pub struct LedgerCheck {
    /// Segments and steps the ledger counts stored.
    pub stored_segments: u64,
    pub stored_steps: u64,
    /// Segments it holds as seen (admitted).
    pub seen: u64,
    /// Copies it dropped.
    pub duplicates: u64,
    /// The journals' steps of the segments the ledger holds, and the segments it holds no journal has.
    pub journal_steps: u64,
    pub unjournalled: u64,
    /// `steps_collected` summed over metrics.csv.
    pub metrics_steps: Option<u64>,
}

/// The run's audit.
#[derive(Clone, Debug, Serialize)]
pub struct Audit {
    pub run: PathBuf,
    pub actors: Vec<ActorProcess>,
    pub learners: Vec<LearnerProcess>,
    /// Every actor's segments, by fate.
    pub fates: BTreeMap<Fate, Count>,
    pub ledger: LedgerCheck,
    /// What does not add up: the audit fails on any.
    pub problems: Vec<String>,
}

/// The audit's figures, without the processes one by one (`cabc chaos`'s report).
#[derive(Clone, Debug, Default, Serialize)]
pub struct Figures {
    /// Segments (and steps) by fate.
    pub fates: BTreeMap<Fate, Count>,
    /// Steps taken and never published: staged at the run's end, and in flight at an actor's kill or interrupt.
    pub never_published_staged: u64,
    pub never_published_in_flight: u64,
    pub actor_processes: usize,
    pub learner_processes: usize,
}

/// Lost seqs listed per actor process.
pub const MAX_LISTED: usize = 20;

/// Errors that stop an audit: nothing to audit.
#[derive(Debug, thiserror::Error)]
pub enum AuditError {
    #[error("{0} has no journal/ (a run whose actors ran with --journal: every run under `cabc supervise`)")]
    NoJournal(PathBuf),
    #[error("{0}: no checkpoint state.json to hold the journals against")]
    NoLedger(PathBuf),
    #[error("{0}")]
    Read(String),
}

/// The checkpoint's ledger, as `learning::ledger::Ledger` serialises it.
#[derive(serde::Deserialize)]
struct Ledger {
    seen: HashMap<String, HashSet<u64>>,
    duplicates: u64,
    stored_segments: u64,
    stored_steps: u64,
}

#[derive(serde::Deserialize)]
struct State {
    ledger: Ledger,
}

fn ledger_of(run: &Path) -> Result<Ledger, AuditError> {
    let path = [CHECKPOINT, CHECKPOINT_OLD]
        .iter()
        .map(|c| run.join(c).join("state.json"))
        .find(|p| p.exists())
        .ok_or_else(|| AuditError::NoLedger(run.to_path_buf()))?;
    let text = std::fs::read_to_string(&path)
        .map_err(|e| AuditError::Read(format!("{}: {e}", path.display())))?;
    let state: State = serde_json::from_str(&text)
        .map_err(|e| AuditError::Read(format!("{}: {e}", path.display())))?;
    Ok(state.ledger)
}

/// What the learners' journal says about the segments and the processes.
#[derive(Default)]
struct Learners {
    processes: Vec<LearnerProcess>,
    refused: HashSet<(String, u64, u64)>,
    unstored: HashSet<(String, u64, u64)>,
}

fn learners_of(dir: &Path, problems: &mut Vec<String>) -> Result<Learners, AuditError> {
    let path = dir.join(journal::LEARNER);
    let mut learners = Learners::default();
    if !path.exists() {
        problems.push(format!(
            "{} is missing: no learner process journalled",
            path.display()
        ));
        return Ok(learners);
    }
    let (events, damaged) =
        journal::read::<LearnerEvent>(&path).map_err(|e| AuditError::Read(e.to_string()))?;
    if let Some(damaged) = damaged {
        problems.push(format!("the learner's journal is damaged: {damaged}"));
    }
    for event in events {
        match event {
            LearnerEvent::Began {
                incarnation,
                resumed,
                ..
            } => learners.processes.push(LearnerProcess {
                incarnation,
                resumed,
                ended: None,
            }),
            LearnerEvent::Refused {
                actor,
                incarnation,
                seq,
                ..
            } => {
                learners.refused.insert((actor, incarnation, seq));
            }
            LearnerEvent::Unstored {
                actor,
                incarnation,
                seqs,
            } => {
                for seq in seqs {
                    learners.unstored.insert((actor.clone(), incarnation, seq));
                }
            }
            LearnerEvent::Ended { reason } => {
                if let Some(last) = learners.processes.last_mut() {
                    last.ended = Some(reason);
                }
            }
        }
    }
    Ok(learners)
}

/// One actor process's journal, read.
struct Journalled {
    process: ActorProcess,
    /// seq -> its steps and receipts.
    published: BTreeMap<u64, Receipts>,
    unsent: HashSet<u64>,
}

/// A published segment's steps and receipts, as its actor journalled them.
#[derive(Default)]
struct Receipts {
    steps: u64,
    /// The learner processes that received it.
    received_by: BTreeSet<u64>,
    /// Whether a learner's checkpoint holds it (a committed receipt).
    committed: bool,
}

fn actor_of(jsonl: &Path) -> Result<Option<Journalled>, AuditError> {
    let (events, damaged) =
        journal::read::<ActorEvent>(jsonl).map_err(|e| AuditError::Read(e.to_string()))?;
    let mut events = events.into_iter();
    let Some(ActorEvent::Began {
        actor, incarnation, ..
    }) = events.next()
    else {
        return Ok(None);
    };
    let mut published: BTreeMap<u64, Receipts> = BTreeMap::new();
    let (mut unsent, mut ended, mut published_steps) = (HashSet::new(), None, 0);
    for event in events {
        match event {
            ActorEvent::Published { seq, steps, .. } => {
                published_steps += steps;
                let receipts = Receipts {
                    steps,
                    ..Receipts::default()
                };
                published.insert(seq, receipts);
            }
            ActorEvent::Unsent { seq, .. } => {
                unsent.insert(seq);
            }
            ActorEvent::Acknowledged {
                learner,
                seqs,
                committed,
            } => {
                for seq in seqs {
                    if let Some(receipts) = published.get_mut(&seq) {
                        receipts.received_by.insert(learner);
                        receipts.committed |= committed;
                    }
                }
            }
            ActorEvent::Ended { reason } => ended = Some(reason),
            ActorEvent::Began { .. } | ActorEvent::Done { .. } => {}
        }
    }
    let taken = journal::read_taken(&jsonl.with_extension("taken"));
    Ok(Some(Journalled {
        process: ActorProcess {
            actor,
            incarnation,
            ended,
            fates: BTreeMap::new(),
            lost: Vec::new(),
            taken,
            published_steps,
            damaged,
        },
        published,
        unsent,
    }))
}

impl Audit {
    /// The audit of the run folder `run` (its `journal/` and its checkpoint's ledger).
    pub fn of(run: &Path) -> Result<Audit, AuditError> {
        let dir = run.join(journal::JOURNAL);
        if !dir.is_dir() {
            return Err(AuditError::NoJournal(run.to_path_buf()));
        }
        let ledger = ledger_of(run)?;
        let mut problems = Vec::new();
        let learners = learners_of(&dir, &mut problems)?;
        let last = learners.processes.last();
        if let Some(running) = last.filter(|l| l.ended.is_none()) {
            let incarnation = running.incarnation;
            problems.push(format!(
                "the last learner process ({incarnation}) did not end: audit a run that ended"
            ));
        }
        let last = last.map(|l| l.incarnation);
        let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
            .map_err(|e| AuditError::Read(format!("{}: {e}", dir.display())))?
            .filter_map(|e| Some(e.ok()?.path()))
            .filter(|p| {
                p.extension().is_some_and(|e| e == "jsonl")
                    && p.file_name().is_some_and(|n| n != journal::LEARNER)
            })
            .collect();
        files.sort();
        let (mut actors, mut fates) = (Vec::new(), BTreeMap::new());
        let mut journalled: HashSet<String> = HashSet::new();
        let mut journal_steps = 0;
        for file in files {
            let Some(mut j) = actor_of(&file)? else {
                problems.push(format!(
                    "{}: no first line naming its process",
                    file.display()
                ));
                continue;
            };
            let key = format!("{}/{}", j.process.actor, j.process.incarnation);
            let stored = ledger.seen.get(&key);
            journalled.insert(key);
            if let Some(damaged) = &j.process.damaged {
                problems.push(format!("a damaged journal: {damaged}"));
            }
            // An actor that ended on the learner's stop lived through every learner: what a learner received and
            // never committed it published again to the next one, so nothing of it may be missing.
            let lived = j.process.ended.as_deref() == Some(journal::STOPPED);
            for (&seq, receipts) in &j.published {
                let steps = &receipts.steps;
                let id = (j.process.actor.clone(), j.process.incarnation, seq);
                let received_by_last = last.is_some_and(|l| receipts.received_by.contains(&l));
                let fate = if stored.is_some_and(|s| s.contains(&seq)) {
                    journal_steps += steps;
                    Fate::Stored
                } else if learners.refused.contains(&id) {
                    Fate::Refused
                } else if j.unsent.contains(&seq) {
                    Fate::NeverSent
                } else if learners.unstored.contains(&id) {
                    Fate::AfterTheRunsEnd
                } else if receipts.committed || received_by_last || lived {
                    Fate::Lost
                } else if !receipts.received_by.is_empty() {
                    Fate::HeldByALearnerThatStopped
                } else {
                    Fate::InFlightAtItsActorsEnd
                };
                if fate == Fate::Lost && j.process.lost.len() < MAX_LISTED {
                    j.process.lost.push(seq);
                }
                j.process
                    .fates
                    .entry(fate)
                    .or_insert_with(Count::default)
                    .add(*steps);
                fates.entry(fate).or_insert_with(Count::default).add(*steps);
            }
            actors.push(j.process);
        }
        let unjournalled: u64 = ledger
            .seen
            .iter()
            .filter(|(key, _)| !journalled.contains(*key))
            .map(|(_, seqs)| seqs.len() as u64)
            .sum();
        let seen = ledger.seen.values().map(|s| s.len() as u64).sum();
        let metrics_steps = Table::read(&run.join(METRICS)).ok().and_then(|t| {
            let column = t.parsed::<u64>("steps_collected").ok()?;
            Some(column.into_iter().flatten().sum())
        });
        let check = LedgerCheck {
            stored_segments: ledger.stored_segments,
            stored_steps: ledger.stored_steps,
            seen,
            duplicates: ledger.duplicates,
            journal_steps,
            unjournalled,
            metrics_steps,
        };
        if let Some(lost) = fates.get(&Fate::Lost) {
            problems.push(format!(
                "{} segments ({} steps) lost: published, and neither stored nor accounted for",
                lost.segments, lost.steps
            ));
        }
        if unjournalled > 0 {
            problems.push(format!(
                "the ledger holds {unjournalled} segments of processes with no journal"
            ));
        }
        if check.seen != check.stored_segments {
            problems.push(format!(
                "the ledger admitted {} segments and counts {} stored",
                check.seen, check.stored_segments
            ));
        }
        if unjournalled == 0 && check.journal_steps != check.stored_steps {
            problems.push(format!(
                "the ledger counts {} steps stored, the journals {} for the same segments",
                check.stored_steps, check.journal_steps
            ));
        }
        let restarted = learners.processes.len() > 1;
        if let Some(m) = metrics_steps.filter(|&m| m != check.stored_steps && !restarted) {
            problems.push(format!(
                "metrics.csv's steps_collected add up to {m}, the ledger's stored steps to {}",
                check.stored_steps
            ));
        }
        Ok(Audit {
            run: run.to_path_buf(),
            actors,
            learners: learners.processes,
            fates,
            ledger: check,
            problems,
        })
    }

    /// Whether every published segment is accounted for and the ledger agrees with the journals.
    pub fn ok(&self) -> bool {
        self.problems.is_empty()
    }

    /// The count of segments (and steps) with `fate`.
    pub fn count(&self, fate: Fate) -> Count {
        self.fates.get(&fate).copied().unwrap_or_default()
    }

    /// Every segment published, whatever its fate.
    pub fn published(&self) -> Count {
        let mut all = Count::default();
        for c in self.fates.values() {
            all.segments += c.segments;
            all.steps += c.steps;
        }
        all
    }

    /// The figures, without the processes one by one.
    pub fn figures(&self) -> Figures {
        let (staged, in_flight) = self.never_published();
        Figures {
            fates: self.fates.clone(),
            never_published_staged: staged,
            never_published_in_flight: in_flight,
            actor_processes: self.actors.len(),
            learner_processes: self.learners.len(),
        }
    }

    /// Steps taken and never published: by processes that ended on the learner's stop (staged at the end:
    /// unfinished laps), and by the others (in flight at a kill or an interrupt).
    pub fn never_published(&self) -> (u64, u64) {
        let mut staged = 0;
        let mut in_flight = 0;
        for a in &self.actors {
            let steps = a.taken.saturating_sub(a.published_steps);
            if a.ended.as_deref() == Some(journal::STOPPED) {
                staged += steps;
            } else {
                in_flight += steps;
            }
        }
        (staged, in_flight)
    }
}

impl std::fmt::Display for Audit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let resumed = self.learners.iter().filter(|l| l.resumed).count();
        let killed = self.actors.iter().filter(|a| a.ended.is_none()).count();
        writeln!(
            f,
            "{}: {} actor processes ({killed} killed), {} learner processes ({resumed} resumed)",
            self.run.display(),
            self.actors.len(),
            self.learners.len()
        )?;
        let all = self.published();
        writeln!(
            f,
            "segments published: {} ({} steps)",
            all.segments, all.steps
        )?;
        for fate in Fate::ALL {
            let c = self.count(fate);
            writeln!(
                f,
                "  {:<34} {:>8} ({} steps)",
                fate.label(),
                c.segments,
                c.steps
            )?;
        }
        let l = &self.ledger;
        writeln!(
            f,
            "copies the ledger dropped: {}; the ledger: {} segments, {} steps stored (the journals: {} steps for them{})",
            l.duplicates,
            l.stored_segments,
            l.stored_steps,
            l.journal_steps,
            l.metrics_steps
                .map_or(String::new(), |m| format!("; metrics.csv: {m}"))
        )?;
        let (staged, in_flight) = self.never_published();
        writeln!(
            f,
            "steps taken and never published: {staged} staged at the run's end (unfinished laps), {in_flight} in flight at an actor's kill or interrupt"
        )?;
        writeln!(
            f,
            "per actor process (stored / other fates / taken, published steps):"
        )?;
        for a in &self.actors {
            let others: Vec<String> = a
                .fates
                .iter()
                .filter(|(fate, _)| **fate != Fate::Stored)
                .map(|(fate, c)| format!("{} {}", c.segments, fate.label()))
                .collect();
            writeln!(
                f,
                "  {}/{} ({}): {} stored{}{}; taken {}, published {} steps{}",
                a.actor,
                a.incarnation,
                a.ended.as_deref().unwrap_or("killed"),
                a.fates.get(&Fate::Stored).map_or(0, |c| c.segments),
                if others.is_empty() { "" } else { ", " },
                others.join(", "),
                a.taken,
                a.published_steps,
                if a.lost.is_empty() {
                    String::new()
                } else {
                    format!("; lost seqs {:?}", a.lost)
                }
            )?;
        }
        if self.problems.is_empty() {
            writeln!(f, "every published segment accounted for")
        } else {
            for p in &self.problems {
                writeln!(f, "PROBLEM: {p}")?;
            }
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests;
