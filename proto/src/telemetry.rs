//! `tracing` set up the same way in every binary: human-readable lines on stderr, `RUST_LOG` respected (default
//! `info`), and, once the process knows its run ([`log_to_file`]), the same lines appended to
//! `<runs_dir>/<run>/logs/<component>.log`, however the process was started. A panic is logged too, so that it
//! lands in that file.

use std::collections::BTreeMap;
use std::fs::{File, OpenOptions};
use std::io::{self, Write};
use std::path::Path;
use std::sync::{Mutex, OnceLock};
use tracing::field::{Field, Visit};
use tracing::{Event, Level, Metadata, Subscriber};
use tracing_subscriber::filter::{FilterExt, LevelFilter, Targets};
use tracing_subscriber::fmt::MakeWriter;
use tracing_subscriber::layer::{Context, Filter, Layer, SubscriberExt};
use tracing_subscriber::util::SubscriberInitExt;
use tracing_subscriber::{fmt, EnvFilter};

/// Set by a launcher that already writes each process's stderr to its log file (`deploy/run-local.sh`): no second
/// copy.
pub const NO_LOG_FILE: &str = "CABC_NO_LOG_FILE";

/// Set by `deploy/run-local.sh` for a learner whose stderr is a terminal (issue 59): there its stderr shows
/// warnings and errors alone, beside the progress bar and the short lines the learner draws itself, while its log
/// file (which it then writes itself) keeps every line. Ignored when stderr is not a terminal or `RUST_LOG` is set.
pub const BRIEF: &str = "CABC_TERMINAL_BRIEF";

/// Whether this process's stderr is brief ([`BRIEF`]): set, stderr a terminal, and no `RUST_LOG`.
pub fn brief() -> bool {
    use std::io::IsTerminal;
    std::env::var_os(BRIEF).is_some()
        && std::env::var_os("RUST_LOG").is_none()
        && std::io::stderr().is_terminal()
}

/// The log file, once known.
static FILE: OnceLock<Mutex<Option<File>>> = OnceLock::new();

fn file() -> &'static Mutex<Option<File>> {
    FILE.get_or_init(|| Mutex::new(None))
}

/// Writes to the log file when there is one, else nowhere.
struct ToFile;

impl Write for ToFile {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        match file().lock().unwrap_or_else(|e| e.into_inner()).as_mut() {
            Some(f) => f.write(buf),
            None => Ok(buf.len()),
        }
    }

    fn flush(&mut self) -> io::Result<()> {
        match file().lock().unwrap_or_else(|e| e.into_inner()).as_mut() {
            Some(f) => f.flush(),
            None => Ok(()),
        }
    }
}

impl<'a> MakeWriter<'a> for ToFile {
    type Writer = ToFile;

    fn make_writer(&'a self) -> ToFile {
        ToFile
    }
}

/// Installs the global subscriber and the panic hook. Safe to call twice (the second call is a no-op).
pub fn init() {
    fn env() -> EnvFilter {
        EnvFilter::try_from_default_env()
            .unwrap_or_else(|_| EnvFilter::new("info,zenoh=warn,zenoh_transport=warn"))
    }
    fn filter<S: Subscriber>() -> impl Filter<S> {
        quiet(env())
    }
    // On a terminal that the process draws on itself ([`brief`]): warnings and errors alone.
    fn terminal<S: Subscriber>() -> impl Filter<S> {
        quiet(match brief() {
            true => EnvFilter::new("warn"),
            false => env(),
        })
    }
    let installed = tracing_subscriber::registry()
        .with(
            fmt::layer()
                .with_writer(std::io::stderr)
                .with_target(false)
                .with_filter(terminal()),
        )
        .with(
            fmt::layer()
                .with_writer(ToFile)
                .with_ansi(false)
                .with_target(false)
                .with_filter(filter()),
        )
        .with(AclDenials.with_filter(Targets::new().with_target(ACL_TARGET, Level::TRACE)))
        .try_init()
        .is_ok();
    if installed {
        let default = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            tracing::error!("panic: {info}");
            default(info);
        }));
    }
}

