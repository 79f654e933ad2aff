//! Ctrl-C (and SIGTERM) as a flag: the blocking loops of the binaries poll it between waits of at most a fraction of a
//! second, so one Ctrl-C ends a process cleanly (the learner keeps its last checkpoint, actors flush their epoch).
//! SIGTERM is what a scheduler sends first: Slurm's `scancel`, `scontrol requeue` and preemption signal every process
//! of a job step, then SIGKILL after its grace time (KillWait), so the same clean end must fit in it.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// Set once Ctrl-C (SIGINT) arrived.
#[derive(Clone, Debug, Default)]
pub struct Interrupt(Arc<AtomicBool>);

impl Interrupt {
    /// A flag set by the process's Ctrl-C or SIGTERM (a watcher thread; the default handlers, which would kill the
    /// process mid-write, are replaced).
    pub fn on_signals() -> Interrupt {
        let flag = Interrupt::default();
        let set = flag.clone();
        let watcher = std::thread::Builder::new()
            .name("ctrl-c".into())
            .spawn(move || {
                let runtime = tokio::runtime::Builder::new_current_thread()
                    .enable_all()
                    .build();
                match runtime {
                    Ok(rt) => {
                        if let Some(which) = rt.block_on(first_signal()) {
                            tracing::info!("interrupted ({which})");
                            set.0.store(true, Ordering::SeqCst);
                        }
                    }
                    Err(e) => tracing::warn!("no Ctrl-C watcher: {e}"),
                }
            });
        if let Err(e) = watcher {
            tracing::warn!("no Ctrl-C watcher: {e}");
        }
        flag
    }

    pub fn is_set(&self) -> bool {
        self.0.load(Ordering::SeqCst)
    }

    /// Sets the flag (tests, or a stop decided in-process).
    pub fn set(&self) {
        self.0.store(true, Ordering::SeqCst);
    }
}

/// The first of Ctrl-C (SIGINT) and SIGTERM to arrive, by name; None when neither can be watched.
async fn first_signal() -> Option<&'static str> {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        match signal(SignalKind::terminate()) {
            Ok(mut term) => tokio::select! {
                c = tokio::signal::ctrl_c() => c.ok().map(|()| "Ctrl-C"),
                _ = term.recv() => Some("SIGTERM"),
            },
            Err(e) => {
                tracing::warn!("no SIGTERM watcher: {e}");
                tokio::signal::ctrl_c().await.ok().map(|()| "Ctrl-C")
            }
        }
    }
    #[cfg(not(unix))]
    {
        tokio::signal::ctrl_c().await.ok().map(|()| "Ctrl-C")
    }
}
