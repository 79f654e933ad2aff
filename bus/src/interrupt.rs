//! Ctrl-C as a flag: the blocking loops of the binaries poll it between waits of at most a fraction of a second, so
//! one Ctrl-C ends a process cleanly (the learner keeps its last checkpoint, actors flush their epoch).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// Set once Ctrl-C (SIGINT) arrived.
#[derive(Clone, Debug, Default)]
pub struct Interrupt(Arc<AtomicBool>);

impl Interrupt {
    /// A flag set by the process's Ctrl-C (a watcher thread; the default handler, which would kill the process
    /// mid-write, is replaced).
    pub fn on_ctrl_c() -> Interrupt {
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
                        if rt.block_on(tokio::signal::ctrl_c()).is_ok() {
                            tracing::info!("interrupted (Ctrl-C)");
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
