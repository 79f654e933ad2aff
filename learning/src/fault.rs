//! Fault injection for the crash tests: `CABC_FAULT=<point>:<n>` makes the process abort (as a SIGKILL would end it:
//! no destructor, no flush) the n-th time it reaches `point`. Unset, as in every real run, it costs one environment
//! read per process. Points: `checkpoint-between-renames` (a checkpoint commit after `checkpoint/` became
//! `checkpoint.old/` and before `checkpoint.tmp/` became `checkpoint/`).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::OnceLock;

static PLAN: OnceLock<Option<(String, u64)>> = OnceLock::new();
static REACHED: AtomicU64 = AtomicU64::new(0);

/// Aborts the process if `CABC_FAULT` names `point` and this is its n-th time.
pub fn point(point: &str) {
    let plan = PLAN.get_or_init(|| {
        let value = std::env::var("CABC_FAULT").ok()?;
        let (name, n) = value.rsplit_once(':')?;
        Some((name.to_string(), n.parse().ok()?))
    });
    if let Some((name, n)) = plan {
        if name == point && REACHED.fetch_add(1, Ordering::SeqCst) + 1 == *n {
            eprintln!("CABC_FAULT: aborting at {point} (time {n})");
            std::process::abort();
        }
    }
}