/// zenoh 1.10.2's ERROR lines, by (target, message), for a client withdrawing a declaration that the router's
/// access control refused: a subscriber, a queryable, a liveliness token, a liveliness subscriber (its interest).
///
/// The access control checks an undeclaration on its way in only when it names its key, and zenoh's own session
/// never does (`src/api/session.rs:1842`, an empty `ext_wire_expr`); so it lets it pass, "it will be rejected by
/// the routing logic if its associated declaration was denied" (`src/net/routing/interceptor/access_control.rs:546`,
/// also 581, 617, and 672 for an interest's end). The routing of the router's clients (the `broker` HAT) then finds
/// no such declaration of that client, logs one of these lines at ERROR and does nothing else: nothing was
/// registered, nothing is undone (`src/net/routing/hat/broker/pubsub.rs:325`, `queries.rs:380`, `token.rs:188`,
/// `interests.rs:477`). So a denial that was handled, and already counted and warned ([`acl_denials`]), would end in
/// an ERROR each time the denied client leaves (issue 47 item 8). Exactly these four lines are kept out of the logs;
/// every other event of these modules, and every other ERROR, is not.
const REFUSED_UNDECLARATIONS: [(&str, &str); 4] = [
    (
        "zenoh::net::routing::hat::broker::pubsub",
        "Unknown subscriber",
    ),
    ("zenoh::net::routing::hat::broker::queries", "Unknown id"),
    ("zenoh::net::routing::hat::broker::token", "Unknown token"),
    (
        "zenoh::net::routing::hat::broker::interests",
        "Unknown interest",
    ),
];

/// The filter that drops [`REFUSED_UNDECLARATIONS`] from the log lines (stderr and the run's file); it passes every
/// other event.
struct RefusedUndeclarations;

impl RefusedUndeclarations {
    fn drops(event: &Event<'_>) -> bool {
        let meta = event.metadata();
        if *meta.level() != Level::ERROR {
            return false;
        }
        let Some((_, message)) = REFUSED_UNDECLARATIONS
            .iter()
            .find(|(target, _)| *target == meta.target())
        else {
            return false;
        };
        let mut m = Message(String::new());
        event.record(&mut m);
        m.0 == *message
    }
}

impl<S: Subscriber> Filter<S> for RefusedUndeclarations {
    fn enabled(&self, _: &Metadata<'_>, _: &Context<'_, S>) -> bool {
        true
    }

    fn event_enabled(&self, event: &Event<'_>, _: &Context<'_, S>) -> bool {
        !Self::drops(event)
    }

    /// No bound of its own (combined with `RUST_LOG`'s filter, that one's bound holds).
    fn max_level_hint(&self) -> Option<LevelFilter> {
        Some(LevelFilter::TRACE)
    }
}

/// `filter` less [`REFUSED_UNDECLARATIONS`]: the filter of the log lines.
fn quiet<S: Subscriber, F: Filter<S>>(filter: F) -> impl Filter<S> {
    filter.and(RefusedUndeclarations)
}

/// From now on, also appends every log line to `path` (its folder created), unless [`NO_LOG_FILE`] is set. A file
/// that cannot be opened is reported on stderr and the process goes on without it.
pub fn log_to_file(path: &Path) {
    if std::env::var_os(NO_LOG_FILE).is_some() {
        return;
    }
    let opened = path
        .parent()
        .map_or(Ok(()), std::fs::create_dir_all)
        .and_then(|_| OpenOptions::new().create(true).append(true).open(path));
    match opened {
        Ok(f) => {
            *file().lock().unwrap_or_else(|e| e.into_inner()) = Some(f);
            tracing::info!(path = %path.display(), "logging to this file too");
        }
        Err(e) => tracing::warn!(path = %path.display(), "no log file: {e}"),
    }
}

/// Logs to `<runs_dir>/<run>/logs/<component>.log` of `config`'s run too ([`log_to_file`]).
pub fn log_run(config: &crate::config::RunConfig, component: &str) {
    log_to_file(
        &Path::new(&config.run.runs_dir)
            .join(&config.run.name)
            .join("logs")
            .join(format!("{}.log", component.replace('/', "-"))),
    );
}

/// Where zenoh 1.10 logs its access-control decisions, at TRACE. A fresh decision logs one line per subject the
/// client matches, "<zid> on <subject> is unauthorized to <action> on <key>" (or "authorized", which ends the
/// decision as allowed), and nothing once all denied; a cached one logs "Using cached result: <zid> is
/// unauthorized to ...", one line per message.
const ACL_TARGET: &str = "zenoh::net::routing::interceptor::access_control";

