//! The run's history, written where it happens (issue 74; Jepsen's way: every operation recorded by the process that
//! issues it, the history checked against the final state afterwards, [`crate::audit`]).
//!
//! `journal/` in the run folder holds one file per actor process (incarnation), `<actor>-<incarnation>.jsonl`, and
//! the learner's, `learner.jsonl`: JSON lines, each written with one `write` as its event happens, unbuffered, so a
//! process killed (SIGKILL) leaves every line it wrote (the kernel holds them; only the machine's own crash loses
//! the page cache). Beside each actor's file, `<actor>-<incarnation>.taken` holds the steps the process took so far,
//! rewritten in place after every batch of steps: what an actor killed had collected and never published.
//!
//! An actor writes a segment's line *before* the segment goes on the wire, so every segment the learner can hold is
//! in a journal; a line whose segment never left (the process killed between the two) is accounted as lost in flight
//! at the kill, which it was.

use serde::{Deserialize, Serialize};
use std::fs::{File, OpenOptions};
use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// The journal's folder in the run folder.
pub const JOURNAL: &str = "journal";
/// The learner's journal in [`JOURNAL`].
pub const LEARNER: &str = "learner.jsonl";
/// The reason an actor's last line gives when it ended on the learner's stop (the run's end): what it had not
/// published then was staged (unfinished laps), and what it had published the learner had.
pub const STOPPED: &str = "stopped";
/// A line longer than this is not the journal's (a file damaged or not ours): the reader stops at it.
const MAX_LINE: usize = 1 << 20;
/// The width of the `.taken` file's number (digits, then a newline).
const TALLY_WIDTH: usize = 20;

/// What an actor process did, in its journal.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum ActorEvent {
    /// The process began: the first line.
    Began {
        actor: String,
        incarnation: u64,
        unix_ms: u64,
    },
    /// Segment `seq` of policy `version` with `steps` steps, about to be published (the first time).
    Published { seq: u64, version: u64, steps: u64 },
    /// Not published after all: the process was stopped while it held it (no router up), or its outbox, full,
    /// dropped it unacknowledged.
    Unsent { seq: u64, why: String },
    /// The learner incarnation `learner` acknowledged these segments: it received them, or (`committed`) its
    /// checkpoint holds them.
    Acknowledged {
        learner: u64,
        seqs: Vec<u64>,
        #[serde(default)]
        committed: bool,
    },
    /// The "done with `version`" marker: the steps published, taken and still staged (unfinished laps) in it.
    Done {
        version: u64,
        published: u64,
        taken: u64,
        staged: u64,
    },
    /// The process ended on its own (a stop, an interrupt): the last line of one not killed.
    Ended { reason: String },
}

/// What a learner process did, in `learner.jsonl`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum LearnerEvent {
    /// A learner process began; its acknowledgements carry `incarnation`. `resumed` from its checkpoint or not.
    Began {
        incarnation: u64,
        resumed: bool,
        unix_ms: u64,
    },
    /// A segment it acknowledged and refused (a policy version it never published, images of the wrong size).
    Refused {
        actor: String,
        incarnation: u64,
        seq: u64,
        why: String,
    },
    /// Segments it had acknowledged and not stored when its last epoch closed: after the run's end.
    Unstored {
        actor: String,
        incarnation: u64,
        seqs: Vec<u64>,
    },
    /// The process ended on its own, with `reason`.
    Ended { reason: String },
}

/// Errors of writing or reading a journal: what, on which file, and why.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct JournalError(pub String);

fn error(what: &str, path: &Path, e: impl std::fmt::Display) -> JournalError {
    JournalError(format!("{what} {}: {e}", path.display()))
}

fn unix_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

/// One JSON-lines file, appended a line per `write`.
struct Lines {
    path: PathBuf,
    file: Mutex<File>,
}

impl Lines {
    fn create(path: PathBuf) -> Result<Lines, JournalError> {
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).map_err(|e| error("creating", parent, e))?;
        }
        let file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .map_err(|e| error("opening", &path, e))?;
        Ok(Lines {
            path,
            file: Mutex::new(file),
        })
    }

    /// Appends `event` as one line. A failed write is logged by the caller's error and otherwise ignored: the run
    /// goes on without its history rather than stop for it.
    fn write(&self, event: &impl Serialize) -> Result<(), JournalError> {
        let mut line =
            serde_json::to_vec(event).map_err(|e| error("encoding for", &self.path, e))?;
        line.push(b'\n');
        let mut file = self.file.lock().unwrap_or_else(|e| e.into_inner());
        file.write_all(&line)
            .map_err(|e| error("writing", &self.path, e))
    }
}

/// An actor process's journal (the module's doc).
pub struct ActorJournal {
    lines: Lines,
    tally: File,
    tally_path: PathBuf,
}

impl ActorJournal {
    /// The journal of `actor`'s incarnation `incarnation` in `dir` (the run folder's [`JOURNAL`]), begun.
    pub fn begin(dir: &Path, actor: &str, incarnation: u64) -> Result<ActorJournal, JournalError> {
        let stem = format!("{actor}-{incarnation}");
        let lines = Lines::create(dir.join(format!("{stem}.jsonl")))?;
        let tally_path = dir.join(format!("{stem}.taken"));
        let tally = File::create(&tally_path).map_err(|e| error("creating", &tally_path, e))?;
        let journal = ActorJournal {
            lines,
            tally,
            tally_path,
        };
        journal.record(&ActorEvent::Began {
            actor: actor.to_string(),
            incarnation,
            unix_ms: unix_ms(),
        });
        journal.taken(0);
        Ok(journal)
    }

