//! cabc-bus: the zenoh side of cabc, shared by the three binaries.
//!
//! * [`zenoh_config`] and [`Bus::join`]: a zenoh session from the run configuration's `[bus]` section (the learner listens, the others
//!   connect; multicast scouting off unless asked for, so a loopback run never meets strangers), with
//!   [`security`]'s TLS, passwords and access control when `[bus.security]` asks for them;
//! * [`Bus`]: typed publishing over the codec (every payload carries its zenoh encoding), JSON metrics, a
//!   liveliness token, and the [`Rejects`] counter of refused messages;
//! * [`decode_sample`]: decode an incoming payload, counting and logging it when it is foreign or malformed;
//! * [`ports`]: the actor's ports of Algorithm 1 over zenoh (policy source, expert client, segment and evaluation
//!   sinks); [`rollouts`]: the learner's port, the actors over zenoh, with the epoch protocol's [`gate`];
//! * [`interrupt`]: Ctrl-C as a flag that the blocking loops poll.
//!
//! Only binaries open sessions (architecture.md); libraries stay free of zenoh.

pub mod expert;
pub mod gate;
pub mod interrupt;
pub mod membership;
pub mod outbox;
pub mod ports;
mod publications;
pub mod receipts;
pub mod rollouts;
pub mod security;
pub mod senders;
pub mod vouch;
pub mod zenohd;

/// A query on the bus (what a queryable receives: the expert server's relabelling requests).
pub use zenoh::query::Query;

use cabc_proto::codec::{self, Message};
use cabc_proto::config::BusSection;
use cabc_proto::keys::Keys;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use zenoh::bytes::Encoding;
use zenoh::liveliness::LivelinessToken;
use zenoh::qos::CongestionControl;
use zenoh::{Session, Wait};

/// How a process joins the bus.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// A zenoh router listening on `bus.listen`: the learner, so that one machine needs no zenohd (the embedded
    /// default). It routes between the clients.
    Listen,
    /// A zenoh client of `bus.connect` (actors, expert servers, tools): it waits for the router to come up and
    /// reconnects when it restarts (a learner resumed with `--resume`).
    Connect,
}

impl Role {
    /// The learner's role: the run's router when it listens (`bus.listen`, the embedded default and §1 of
    /// deploy/SCALE-OUT.md), a client of the standalone router(s) of `bus.connect` (zenohd, §2) when `bus.listen` is
    /// empty, so that the router's access control alone decides who reads and writes what.
    pub fn of_learner(bus: &BusSection) -> Role {
        if bus.listen.is_empty() {
            Role::Connect
        } else {
            Role::Listen
        }
    }
}

/// Errors of the bus.
#[derive(Debug, thiserror::Error)]
pub enum BusError {
    #[error("zenoh: {0}")]
    Zenoh(String),
    #[error("bad zenoh configuration {key} = {value}: {why}")]
    Config {
        key: &'static str,
        value: String,
        why: String,
    },
}

fn zerr(e: impl std::fmt::Display) -> BusError {
    BusError::Zenoh(e.to_string())
}

/// The largest zenoh message a process reassembles: a codec header and the largest body the codec decodes.
pub const MAX_MESSAGE: usize = codec::HEADER_LEN + codec::MAX_BODY;

/// How long a reliable put (segments, markers, the policy: `CongestionControl::Block`) may wait for room on a link
/// before zenoh closes that link, in microseconds. zenoh's default, 5 s, turns a consumer that is alive but slower
/// than its publishers (a learner at saturation, and a standalone router in front of it) into a closed link: what was
/// in flight is dropped and comes again only as the outboxes' copies, after the epoch may have closed (`cabc
/// bench-bus`, issue 73: 595 of 2,752 camera segments missing at the end with 64 actors through zenohd). A minute
/// keeps backpressure as backpressure; a peer that is dead or paused is still dropped by zenoh's lease (10 s).
pub const BLOCK_BEFORE_CLOSE_US: u64 = 60_000_000;

/// Whether the router listening on `listen` would dial itself through the connect endpoint `endpoint`: one of its
/// listeners, or the same protocol and port as a listener (a connect address is the name the other machines use for
/// this one, `tls/<host-A>:7447`, while the listener is `tls/0.0.0.0:7447`). A standalone router on another machine
/// must therefore listen on another port than the learner (deploy/SCALE-OUT.md, §2).
pub fn dials_itself(endpoint: &str, listen: &[String]) -> bool {
    listen.iter().any(|l| {
        l == endpoint || (proto_port(l).is_some() && proto_port(l) == proto_port(endpoint))
    })
}