/// Messages an access control dropped, by "<subject>: <action> on <key>", read off zenoh's decision lines
/// ([`ACL_TARGET`]): those of this process's router (the tracing layer) or of a zenohd's log
/// ([`acl_denials_in_log`]).
#[derive(Default)]
struct AclLedger {
    by: BTreeMap<String, u64>,
    /// The subject (certificate or user name) of each zenoh id seen in a fresh decision.
    subjects: BTreeMap<String, String>,
    /// Each thread's place in its sequence of decision lines (zenoh decides a message on one thread).
    threads: BTreeMap<String, ThreadState>,
}

/// A thread's last fresh denial (zid, what, subject): a permission for the same right after it undoes it.
type Pending = Option<(String, String, String)>;

/// While zenoh fills its permission cache for a key (a line "caching permissions for ..."), it decides every kind
/// of message for it, the last being a liveliness subscriber: these decisions are no message, and are not counted.
#[derive(Clone, Copy, Default, PartialEq, Eq)]
enum Caching {
    #[default]
    No,
    Yes,
    /// At the last of the cache's decisions.
    Last,
}

#[derive(Default)]
struct ThreadState {
    pending: Pending,
    caching: Caching,
}

/// The action of the cache's last decision.
const CACHE_LAST: &str = "Declare Liveliness Subscriber (";

/// The client's name in a subject's description: its certificate's common name or its user name (zenoh prints
/// `Interface(lo)+CertCommonName(actor/actor-0)+Transport(Tls)+...`), else the description.
fn subject_name(subject: &str) -> String {
    for tag in ["CertCommonName(", "Username("] {
        if let Some(rest) = subject.split_once(tag).map(|(_, r)| r) {
            if let Some((name, _)) = rest.split_once(')') {
                return name.to_string();
            }
        }
    }
    subject.to_string()
}

impl AclLedger {
    fn count(&mut self, who: &str, what: &str) {
        *self.by.entry(format!("{who}: {what}")).or_insert(0) += 1;
    }

    /// One decision line of `thread`.
    fn line(&mut self, thread: &str, text: &str) {
        if text.contains("caching permissions for") {
            self.threads.entry(thread.to_string()).or_default().caching = Caching::Yes;
            return;
        }
        let (who, what, allowed) = match text.split_once(" is unauthorized to ") {
            Some((who, what)) => (who, what, false),
            None => match text.split_once(" is authorized to ") {
                Some((who, what)) => (who, what, true),
                None => return,
            },
        };
        let (zid, subject) = match who.strip_prefix("Using cached result: ") {
            Some(zid) => {
                let subject = self.subjects.get(zid).cloned();
                (zid, subject.unwrap_or_else(|| zid.to_string()))
            }
            None => match who.split_once(" on ") {
                Some((zid, subject)) => {
                    let subject = subject_name(subject);
                    self.subjects.insert(zid.to_string(), subject.clone());
                    (zid, subject)
                }
                None => return,
            },
        };
        let cached = who.starts_with("Using cached result: ");
        let state = self.threads.entry(thread.to_string()).or_default();
        state.caching = match (state.caching, cached || !what.starts_with(CACHE_LAST)) {
            (Caching::No, _) => Caching::No,
            (_, false) => Caching::Last,
            (Caching::Yes, true) => Caching::Yes,
            (Caching::Last, true) => Caching::No,
        };
        let caching = state.caching != Caching::No;
        let pending = state.pending.take();
        if caching {
            return;
        }
        if allowed {
            // A client matched by several subjects: a first subject's denial, then another's permission, is one
            // allowed message.
            if let Some((_, w, s)) = pending.filter(|(z, w, _)| !cached && z == zid && w == what) {
                let key = format!("{s}: {w}");
                if let Some(n) = self.by.get_mut(&key) {
                    *n -= 1;
                    if *n == 0 {
                        self.by.remove(&key);
                    }
                }
            }
            return;
        }
        self.count(&subject, what);
        if !cached {
            let state = self.threads.entry(thread.to_string()).or_default();
            state.pending = Some((zid.into(), what.into(), subject));
        }
    }
}

static LEDGER: OnceLock<Mutex<AclLedger>> = OnceLock::new();

fn ledger() -> &'static Mutex<AclLedger> {
    LEDGER.get_or_init(Default::default)
}

