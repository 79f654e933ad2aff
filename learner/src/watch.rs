//! The learner's metrics on the bus (`metrics/learner`), one of its sinks in a distributed run: each epoch's record
//! as JSON, with the actors alive when its collection closed and the messages the bus refused so far, for people
//! watching the run (`zenoh subscribe -k 'cabc/**/metrics/**'`).

use cabc_bus::MetricsOut;
use cabc_learning::record::Record;
use cabc_learning::sink::{Sink, SinkError};
use cabc_proto::ports::Collected;
use serde_json::json;

/// The sink of the bus's metrics.
pub struct BusMetrics {
    out: MetricsOut,
    /// The actors alive when the epoch's collection closed.
    live: Vec<String>,
}

impl BusMetrics {
    pub fn new(out: MetricsOut) -> Self {
        BusMetrics {
            out,
            live: Vec::new(),
        }
    }
}

impl Sink for BusMetrics {
    fn collected(&mut self, _epoch: u64, collected: &Collected) {
        self.live.clone_from(&collected.live);
    }

    fn write(&mut self, record: &Record) -> Result<(), SinkError> {
        let json = json!({
            "epoch": record.epoch(),
            "row": record.to_json(),
            "live_actors": self.live,
            "rejected_messages": self.out.rejected(),
        });
        self.out.publish(&json.to_string());
        Ok(())
    }
}
