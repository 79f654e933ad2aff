//! Where a QP's time goes, from Clarabel's own timers (`solver.timers`), summed over the QPs solved on this thread
//! while recording is on (`expert-server bench --profile`; issue 75). Off, it costs one thread-local check per QP.
//!
//! Clarabel keeps its timers private and shows them only through `Debug`; the phases are read from that text, by
//! their names in Clarabel's `IPSolver::solve`: "default start", "scale cones", "kkt update" (the KKT matrix's new
//! diagonal, then its numeric LDL factorisation), "kkt solve" (the two triangular solves a step, affine and
//! combined) and the rest of "IP iteration" (residuals, convergence checks, step lengths, the iterate's update).

use std::cell::RefCell;
use std::time::Duration;

use serde::{Deserialize, Serialize};

/// Time per phase, summed over QPs.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SolverPhases {
    /// QPs summed.
    pub qps: u64,
    /// Clarabel's interior-point iterations summed.
    pub iterations: u64,
    /// Handing the QP to Clarabel: `update_P/A/q/b` on a cached solver, or a new solver (its symbolic factorisation).
    pub data: Duration,
    /// Clarabel's "default start": the initial point (one KKT factorisation and solve).
    pub default_start: Duration,
    /// "scale cones": the Nesterov-Todd scalings of the nonnegative cone.
    pub scale_cones: Duration,
    /// "kkt update": the KKT system's diagonal and its numeric LDL factorisation, once an iteration.
    pub kkt_update: Duration,
    /// "kkt solve": the triangular solves, twice an iteration.
    pub kkt_solve: Duration,
    /// The rest of "IP iteration": residuals, convergence checks, step lengths, the iterate's update.
    pub iteration_rest: Duration,
    /// The KKT system of the last QP: its nonzeros (upper triangle) and those of its LDL factor L.
    pub kkt_nnz: usize,
    pub ldl_nnz: usize,
}

impl SolverPhases {
    /// The phases as (name, share of their sum).
    pub fn shares(&self) -> Vec<(&'static str, f64)> {
        let parts = [
            ("data", self.data),
            ("default start", self.default_start),
            ("scale cones", self.scale_cones),
            ("kkt update (factorisation)", self.kkt_update),
            ("kkt solve", self.kkt_solve),
            ("iteration rest", self.iteration_rest),
        ];
        let total: f64 = parts.iter().map(|(_, d)| d.as_secs_f64()).sum();
        parts
            .iter()
            .map(|(n, d)| (*n, d.as_secs_f64() / total.max(f64::MIN_POSITIVE)))
            .collect()
    }
}

thread_local! {
    static RECORDING: RefCell<Option<SolverPhases>> = const { RefCell::new(None) };
}

/// Starts recording on this thread (a recording under way starts over).
pub fn start() {
    RECORDING.with(|r| *r.borrow_mut() = Some(SolverPhases::default()));
}

/// Stops recording on this thread and returns the sums (zero when none was started).
pub fn take() -> SolverPhases {
    RECORDING.with(|r| r.borrow_mut().take().unwrap_or_default())
}

/// Whether this thread records.
pub(super) fn recording() -> bool {
    RECORDING.with(|r| r.borrow().is_some())
}

/// Adds one QP: the time spent handing it over and Clarabel's timers after its solve (their `Debug` text).
pub(super) fn add(data: Duration, iterations: u32, timers_debug: &str, nnz: (usize, usize)) {
    RECORDING.with(|r| {
        if let Some(p) = r.borrow_mut().as_mut() {
            let t = |name: &str| timer(timers_debug, name).unwrap_or_default();
            let ip = t("IP iteration");
            let (scale, update, solve) = (t("scale cones"), t("kkt update"), t("kkt solve"));
            p.qps += 1;
            p.iterations += u64::from(iterations);
            p.data += data;
            p.default_start += t("default start");
            p.scale_cones += scale;
            p.kkt_update += update;
            p.kkt_solve += solve;
            p.iteration_rest += ip.saturating_sub(scale + update + solve);
            (p.kkt_nnz, p.ldl_nnz) = nnz;
        }
    });
}

/// The elapsed time of the timer `name` in the `Debug` text of Clarabel's `Timers`
/// (`"name": InnerTimer { start: None, elapsed: 1.5µs, ...`).
fn timer(text: &str, name: &str) -> Option<Duration> {
    let at = text.find(&format!("\"{name}\": InnerTimer"))?;
    let rest = &text[at..];
    let from = rest.find("elapsed: ")? + "elapsed: ".len();
    let value = &rest[from..];
    let end = value.find([',', ' ', '}'])?;
    parse_duration(&value[..end])
}

/// A `Duration`'s `Debug` text: `1.5s`, `2.25ms`, `13.2µs`, `850ns`.
fn parse_duration(text: &str) -> Option<Duration> {
    let (number, unit) = [("ns", 1e-9), ("µs", 1e-6), ("ms", 1e-3), ("s", 1.0)]
        .iter()
        .find_map(|(suffix, unit)| text.strip_suffix(suffix).map(|n| (n, *unit)))?;
    let seconds = number.parse::<f64>().ok()? * unit;
    (seconds.is_finite() && seconds >= 0.0).then(|| Duration::from_secs_f64(seconds))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations_read_as_debug_writes_them() {
        for d in [
            Duration::from_nanos(850),
            Duration::from_nanos(13_200),
            Duration::from_micros(2_250),
            Duration::from_millis(1_500),
        ] {
            let back = parse_duration(&format!("{d:?}")).unwrap();
            assert!(
                (back.as_secs_f64() - d.as_secs_f64()).abs() < 1e-12,
                "{d:?}"
            );
        }
        assert_eq!(parse_duration("12 parsecs"), None);
    }

    #[test]
    fn a_timer_is_found_by_its_name() {
        let text = r#"Timers { stack: [], subtimers: SubTimersMap({"solve": InnerTimer { start: None, elapsed: 1.2ms, subtimers: SubTimersMap({"IP iteration": InnerTimer { start: None, elapsed: 1ms, subtimers: SubTimersMap({"kkt solve": InnerTimer { start: None, elapsed: 300µs, subtimers: SubTimersMap({}) }}) }}) }}) }"#;
        assert_eq!(timer(text, "kkt solve"), Some(Duration::from_micros(300)));
        assert_eq!(timer(text, "IP iteration"), Some(Duration::from_millis(1)));
        assert_eq!(timer(text, "scale cones"), None);
    }
}