/// The layer that counts zenoh's access-control denials (only that target's events reach it).
struct AclDenials;

struct Message(String);

impl Visit for Message {
    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            self.0 = format!("{value:?}");
        }
    }
}

impl<S: Subscriber> Layer<S> for AclDenials {
    fn on_event(&self, event: &Event<'_>, _: Context<'_, S>) {
        let mut m = Message(String::new());
        event.record(&mut m);
        let thread = format!("{:?}", std::thread::current().id());
        let mut ledger = ledger().lock().unwrap_or_else(|e| e.into_inner());
        ledger.line(&thread, &m.0);
    }
}

/// The messages this process's access control dropped so far, by "<subject>: <action> on <key>" (empty where the
/// process runs no access control: every process but a secured learner).
pub fn acl_denials() -> BTreeMap<String, u64> {
    ledger()
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .by
        .clone()
}

/// The messages dropped according to a zenohd's log written with
/// `RUST_LOG=...,zenoh::net::routing::interceptor::access_control=trace` (colours and all), by
/// "<subject>: <action> on <key>": the decisions read as [`acl_denials`] reads this process's, each thread's lines
/// in their order (zenohd prints `ThreadId(n)` on every line).
pub fn acl_denials_in_log(text: &str) -> BTreeMap<String, u64> {
    let marker = format!("{ACL_TARGET}: ");
    let mut ledger = AclLedger::default();
    for raw in text.lines() {
        let line = strip_ansi(raw);
        let Some((head, message)) = line.split_once(&marker) else {
            continue;
        };
        let thread = head
            .split_whitespace()
            .find(|w| w.starts_with("ThreadId("))
            .unwrap_or_default();
        ledger.line(thread, message);
    }
    ledger.by
}

