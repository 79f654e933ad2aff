//! The codec: `encode` / `decode` every bus message (bincode 2, behind these two functions so that the format
//! can change in one place).
//!
//! Layout: `b"CABC"` | schema version (u16, little-endian) | message kind (u8) | bincode body.
//! Decoding refuses, with a [`DecodeError`] that says what was wrong, and never panics:
//! truncated or empty bytes, a foreign magic, another schema version, another message kind, a body that does not
//! decode or has trailing bytes, a body larger than [`MAX_BODY`], and NaN/inf where a state or action is expected.

use crate::messages::*;
use serde::{de::DeserializeOwned, Serialize};

/// The first four bytes of every payload.
pub const MAGIC: [u8; 4] = *b"CABC";
/// Bumped whenever a message changes shape.
pub const SCHEMA_VERSION: u16 = 8;
/// Header length in bytes.
pub const HEADER_LEN: usize = 7;
/// Largest body accepted (a policy update of a ResNet-18 is ~45 MB; segments are far smaller).
pub const MAX_BODY: usize = 256 << 20;

fn config() -> impl bincode::config::Config {
    bincode::config::standard().with_limit::<MAX_BODY>()
}

/// A type that travels on the bus.
pub trait Message: Serialize + DeserializeOwned {
    /// Distinguishes message types on the wire.
    const KIND: u8;
    /// For error messages.
    const NAME: &'static str;
    /// Checks values that serde cannot (finite numbers, consistent sizes).
    fn validate(&self) -> Result<(), String> {
        Ok(())
    }
}

/// Why bytes were refused.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum DecodeError {
    #[error("payload too short: {len} bytes, a header alone is {HEADER_LEN}")]
    Truncated { len: usize },
    #[error("foreign payload: magic {found:02x?} is not {MAGIC:02x?} (\"CABC\")")]
    Foreign { found: [u8; 4] },
    #[error("schema version {found} is not this build's {SCHEMA_VERSION}: sender and receiver run different cabc versions")]
    SchemaVersion { found: u16 },
    #[error("expected a {expected} message (kind {expected_kind}), got kind {found}")]
    WrongKind {
        expected: &'static str,
        expected_kind: u8,
        found: u8,
    },
    #[error("malformed {message} body: {reason}")]
    Malformed {
        message: &'static str,
        reason: String,
    },
    #[error("{message} has {extra} trailing bytes after its body")]
    TrailingBytes { message: &'static str, extra: usize },
    #[error("invalid {message}: {reason}")]
    Invalid {
        message: &'static str,
        reason: String,
    },
    #[error("{message} of {len} items, more than the {max} taken")]
    TooMany {
        message: &'static str,
        len: u64,
        max: usize,
    },
}

/// Encodes a message with its header. Encoding plain data cannot fail short of memory exhaustion.
pub fn encode<M: Message>(message: &M) -> Vec<u8> {
    let mut out = Vec::with_capacity(64);
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&SCHEMA_VERSION.to_le_bytes());
    out.push(M::KIND);
    bincode::serde::encode_into_std_write(message, &mut out, config())
        .expect("encoding plain data into a Vec cannot fail");
    out
}

/// Decodes and validates a message.
pub fn decode<M: Message>(bytes: &[u8]) -> Result<M, DecodeError> {
    let kind = check_header(bytes)?;
    if kind != M::KIND {
        return Err(DecodeError::WrongKind {
            expected: M::NAME,
            expected_kind: M::KIND,
            found: kind,
        });
    }
    let body = &bytes[HEADER_LEN..];
    let (message, used): (M, usize) =
        bincode::serde::decode_from_slice(body, config()).map_err(|e| DecodeError::Malformed {
            message: M::NAME,
            reason: e.to_string(),
        })?;
    if used != body.len() {
        return Err(DecodeError::TrailingBytes {
            message: M::NAME,
            extra: body.len() - used,
        });
    }
    message.validate().map_err(|reason| DecodeError::Invalid {
        message: M::NAME,
        reason,
    })?;
    Ok(message)
}

/// Decodes an [`ExpertRequest`] of at most `max_batch` queries. The batch size, the length prefix of `queries`
/// right after the header and `request_id`, is read and checked before anything is decoded, so a request that
/// claims a billion queries costs a few bytes of reading.
pub fn decode_request(bytes: &[u8], max_batch: usize) -> Result<ExpertRequest, DecodeError> {
    let kind = check_header(bytes)?;
    if kind != ExpertRequest::KIND {
        return Err(DecodeError::WrongKind {
            expected: ExpertRequest::NAME,
            expected_kind: ExpertRequest::KIND,
            found: kind,
        });
    }
    // `request_id` then the length of `queries`, as the encoding of (u64, u64) reads them.
    let ((_, len), _): ((u64, u64), usize) =
        bincode::serde::decode_from_slice(&bytes[HEADER_LEN..], config()).map_err(|e| {
            DecodeError::Malformed {
                message: ExpertRequest::NAME,
                reason: e.to_string(),
            }
        })?;
    if len > max_batch as u64 {
        return Err(DecodeError::TooMany {
            message: ExpertRequest::NAME,
            len,
            max: max_batch,
        });
    }
    decode(bytes)
}

