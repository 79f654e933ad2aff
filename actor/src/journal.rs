//! The actor's side of the run's journal (`cabc_runfolder::journal`, issue 74): [`Journaled`] writes each segment's
//! line before the segment goes on the wire, and each marker's after it went; the outbox writes the learner's
//! receipts (`cabc_bus::outbox`), the collector the steps taken (`Collector::with_tally`).

use crate::run::{ActorError, ActorStats};
use cabc_proto::messages::TrajMessage;
use cabc_proto::ports::{PortError, SegmentSink};
use cabc_runfolder::journal::{ActorEvent, ActorJournal, JournalError, STOPPED};
use std::path::Path;
use std::sync::Arc;

/// A [`SegmentSink`] that journals what goes through it to the sink it wraps (with no journal, it passes through).
pub struct Journaled<'a> {
    sink: &'a mut dyn SegmentSink,
    journal: Option<Arc<ActorJournal>>,
}

impl<'a> Journaled<'a> {
    pub fn new(sink: &'a mut dyn SegmentSink, journal: Option<Arc<ActorJournal>>) -> Self {
        Journaled { sink, journal }
    }
}

/// The journal of `actor`'s process `incarnation` in `dir`, when it keeps one (`actor --journal DIR`).
pub fn begin(
    dir: Option<&Path>,
    actor: &str,
    incarnation: u64,
) -> Result<Option<Arc<ActorJournal>>, JournalError> {
    dir.map(|dir| ActorJournal::begin(dir, actor, incarnation).map(Arc::new))
        .transpose()
}

/// The collector's tally (`Collector::with_tally`) into `journal`.
pub fn tally(journal: Arc<ActorJournal>) -> impl FnMut(u64) + Send + 'static {
    move |taken| journal.taken(taken)
}

/// The journal's last line: how the actor's run ended (`interrupted` by its own signal, stopped by the learner, or
/// failed).
pub fn ended(journal: &ActorJournal, ran: &Result<ActorStats, ActorError>, interrupted: bool) {
    let reason = match ran {
        Ok(_) if interrupted => "interrupted".to_string(),
        Ok(_) => STOPPED.to_string(),
        Err(e) => format!("failed: {e}"),
    };
    journal.record(&ActorEvent::Ended { reason });
}

impl SegmentSink for Journaled<'_> {
    fn put(&mut self, message: TrajMessage) -> Result<(), PortError> {
        let Some(journal) = &self.journal else {
            return self.sink.put(message);
        };
        match &message {
            TrajMessage::Segment(_) | TrajMessage::Segments(_) => {
                for segment in message.segments() {
                    journal.record(&ActorEvent::Published {
                        seq: segment.seq,
                        version: segment.policy_version,
                        steps: segment.steps.len() as u64,
                    });
                }
                let seqs: Vec<u64> = message.segments().iter().map(|s| s.seq).collect();
                let put = self.sink.put(message);
                if let Err(e) = &put {
                    let why = e.to_string();
                    for seq in seqs {
                        journal.record(&ActorEvent::Unsent {
                            seq,
                            why: why.clone(),
                        });
                    }
                }
                put
            }
            TrajMessage::EpochDone(marker) => {
                let done = ActorEvent::Done {
                    version: marker.version,
                    published: marker.steps,
                    taken: marker.taken,
                    staged: marker.staged,
                };
                self.sink.put(message)?;
                journal.record(&done);
                Ok(())
            }
        }
    }
}
