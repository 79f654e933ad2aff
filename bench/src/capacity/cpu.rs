//! CPU time of this process, its threads and other processes, for the learner's cost per step: `getrusage` of the
//! process (threads that ended included) and of the calling thread, `/proc/<pid>/stat` of the actors' and the
//! router's processes, `/proc/self/task/*` for a breakdown by thread name.

use std::collections::BTreeMap;
use std::time::Duration;

fn rusage(who: libc::c_int) -> Duration {
    let mut usage = std::mem::MaybeUninit::<libc::rusage>::zeroed();
    // SAFETY: getrusage writes a `rusage` into the pointer it is given and reads nothing else; a zeroed one is
    // valid should it fail (then the time reads 0).
    let usage = unsafe {
        libc::getrusage(who, usage.as_mut_ptr());
        usage.assume_init()
    };
    let time = |t: libc::timeval| Duration::new(t.tv_sec as u64, t.tv_usec as u32 * 1000);
    time(usage.ru_utime) + time(usage.ru_stime)
}

/// User and system time of this process so far (all its threads, ended ones too).
pub fn process() -> Duration {
    rusage(libc::RUSAGE_SELF)
}

/// User and system time of the calling thread so far.
pub fn this_thread() -> Duration {
    rusage(libc::RUSAGE_THREAD)
}

/// Clock ticks a second of `/proc/<pid>/stat`'s times.
fn ticks_per_second() -> f64 {
    // SAFETY: sysconf reads a constant of the system.
    let ticks = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    if ticks > 0 {
        ticks as f64
    } else {
        100.0
    }
}

/// User and system time of process `pid` so far (its threads', ended ones too), from `/proc/<pid>/stat` (a clock
/// tick's resolution); None once it is gone or where there is no /proc.
pub fn of_process(pid: u32) -> Option<Duration> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // The fields after the command name (which may hold spaces) are the 3rd onwards: utime is the 14th, stime the
    // 15th.
    let rest = stat.rsplit_once(')')?.1;
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let utime: f64 = fields.get(11)?.parse().ok()?;
    let stime: f64 = fields.get(12)?.parse().ok()?;
    Some(Duration::from_secs_f64(
        (utime + stime) / ticks_per_second(),
    ))
}

/// CPU time of this process's live threads so far, summed by thread name with its digits dropped (`rx-3` ->
/// `rx-`), from `/proc/self/task/<tid>/schedstat` (nanoseconds).
pub fn by_thread_name() -> BTreeMap<String, Duration> {
    let mut by = BTreeMap::new();
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return by;
    };
    for task in tasks.flatten() {
        let path = task.path();
        let name = std::fs::read_to_string(path.join("comm")).unwrap_or_default();
        let name: String = name
            .trim()
            .chars()
            .filter(|c| !c.is_ascii_digit())
            .collect();
        let ns = std::fs::read_to_string(path.join("schedstat"))
            .ok()
            .and_then(|s| s.split_whitespace().next()?.parse::<u64>().ok());
        if let Some(ns) = ns {
            *by.entry(name).or_default() += Duration::from_nanos(ns);
        }
    }
    by
}

/// `after - before`, name by name (a thread that started in between counts from 0).
pub fn since(
    after: &BTreeMap<String, Duration>,
    before: &BTreeMap<String, Duration>,
) -> BTreeMap<String, f64> {
    after
        .iter()
        .map(|(name, t)| {
            let before = before.get(name).copied().unwrap_or_default();
            (name.clone(), t.saturating_sub(before).as_secs_f64())
        })
        .filter(|(_, s)| *s > 0.0)
        .collect()
}

/// The `q`-quantile (0..=1) of `values`, sorted in place (nearest rank); None when empty.
pub fn quantile(values: &mut [f64], q: f64) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    let rank = ((q * values.len() as f64).ceil() as usize).clamp(1, values.len());
    Some(values[rank - 1])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_are_nearest_ranks() {
        let mut v = vec![5.0, 1.0, 3.0, 2.0, 4.0];
        assert_eq!(quantile(&mut v, 0.5), Some(3.0));
        assert_eq!(quantile(&mut v, 0.99), Some(5.0));
        assert_eq!(quantile(&mut v, 0.0), Some(1.0));
        assert_eq!(quantile(&mut [], 0.5), None);
    }

    #[test]
    fn this_process_and_thread_take_time() {
        let spin = std::time::Instant::now();
        while spin.elapsed() < Duration::from_millis(20) {}
        assert!(process() >= this_thread());
        assert!(this_thread() > Duration::ZERO);
        assert!(of_process(std::process::id()).is_some());
        assert!(!by_thread_name().is_empty());
    }
}