/// Checks magic and schema version; returns the message kind.
pub fn check_header(bytes: &[u8]) -> Result<u8, DecodeError> {
    if bytes.len() < HEADER_LEN {
        return Err(DecodeError::Truncated { len: bytes.len() });
    }
    let magic = [bytes[0], bytes[1], bytes[2], bytes[3]];
    if magic != MAGIC {
        return Err(DecodeError::Foreign { found: magic });
    }
    let version = u16::from_le_bytes([bytes[4], bytes[5]]);
    if version != SCHEMA_VERSION {
        return Err(DecodeError::SchemaVersion { found: version });
    }
    Ok(bytes[6])
}

fn finite(what: &str, values: &[f32]) -> Result<(), String> {
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(i) => Err(format!("{what}[{i}] is {}", values[i])),
    }
}

fn finite64(what: &str, values: &[f64]) -> Result<(), String> {
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(i) => Err(format!("{what}[{i}] is {}", values[i])),
    }
}

impl Step {
    /// Every number finite. An image's size is checked once, against the run's observation, where the learner takes
    /// the segment in (`cabc_learning::replay::Frames`): the codec only bounds its bytes as it bounds every `Vec`.
    pub fn validate(&self) -> Result<(), String> {
        finite("state", &self.state)?;
        finite("pose", &self.pose)?;
        finite("applied_action", &self.applied_action)?;
        finite("next_state", &self.next_state)?;
        if self.expert_ok {
            finite("expert_action", &self.expert_action)?;
        }
        Ok(())
    }
}

fn validate_steps(segment: &Segment) -> Result<(), String> {
    for (i, step) in segment.steps.iter().enumerate() {
        step.validate().map_err(|e| format!("step {i}: {e}"))?;
    }
    Ok(())
}

impl Message for TrajMessage {
    const KIND: u8 = 1;
    const NAME: &'static str = "TrajMessage";
    fn validate(&self) -> Result<(), String> {
        match self {
            TrajMessage::Segment(segment) => validate_steps(segment),
            TrajMessage::Segments(segments) => {
                let Some(first) = segments.first() else {
                    return Err("a batch of no segments".into());
                };
                for (k, segment) in segments.iter().enumerate() {
                    if (&segment.actor, segment.incarnation) != (&first.actor, first.incarnation) {
                        return Err(format!(
                            "segment {k} of a batch is of actor `{}` incarnation {}, the first of `{}` incarnation {}",
                            segment.actor, segment.incarnation, first.actor, first.incarnation
                        ));
                    }
                    validate_steps(segment).map_err(|e| format!("segment {k}: {e}"))?;
                }
                Ok(())
            }
            TrajMessage::EpochDone(_) => Ok(()),
        }
    }
}

impl Message for PolicyUpdate {
    const KIND: u8 = 2;
    const NAME: &'static str = "PolicyUpdate";
    fn validate(&self) -> Result<(), String> {
        if !(0.0..=1.0).contains(&self.beta) {
            return Err(format!("beta {} is outside [0, 1]", self.beta));
        }
        Ok(())
    }
}

/// Query states are checked item by item by the expert server (a bad state is a per-item failure, not a refusal
/// of the whole batch), so only the shape is checked here.
impl Message for ExpertRequest {
    const KIND: u8 = 3;
    const NAME: &'static str = "ExpertRequest";
}

impl Message for ExpertReply {
    const KIND: u8 = 4;
    const NAME: &'static str = "ExpertReply";
    fn validate(&self) -> Result<(), String> {
        for (i, a) in self.answers.iter().enumerate() {
            if a.success {
                finite64(&format!("answer {i} action"), &a.action)?;
            }
        }
        Ok(())
    }
}

impl Message for EvalReport {
    const KIND: u8 = 5;
    const NAME: &'static str = "EvalReport";
    fn validate(&self) -> Result<(), String> {
        finite64("lap_times", &self.lap_times)?;
        if self.lap_times.len() != self.laps as usize {
            return Err(format!(
                "{} laps but {} lap times",
                self.laps,
                self.lap_times.len()
            ));
        }
        if self.spawn_crashes > self.spawn_episodes {
            return Err(format!(
                "{} crashes of {} episodes from random spawns",
                self.spawn_crashes, self.spawn_episodes
            ));
        }
        Ok(())
    }
}

impl Message for Stop {
    const KIND: u8 = 6;
    const NAME: &'static str = "Stop";
}

impl Message for Ack {
    const KIND: u8 = 7;
    const NAME: &'static str = "Ack";
}

#[cfg(test)]
mod tests;