/// `text` without its terminal colour codes (`ESC [ ... m`).
pub fn strip_ansi(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut chars = text.chars();
    while let Some(c) = chars.next() {
        if c == '\u{1b}' {
            for c in chars.by_ref() {
                if c.is_ascii_alphabetic() {
                    break;
                }
            }
        } else {
            out.push(c);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// zenoh's lines for: an allowed put (one subject denies, another allows), two denied puts, the filling of a
    /// cache (not messages), a cached denial, and an allowed put of another client.
    #[test]
    fn denials_are_counted_once_per_message_and_allowed_ones_not_at_all() {
        let a0 = "Interface(lo)+CertCommonName(actor/actor-0)+Transport(Tls)+z1";
        let lines = [
            format!("z1 on {a0} is unauthorized to Put (ingress) on cabc/r/traj/actor-0"),
            format!("z1 on {a0} is authorized to Put (ingress) on cabc/r/traj/actor-0"),
            format!("z1 on {a0} is unauthorized to Put (ingress) on cabc/r/policy"),
            format!("z1 on {a0} is unauthorized to Put (ingress) on cabc/r/policy"),
            // Filling the cache for a declared key: decisions for every kind of message, none of them a message.
            "ACL (ingress): caching permissions for `cabc/r/traj/*` ...".into(),
            format!("z1 on {a0} is unauthorized to Query (ingress) on cabc/r/traj/*"),
            format!("z1 on {a0} is unauthorized to Declare/Undeclare Subscriber (ingress) on cabc/r/traj/*"),
            format!("z1 on {a0} is unauthorized to Declare Liveliness Subscriber (ingress) on cabc/r/traj/*"),
            format!("z1 on {a0} is unauthorized to Declare Liveliness Subscriber (ingress) on cabc/r/traj/*"),
            "Using cached result: z1 is unauthorized to Declare/Undeclare Subscriber (ingress) on cabc/r/traj/*".into(),
            "z2 on Interface(lo)+Username(observer)+z2 is authorized to Put (ingress) on cabc/r/metrics/observer".into(),
        ];
        let mut ledger = AclLedger::default();
        for line in &lines {
            ledger.line("t", line);
        }
        let d = ledger.by;
        assert_eq!(
            d.get("actor/actor-0: Put (ingress) on cabc/r/policy"),
            Some(&2),
            "two puts: {d:?}"
        );
        let sub = "actor/actor-0: Declare/Undeclare Subscriber (ingress) on cabc/r/traj/*";
        assert_eq!(d.get(sub), Some(&1), "{d:?}");
        assert_eq!(d.values().sum::<u64>(), 3, "{d:?}");
    }

    /// Exactly zenoh's lines for a refused declaration's withdrawal are kept out: not the same message of another
    /// module or at another level, not another ERROR of the same module.
    #[test]
    fn only_the_withdrawals_of_refused_declarations_are_kept_out_of_the_log() {
        #[derive(Clone, Default)]
        struct Buffer(std::sync::Arc<Mutex<Vec<u8>>>);
        impl Write for Buffer {
            fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
                self.0.lock().unwrap().write(buf)
            }
            fn flush(&mut self) -> io::Result<()> {
                Ok(())
            }
        }
        let buffer = Buffer::default();
        let writer = buffer.clone();
        let layer = fmt::layer()
            .with_writer(move || writer.clone())
            .with_ansi(false)
            .with_filter(quiet(EnvFilter::new("info")));
        let subscriber = tracing_subscriber::registry().with(layer);
        tracing::subscriber::with_default(subscriber, || {
            let id = 1u32;
            tracing::error!(target: "zenoh::net::routing::hat::broker::pubsub", id, "Unknown subscriber");
            tracing::error!(target: "zenoh::net::routing::hat::broker::queries", "Unknown id");
            tracing::error!(target: "zenoh::net::routing::hat::broker::token", id, "Unknown token");
            tracing::error!(target: "zenoh::net::routing::hat::broker::interests", "Unknown interest");
            tracing::error!(target: "zenoh::net::routing::hat::broker::pubsub", "Unknown matching status resource");
            tracing::warn!(target: "zenoh::net::routing::hat::broker::pubsub", "Unknown subscriber");
            tracing::error!(target: "zenoh::net::routing::hat::broker::token", "Unknown subscriber");
            tracing::error!("Unknown subscriber");
            tracing::info!("the run goes on");
        });
        let text = String::from_utf8(buffer.0.lock().unwrap().clone()).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 5, "{text}");
        for (line, expected) in lines.iter().zip([
            "ERROR zenoh::net::routing::hat::broker::pubsub: Unknown matching status resource",
            "WARN zenoh::net::routing::hat::broker::pubsub: Unknown subscriber",
            "ERROR zenoh::net::routing::hat::broker::token: Unknown subscriber",
            "ERROR cabc_proto::telemetry::tests: Unknown subscriber",
            "INFO cabc_proto::telemetry::tests: the run goes on",
        ]) {
            let (level, rest) = expected.split_once(' ').unwrap();
            assert!(
                line.contains(level) && line.ends_with(rest),
                "{line:?} is not {expected:?}"
            );
        }
    }

    /// A zenohd's log: coloured, two threads' decisions interleaved (a cache being filled on one while the other
    /// drops a put), and other targets' lines.
    #[test]
    fn a_zenohd_log_is_read_thread_by_thread() {
        let line = |thread: &str, message: &str| {
            format!(
                "\u{1b}[2m2026-11-24T06:56:42.676980Z\u{1b}[0m \u{1b}[35mTRACE\u{1b}[0m rx-1 {thread} \u{1b}[2m{ACL_TARGET}\u{1b}[0m\u{1b}[2m:\u{1b}[0m {message}"
            )
        };
        let a0 = "z1 on Interface(cv1s)+CertCommonName(actor/actor-0)+Transport(Tls)+z1";
        let log = [
            line("ThreadId(09)", "ACL (ingress): caching permissions for `cabc/r/policy` ..."),
            line("ThreadId(11)", &format!("{a0} is unauthorized to Put (ingress) on cabc/r/traj/actor-1")),
            line("ThreadId(09)", &format!("{a0} is unauthorized to Put (ingress) on cabc/r/policy")),
            line("ThreadId(09)", &format!("{a0} is unauthorized to Declare Liveliness Subscriber (ingress) on cabc/r/policy")),
            "2026-11-24T06:56:42Z  INFO main ThreadId(01) zenohd: zenohd v1.10.2".into(),
            line("ThreadId(11)", "Using cached result: z1 is unauthorized to Put (ingress) on cabc/r/traj/actor-1"),
        ]
        .join("\n");
        let d = acl_denials_in_log(&log);
        let mut expected = BTreeMap::new();
        expected.insert(
            "actor/actor-0: Put (ingress) on cabc/r/traj/actor-1".to_string(),
            2,
        );
        assert_eq!(d, expected);
    }
}
