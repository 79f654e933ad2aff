//! The operating system's side of supervision: the supervisor's own Ctrl-C and SIGTERM as a flag, a child process
//! started with its log (and, on Linux, ended with its supervisor), how a process ended in words, and whether a bus
//! endpoint accepts connections yet.

use crate::roster::{Role, Spec};
use std::fs::{File, OpenOptions};
use std::io::{BufRead, BufReader, Write};
use std::net::{TcpStream, ToSocketAddrs};
#[cfg(target_os = "linux")]
use std::os::unix::process::CommandExt;
use std::path::PathBuf;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

static INTERRUPTED: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    INTERRUPTED.store(true, Ordering::SeqCst);
}

/// Ctrl-C and SIGTERM set a flag that the loop reads (the processes of a terminal's Ctrl-C get it themselves too).
pub(crate) fn catch_signals() {
    let handler = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
    // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
    unsafe {
        libc::signal(libc::SIGINT, handler);
        libc::signal(libc::SIGTERM, handler);
    }
}

pub(crate) fn interrupted() -> bool {
    INTERRUPTED.load(Ordering::SeqCst)
}

/// "exit 1", "signal 9 (SIGKILL)".
pub fn describe(status: ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    match (status.code(), status.signal()) {
        (Some(code), _) => format!("exit {code}"),
        (None, Some(9)) => "signal 9 (SIGKILL)".into(),
        (None, Some(signal)) => format!("signal {signal}"),
        (None, None) => "an unknown end".into(),
    }
}

/// Starts `spec`'s program with `args`, its stderr (and stdout) appended to its log; the learner's stderr on the
/// terminal under `brief` (it draws its progress bar and writes its own log file), else to its log and this process's
/// stderr.
pub(crate) fn spawn(spec: &Spec, args: &[String], brief: bool) -> std::io::Result<Child> {
    append(
        &spec.log,
        &format!(
            "[supervise] starting {} {}",
            spec.program.display(),
            args.join(" ")
        ),
    );
    let log = OpenOptions::new()
        .create(true)
        .append(true)
        .open(&spec.log)?;
    let mut command = Command::new(&spec.program);
    command.args(args).stdin(Stdio::null());
    // A supervisor that dies takes its processes with it (SIGINT: each ends cleanly) instead of leaving them
    // unsupervised; its own supervisor (or the user) starts the run again with --resume. PR_SET_PDEATHSIG is Linux's
    // alone: elsewhere the processes outlive a supervisor killed with SIGKILL.
    // SAFETY: prctl(2) is async-signal-safe, as a pre_exec closure must be.
    #[cfg(target_os = "linux")]
    unsafe {
        command.pre_exec(|| {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGINT) == -1 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let mut tee = false;
    if spec.role == Role::Learner {
        if brief {
            command
                .env_remove(cabc_proto::telemetry::NO_LOG_FILE)
                .env(cabc_proto::telemetry::BRIEF, "1")
                .stderr(Stdio::inherit());
        } else {
            command
                .env(cabc_proto::telemetry::NO_LOG_FILE, "1")
                .stderr(Stdio::piped());
            tee = true;
        }
    } else {
        command
            .env(cabc_proto::telemetry::NO_LOG_FILE, "1")
            .stdout(log.try_clone()?)
            .stderr(log);
    }
    let mut child = command.spawn()?;
    if tee {
        if let Some(stderr) = child.stderr.take() {
            tee_lines(stderr, spec.log.clone());
        }
    }
    Ok(child)
}

/// Whether something accepts TCP connections at `(host, port)`.
pub(crate) fn accepting((host, port): &(String, u16)) -> bool {
    let Ok(addresses) = (host.as_str(), *port).to_socket_addrs() else {
        return false;
    };
    addresses
        .into_iter()
        .any(|a| TcpStream::connect_timeout(&a, Duration::from_millis(200)).is_ok())
}

/// Appends a line to a log (a failure is said on stderr, never fatal).
pub(crate) fn append(log: &PathBuf, line: &str) {
    let written = OpenOptions::new()
        .create(true)
        .append(true)
        .open(log)
        .and_then(|mut f| writeln!(f, "{line}"));
    if let Err(e) = written {
        eprintln!("[supervise] warning: writing {}: {e}", log.display());
    }
}

/// Copies a process's stderr, line by line, to this process's stderr and to its log.
fn tee_lines(stderr: std::process::ChildStderr, log: PathBuf) {
    std::thread::spawn(move || {
        let mut file: Option<File> = OpenOptions::new().create(true).append(true).open(&log).ok();
        for line in BufReader::new(stderr).lines() {
            let Ok(line) = line else { break };
            eprintln!("{line}");
            if let Some(f) = file.as_mut() {
                let _ = writeln!(f, "{line}");
            }
        }
    });
}
