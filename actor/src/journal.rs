//! The actor's side of the run's journal (`cabc_runfolder::journal`, issue 74): [`Journaled`] writes each segment's
//! line before the segment goes on the wire, and each marker's after it went; the outbox writes the learner's
//! receipts (`cabc_bus::outbox`), the collector the steps taken (`Collector::with_tally`).

use cabc_proto::messages::TrajMessage;
use cabc_proto::ports::{PortError, SegmentSink};
use cabc_runfolder::journal::{ActorEvent, ActorJournal};
use std::sync::Arc;

/// A [`SegmentSink`] that journals what goes through it to the sink it wraps.
pub struct Journaled<'a> {
    sink: &'a mut dyn SegmentSink,
    journal: Arc<ActorJournal>,
}

impl<'a> Journaled<'a> {
    pub fn new(sink: &'a mut dyn SegmentSink, journal: Arc<ActorJournal>) -> Self {
        Journaled { sink, journal }
    }
}

impl SegmentSink for Journaled<'_> {
    fn put(&mut self, message: TrajMessage) -> Result<(), PortError> {
        match &message {
            TrajMessage::Segment(segment) => {
                let seq = segment.seq;
                self.journal.record(&ActorEvent::Published {
                    seq,
                    version: segment.policy_version,
                    steps: segment.steps.len() as u64,
                });
                let put = self.sink.put(message);
                if let Err(e) = &put {
                    let why = e.to_string();
                    self.journal.record(&ActorEvent::Unsent { seq, why });
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
                self.journal.record(&done);
                Ok(())
            }
        }
    }
}