/// An endpoint's protocol and port: `tls/host-a:7447?x` -> (`tls`, `7447`).
pub(crate) fn proto_port(endpoint: &str) -> Option<(&str, &str)> {
    let (proto, rest) = endpoint.split_once('/')?;
    let address = rest.split(['?', '#']).next()?;
    let (_, port) = address.rsplit_once(':')?;
    Some((proto, port))
}

/// Builds the zenoh configuration of the process `component` (`learner`, `actor/<id>`, ...): endpoints from the
/// run configuration, and with `[bus.security]` its certificate (or password) and, for the learner, the access
/// control of `keys`'s run.
pub fn zenoh_config(
    bus: &BusSection,
    role: Role,
    keys: &Keys,
    component: &str,
) -> Result<zenoh::Config, BusError> {
    let mut config = zenoh::Config::default();
    for (key, value) in settings(bus, role, keys, component)? {
        config
            .insert_json5(key, &value)
            .map_err(|e| BusError::Config {
                key,
                value: value.clone(),
                why: e.to_string(),
            })?;
    }
    Ok(config)
}

/// The settings of [`zenoh_config`] as (`insert_json5` key, JSON value) pairs, in order (also the body of
/// [`zenohd::config`]).
pub fn settings(
    bus: &BusSection,
    role: Role,
    keys: &Keys,
    component: &str,
) -> Result<Vec<(&'static str, String)>, BusError> {
    let mut config = Vec::new();
    let endpoints = |list: &[String]| serde_json::to_string(list).expect("strings serialise");
    if role == Role::Listen {
        for e in bus.connect.iter().filter(|e| dials_itself(e, &bus.listen)) {
            tracing::debug!(endpoint = %e, "not dialled: one of this router's own listeners");
        }
    }
    match role {
        Role::Listen => {
            config.push(("mode", "\"router\"".into()));
            config.push(("listen/endpoints", endpoints(&bus.listen)));
            // A standalone zenohd (runs over several machines): join it through the connect endpoints that are
            // not this process's own listeners ([`dials_itself`]).
            let routers: Vec<String> = bus
                .connect
                .iter()
                .filter(|e| !dials_itself(e, &bus.listen))
                .cloned()
                .collect();
            if !routers.is_empty() {
                // The access control of a router applies to every transport, a router's too: a learner that is
                // itself a router would drop what the standalone one forwards. It joins as a client (no listener).
                if bus.security.enabled() {
                    return Err(BusError::Config {
                        key: "bus.listen",
                        value: format!("{:?}", bus.listen),
                        why: format!(
                            "with [bus.security], a learner joining the standalone router {routers:?} is its \
                             client: set bus.listen = [] (deploy/SCALE-OUT.md §2)"
                        ),
                    });
                }
                config.push(("connect/endpoints", endpoints(&routers)));
            }
        }
        Role::Connect => {
            config.push(("mode", "\"client\"".into()));
            config.push(("connect/endpoints", endpoints(&bus.connect)));
            // Wait for the router (it may start later) and never give up on it.
            config.push(("connect/timeout_ms", "-1".into()));
            config.push(("connect/exit_on_failure", "false".into()));
        }
    }
    config.push((
        "scouting/multicast/enabled",
        bus.multicast_scouting.to_string(),
    ));

    // No payload larger than the codec takes is reassembled (zenoh's default is 1 GiB).
    config.push((
        "transport/link/rx/max_message_size",
        MAX_MESSAGE.to_string(),
    ));
    // Backpressure, not a closed link, while a consumer is slower than its publishers.
    config.push((
        "transport/link/tx/queue/congestion_control/block/wait_before_close",
        BLOCK_BEFORE_CLOSE_US.to_string(),
    ));

    if bus.security.enabled() {
        // Command-line endpoints (`--connect`) bypass the configuration's validation.
        let plain = bus
            .listen
            .iter()
            .chain(&bus.connect)
            .find(|e| !e.starts_with("tls/"));
        if let Some(e) = plain {
            return Err(BusError::Config {
                key: "bus.listen / bus.connect",
                value: e.clone(),
                why: "bus.security needs tls/ endpoints".into(),
            });
        }
    }
    config.extend(security::settings(&bus.security, keys, role, component)?);
    Ok(config)
}

/// Counts messages refused by the codec (foreign, malformed, other schema), per process.
#[derive(Clone, Default, Debug)]
pub struct Rejects(Arc<AtomicU64>);

impl Rejects {
    pub fn count(&self) -> u64 {
        self.0.load(Ordering::Relaxed)
    }
    fn bump(&self) -> u64 {
        self.0.fetch_add(1, Ordering::Relaxed) + 1
    }

    /// Counts and logs (warn) a message that decoded but is refused: `why` (it came on another's key, ...).
    pub fn refuse(&self, key: &str, why: &str) {
        let n = self.bump();
        tracing::warn!(key, rejected = n, "refused a message: {why}");
    }
}