    /// Appends `event`; a failure is logged and the run goes on.
    pub fn record(&self, event: &ActorEvent) {
        if let Err(e) = self.lines.write(event) {
            warn(&e);
        }
    }

    /// The steps this process took so far, in place (one `pwrite`: a kill between two leaves one of them whole).
    pub fn taken(&self, steps: u64) {
        let text = format!("{steps:>width$}\n", width = TALLY_WIDTH);
        if let Err(e) = self.tally.write_all_at(text.as_bytes(), 0) {
            warn(&error("writing", &self.tally_path, e));
        }
    }
}

/// The learner's journal (`learner.jsonl`).
pub struct LearnerJournal {
    lines: Lines,
}

impl LearnerJournal {
    /// `dir`'s (the run folder's [`JOURNAL`]) learner journal, appended to: one file across restarts.
    pub fn open(dir: &Path) -> Result<LearnerJournal, JournalError> {
        Ok(LearnerJournal {
            lines: Lines::create(dir.join(LEARNER))?,
        })
    }

    /// The line of a learner process that begins.
    pub fn began(incarnation: u64, resumed: bool) -> LearnerEvent {
        LearnerEvent::Began {
            incarnation,
            resumed,
            unix_ms: unix_ms(),
        }
    }

    /// Appends `event`; a failure is logged and the run goes on.
    pub fn record(&self, event: &LearnerEvent) {
        if let Err(e) = self.lines.write(event) {
            warn(&e);
        }
    }
}

/// A journal that cannot be written says so in the process's log; the run goes on without that line.
fn warn(e: &JournalError) {
    tracing::warn!("the run's journal: {e}");
}

/// Reads the events of a JSON-lines journal; a line that does not parse (the last one, cut by a kill mid-write, or a
/// stranger's) ends the reading, and is reported as the second value.
pub fn read<E: for<'de> Deserialize<'de>>(
    path: &Path,
) -> Result<(Vec<E>, Option<String>), JournalError> {
    let file = File::open(path).map_err(|e| error("opening", path, e))?;
    let mut events = Vec::new();
    let mut reader = BufReader::new(file);
    let mut line = Vec::new();
    let mut number = 0;
    loop {
        line.clear();
        let n = (&mut reader)
            .take(MAX_LINE as u64 + 1)
            .read_until(b'\n', &mut line)
            .map_err(|e| error("reading", path, e))?;
        if n == 0 {
            return Ok((events, None));
        }
        number += 1;
        if line.len() > MAX_LINE {
            return Ok((
                events,
                Some(format!(
                    "{}:{number}: a line over {MAX_LINE} bytes",
                    path.display()
                )),
            ));
        }
        match serde_json::from_slice(&line) {
            Ok(event) => events.push(event),
            Err(e) => return Ok((events, Some(format!("{}:{number}: {e}", path.display())))),
        }
    }
}

/// The steps an actor's `.taken` file says it took (0 when it is missing or unreadable: a process killed before it
/// took a step).
pub fn read_taken(path: &Path) -> u64 {
    std::fs::read_to_string(path)
        .ok()
        .and_then(|t| t.trim().parse().ok())
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_actor_journal_reads_back_what_it_wrote_and_its_tally() {
        let dir = tempfile::tempdir().unwrap();
        let journal = ActorJournal::begin(dir.path(), "actor-1", 42).unwrap();
        journal.record(&ActorEvent::Published {
            seq: 0,
            version: 3,
            steps: 9,
        });
        journal.taken(12);
        journal.taken(7);
        journal.record(&ActorEvent::Acknowledged {
            learner: 5,
            seqs: vec![0],
            committed: false,
        });
        drop(journal);
        let (events, cut) = read::<ActorEvent>(&dir.path().join("actor-1-42.jsonl")).unwrap();
        assert_eq!(cut, None);
        assert_eq!(events.len(), 3);
        assert!(
            matches!(&events[0], ActorEvent::Began { actor, incarnation: 42, .. } if actor == "actor-1")
        );
        assert_eq!(
            events[2],
            ActorEvent::Acknowledged {
                learner: 5,
                seqs: vec![0],
                committed: false
            }
        );
        // The tally is rewritten in place: the last value, not the largest.
        assert_eq!(read_taken(&dir.path().join("actor-1-42.taken")), 7);
    }

    #[test]
    fn a_line_cut_by_a_kill_ends_the_reading_and_is_reported() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("learner.jsonl");
        std::fs::write(
            &path,
            "{\"event\":\"ended\",\"reason\":\"max_epochs\"}\n{\"event\":\"refu",
        )
        .unwrap();
        let (events, cut) = read::<LearnerEvent>(&path).unwrap();
        assert_eq!(
            events,
            vec![LearnerEvent::Ended {
                reason: "max_epochs".into()
            }]
        );
        assert!(cut.unwrap().contains("learner.jsonl:2"));
    }
}
