//! `tracing` set up the same way in every binary: human-readable lines on stderr, `RUST_LOG` respected (default
//! `info`), and, once the process knows its run ([`log_to_file`]), the same lines appended to
//! `<runs_dir>/<run>/logs/<component>.log`, however the process was started. A panic is logged too, so that it
//! lands in that file.

use std::fs::{File, OpenOptions};
use std::io::{self, Write};
use std::path::Path;
use std::sync::{Mutex, OnceLock};
use tracing_subscriber::fmt::MakeWriter;
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;
use tracing_subscriber::{fmt, EnvFilter};

/// Set by a launcher that already writes each process's stderr to its log file (`deploy/run-local.sh`): no second
/// copy.
pub const NO_LOG_FILE: &str = "CABC_NO_LOG_FILE";

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
    let filter = EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| EnvFilter::new("info,zenoh=warn,zenoh_transport=warn"));
    let installed = tracing_subscriber::registry()
        .with(filter)
        .with(fmt::layer().with_writer(std::io::stderr).with_target(false))
        .with(
            fmt::layer()
                .with_writer(ToFile)
                .with_ansi(false)
                .with_target(false),
        )
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

/// `<runs_dir>/<run>/logs/<component>.log` of a run: where each process logs ([`log_to_file`]).
pub fn log_path(config: &crate::config::RunConfig, component: &str) -> std::path::PathBuf {
    Path::new(&config.run.runs_dir)
        .join(&config.run.name)
        .join("logs")
        .join(format!("{}.log", component.replace('/', "-")))
}