/// Now, in milliseconds since the Unix epoch (a publication's time).
pub(crate) fn unix_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

/// Decodes a payload received on `key`; a refused one is counted and logged (warn), never fatal.
pub fn decode_sample<M: Message>(key: &str, bytes: &[u8], rejects: &Rejects) -> Option<M> {
    match codec::decode::<M>(bytes) {
        Ok(m) => Some(m),
        Err(e) => {
            let n = rejects.bump();
            tracing::warn!(
                key,
                bytes = bytes.len(),
                rejected = n,
                "refused a message: {e}"
            );
            None
        }
    }
}

/// The zenoh encoding of a cabc message: bytes with the schema named, e.g. `application/octet-stream;cabc/TrajMessage/1`.
pub fn encoding_of<M: Message>() -> Encoding {
    Encoding::APPLICATION_OCTET_STREAM.with_schema(format!(
        "cabc/{}/{}",
        M::NAME,
        codec::SCHEMA_VERSION
    ))
}

/// A process's metrics on the bus (`metrics/<component>`, [`Bus::metrics_out`]): what it publishes for people watching
/// the run, and the messages its bus refused so far.
#[derive(Clone)]
pub struct MetricsOut {
    session: Session,
    key: String,
    rejects: Rejects,
}

impl MetricsOut {
    /// Publishes `value` (JSON), blocking; dropped under congestion, and a failure is logged, never fatal.
    pub fn publish(&self, value: &str) {
        let put = self
            .session
            .put(&self.key, value.to_string())
            .encoding(Encoding::APPLICATION_JSON)
            .congestion_control(CongestionControl::Drop)
            .wait();
        if let Err(e) = put {
            tracing::warn!("publishing metrics: {e}");
        }
    }

    /// Messages this process's bus refused so far ([`Rejects`]).
    pub fn rejected(&self) -> u64 {
        self.rejects.count()
    }
}

/// A process's handle on the bus.
pub struct Bus {
    pub session: Session,
    pub keys: Keys,
    pub rejects: Rejects,
    component: String,
    _alive: LivelinessToken,
}

impl Bus {
    /// Opens the session of the process `component` and declares its liveliness token `alive/<component>`.
    /// Blocking (zenoh's own runtime does the work), so async callers use it too, at start-up.
    pub fn join(
        bus: &BusSection,
        role: Role,
        keys: Keys,
        component: &str,
    ) -> Result<Bus, BusError> {
        let config = zenoh_config(bus, role, &keys, component)?;
        let session = zenoh::open(config).wait().map_err(zerr)?;
        let alive = session
            .liveliness()
            .declare_token(keys.alive(component))
            .wait()
            .map_err(zerr)?;
        Ok(Bus {
            session,
            keys,
            rejects: Rejects::default(),
            component: component.to_string(),
            _alive: alive,
        })
    }

    /// [`Bus::put`], blocking.
    pub fn put_blocking<M: Message>(&self, key: &str, message: &M) -> Result<(), BusError> {
        self.session
            .put(key, codec::encode(message))
            .encoding(encoding_of::<M>())
            .congestion_control(CongestionControl::Block)
            .wait()
            .map_err(zerr)
    }

    /// Publishes a message encoded once ([`codec::encode`] into `bytes::Bytes`), without copying it: the policy's
    /// weights are held for the queryable and published (again) from the same buffer.
    pub fn put_encoded_blocking<M: Message>(
        &self,
        key: &str,
        encoded: bytes::Bytes,
    ) -> Result<(), BusError> {
        self.session
            .put(key, encoded)
            .encoding(encoding_of::<M>())
            .congestion_control(CongestionControl::Block)
            .wait()
            .map_err(zerr)
    }

    /// This process's metrics key and refused count apart from the bus ([`MetricsOut`]), for a writer that lives
    /// beside the one that holds the bus (the learner's sink of its records, beside the actors' port).
    pub fn metrics_out(&self) -> MetricsOut {
        MetricsOut {
            session: self.session.clone(),
            key: self.keys.metrics(&self.component),
            rejects: self.rejects.clone(),
        }
    }

    /// [`Bus::metrics`], blocking ([`MetricsOut::publish`]); a failure is logged, never fatal.
    pub fn metrics_blocking(&self, value: &str) {
        self.metrics_out().publish(value);
    }

    /// [`Bus::close`], blocking.
    pub fn close_blocking(self) -> Result<(), BusError> {
        self.session.close().wait().map_err(zerr)
    }

    pub fn component(&self) -> &str {
        &self.component
    }

    /// Publishes a message reliably (zenoh's default reliability; blocks under congestion rather than dropping).
    pub async fn put<M: Message>(&self, key: &str, message: &M) -> Result<(), BusError> {
        self.session
            .put(key, codec::encode(message))
            .encoding(encoding_of::<M>())
            .congestion_control(CongestionControl::Block)
            .await
            .map_err(zerr)
    }

    /// Publishes this component's metrics as JSON on `metrics/<component>` (readable with the zenoh CLI).
    pub async fn metrics(&self, value: &serde_json::Value) -> Result<(), BusError> {
        self.session
            .put(self.keys.metrics(&self.component), value.to_string())
            .encoding(Encoding::APPLICATION_JSON)
            .congestion_control(CongestionControl::Drop)
            .await
            .map_err(zerr)
    }

    /// Closes the session (the liveliness token goes with it).
    pub async fn close(self) -> Result<(), BusError> {
        self.session.close().await.map_err(zerr)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(bus: &BusSection, role: Role) -> Result<zenoh::Config, BusError> {
        let component = if role == Role::Listen {
            "learner"
        } else {
            "actor/actor-0"
        };
        zenoh_config(bus, role, &Keys::new("r").unwrap(), component)
    }

    #[test]
    fn config_of_each_role_is_valid() {
        let bus = BusSection::default();
        config(&bus, Role::Listen).unwrap();
        config(&bus, Role::Connect).unwrap();
    }

    #[test]
    fn the_listener_joins_a_router_but_never_itself() {
        let bus = BusSection {
            listen: vec!["tcp/127.0.0.1:7448".into()],
            connect: vec!["tcp/10.0.0.1:7447".into()],
            ..BusSection::default()
        };
        let json = config(&bus, Role::Listen)
            .unwrap()
            .get_json("connect/endpoints")
            .unwrap();
        assert!(json.contains("tcp/10.0.0.1:7447"), "{json}");
        let json = config(&BusSection::default(), Role::Listen)
            .unwrap()
            .get_json("connect/endpoints")
            .unwrap();
        assert!(!json.contains("7447"), "{json}");
    }

    /// Issue 21: the guide's learner (`listen = tls/0.0.0.0:7447`, `connect = tls/<host-A>:7447`) does not dial
    /// itself; a router on another port is still joined.
    #[test]
    fn the_guides_learner_does_not_dial_itself() {
        let listen = vec!["tls/0.0.0.0:7447".to_string()];
        assert!(dials_itself("tls/10.200.0.1:7447", &listen));
        assert!(dials_itself("tls/0.0.0.0:7447", &listen));
        assert!(!dials_itself("tls/10.200.0.1:7448", &listen));
        assert!(
            !dials_itself("tcp/10.200.0.1:7447", &listen),
            "another protocol"
        );
        assert!(dials_itself(
            "tls/[::1]:7447",
            &["tls/[::]:7447".to_string()]
        ));
        let bus = BusSection {
            listen,
            connect: vec![
                "tls/learner.example:7447".into(),
                "tls/router.example:7450".into(),
            ],
            ..BusSection::default()
        };
        let json = config(&bus, Role::Listen)
            .unwrap()
            .get_json("connect/endpoints")
            .unwrap();
        assert!(!json.contains("learner.example"), "{json}");
        assert!(json.contains("router.example:7450"), "{json}");
    }

    #[test]
    fn a_bad_endpoint_is_refused_with_its_key() {
        let bus = BusSection {
            listen: vec!["not an endpoint".into()],
            ..BusSection::default()
        };
        let err = config(&bus, Role::Listen).unwrap_err().to_string();
        assert!(err.contains("listen/endpoints"), "{err}");
    }

    #[test]
    fn zenoh_reassembles_no_message_larger_than_the_codec_takes() {
        for role in [Role::Listen, Role::Connect] {
            let keys = Keys::new("r").unwrap();
            let config = zenoh_config(&BusSection::default(), role, &keys, "learner").unwrap();
            let json = config
                .get_json("transport/link/rx/max_message_size")
                .unwrap();
            assert_eq!(json, MAX_MESSAGE.to_string());
        }
    }

    #[test]
    fn a_slow_consumer_holds_its_publishers_back_rather_than_losing_its_link() {
        for role in [Role::Listen, Role::Connect] {
            let keys = Keys::new("r").unwrap();
            let config = zenoh_config(&BusSection::default(), role, &keys, "learner").unwrap();
            let json = config
                .get_json("transport/link/tx/queue/congestion_control/block/wait_before_close")
                .unwrap();
            assert_eq!(json, BLOCK_BEFORE_CLOSE_US.to_string());
        }
    }

    #[test]
    fn rejects_are_counted() {
        let rejects = Rejects::default();
        assert!(decode_sample::<cabc_proto::messages::Stop>("k", b"junk", &rejects).is_none());
        assert!(
            decode_sample::<cabc_proto::messages::Stop>("k", b"CABCxxxxxx", &rejects).is_none()
        );
        assert_eq!(rejects.count(), 2);
    }
}
