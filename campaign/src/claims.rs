//! How lanes share a campaign's slices: a claim per slice, a lock directory in `runs/campaign-claims/`.
//!
//! A slice is claimed by a directory named after its text, `slice-<the first 16 hex digits of md5(text)>`, holding
//! its owner in one file, `owner` (the lane's pid and a token of the lock's own), put in place by one atomic
//! `rename(2)` of a directory prepared beside it: a rename onto a directory that has files in it fails, so of the
//! lanes that race for a slice one wins. [`Claim::done`] writes `done` in it when the slice ended well.
//!
//! A claim is held while its lane runs, or once it is done. One whose lane no longer runs and that is not done (an
//! earlier session's, ended mid-slice) is stale and taken over by exactly one lane: it is moved aside under its own
//! token (`<lock>.stale-<token>`, a name that outlives it); of the lanes that saw it stale, the first one's rename
//! wins, and a later one's finds that name taken and cannot move the claim that the winner has put in its place
//! since. Claims of the older format (the pid alone, in `pid`) are moved aside under their pid.
//!
//! Why a lock directory and not `flock(2)`: a flock dies with its process, which would spare the liveness check,
//! but a claim must outlive its lane (`done`: a slice is not run again in a later session, on this machine), the
//! bash lanes' claims in `runs/campaign-claims/` (deploy/claim.sh, which this replaces) must keep counting, and a
//! lane of the bash campaign may still run beside a typed one. So this is claim.sh's protocol, the same files and
//! names, in Rust: a bash lane's claim and a typed lane's claim are the same thing to either. A lane is alive when
//! its pid runs a campaign (its command line has "campaign": `deploy/campaign.sh` or `cabc campaign run`).

use crate::md5::md5_hex;
use std::io::{self, ErrorKind};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

/// The folder of the claims of the runs in `runs`.
pub const CLAIMS_DIR: &str = "runs/campaign-claims";

/// A folder of claims.
#[derive(Debug, Clone)]
pub struct Claims {
    dir: PathBuf,
}

/// A slice this lane holds.
#[derive(Debug)]
pub struct Claim {
    lock: PathBuf,
}

impl Claim {
    /// Marks the slice as ended well: no lane takes it again.
    pub fn done(&self) -> io::Result<()> {
        std::fs::write(self.lock.join("done"), "")
    }

    /// The lock directory.
    pub fn lock(&self) -> &Path {
        &self.lock
    }
}

/// Makes every claim attempt's temporary directory and token unique, across the threads of a process too.
static ATTEMPTS: AtomicU64 = AtomicU64::new(0);

impl Claims {
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        Self { dir: dir.into() }
    }

    /// The lock directory of a slice's text: `slice-<first 16 hex digits of its md5>` (claim.sh's `lock_of`).
    pub fn lock_of(&self, slice: &str) -> PathBuf {
        self.dir
            .join(format!("slice-{}", &md5_hex(slice.as_bytes())[..16]))
    }

    /// Claims a slice: `Some` if this lane now holds it, `None` if another lane has it or it is done.
    pub fn claim(&self, slice: &str) -> io::Result<Option<Claim>> {
        let lock = self.lock_of(slice);
        std::fs::create_dir_all(&self.dir)?;
        let pid = std::process::id();
        let attempt = ATTEMPTS.fetch_add(1, Ordering::Relaxed);
        let nanos = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        let tmp = self.dir.join(format!(".claim-{pid}-{attempt}"));
        let _ = std::fs::remove_dir_all(&tmp);
        std::fs::create_dir(&tmp)?;
        std::fs::write(
            tmp.join("owner"),
            format!("{pid} {pid}-{attempt}-{nanos}\n"),
        )?;
        loop {
            match std::fs::rename(&tmp, &lock) {
                Ok(()) => return Ok(Some(Claim { lock })),
                Err(e)
                    if matches!(
                        e.kind(),
                        ErrorKind::DirectoryNotEmpty | ErrorKind::AlreadyExists
                    ) => {}
                Err(e) => {
                    let _ = std::fs::remove_dir_all(&tmp);
                    return Err(e);
                }
            }
            // One read, so that pid and token are the same lock's (another lane may put a new lock in place
            // meanwhile); older locks hold their pid alone, in `pid`.
            let owner = std::fs::read_to_string(lock.join("owner"))
                .or_else(|_| std::fs::read_to_string(lock.join("pid")))
                .unwrap_or_default();
            let mut words = owner.split_whitespace();
            let pid = words.next().and_then(|p| p.parse::<u32>().ok());
            let token = words.next();
            let done = lock.join("done").exists();
            let Some(pid) = pid else {
                if done {
                    let _ = std::fs::remove_dir_all(&tmp);
                    return Ok(None);
                }
                // Neither file: the lock was being replaced between the two reads; look again.
                std::thread::sleep(Duration::from_millis(1));
                continue;
            };
            // Its lane still runs, or ended it (done is written before its lane goes on): taken.
            if done || lane_alive(pid) {
                let _ = std::fs::remove_dir_all(&tmp);
                return Ok(None);
            }
            // Stale: moved aside under its own token (see the module's doc).
            let aside = match token {
                Some(token) => format!("stale-{token}"),
                None => format!("stale-pid{pid}"),
            };
            let mut moved = lock.clone().into_os_string();
            moved.push(format!(".{aside}"));
            let _ = std::fs::rename(&lock, moved);
        }
    }
}

/// Whether `pid` runs a campaign's lane: this process, or a process whose command line has "campaign".
fn lane_alive(pid: u32) -> bool {
    if pid == std::process::id() {
        return true;
    }
    let proc = Path::new("/proc");
    let args = if proc.join("self").exists() {
        std::fs::read(proc.join(pid.to_string()).join("cmdline")).unwrap_or_default()
    } else {
        std::process::Command::new("ps")
            .args(["-o", "args=", "-p", &pid.to_string()])
            .output()
            .map(|o| o.stdout)
            .unwrap_or_default()
    };
    args.windows(b"campaign".len()).any(|w| w == b"campaign")
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::process::Command;
    use std::sync::{Arc, Barrier};

    /// The lock's name is the bash lanes' (`printf '%s' SLICE | md5sum | cut -c1-16`), so their claims count.
    #[test]
    fn locks_are_named_as_claim_sh_named_them() {
        let claims = Claims::new("c");
        for slice in [
            "--seeds 2-2 --epochs 200 --methods proposed --tag warmup --set algorithm.lambda_start=1 --set \
             algorithm.lambda_growth=1.007 v-b-ref",
            "--seeds 1-1 --epochs 200 --methods proposed --tag abl-clip --set training.clip_scope=\"policy\" v-b-ref",
            "s1",
        ] {
            let out = Command::new("bash")
                .args(["-c", "printf '%s' \"$1\" | md5sum | cut -c1-16", "-", slice])
                .output()
                .unwrap();
            let hex = String::from_utf8(out.stdout).unwrap();
            assert_eq!(claims.lock_of(slice), Path::new("c").join(format!("slice-{}", hex.trim())));
        }
        assert_eq!(claims.lock_of("s1"), Path::new("c/slice-8ddf878039b70767"));
    }

    /// Threads race for the same slices, stale ones (dead pid, both formats) among them: each slice goes to one.
    #[test]
    fn one_winner_per_slice_and_per_stale_claim() {
        let tmp = tempfile::tempdir().unwrap();
        let claims = Claims::new(tmp.path().join("claims"));
        std::fs::create_dir_all(tmp.path().join("claims")).unwrap();
        // s10..s19 stale in the current format, s20..s29 in the older one, s30..s39 done by a dead lane.
        for i in 10..40 {
            let lock = claims.lock_of(&format!("s{i}"));
            std::fs::create_dir(&lock).unwrap();
            match i / 10 {
                1 => std::fs::write(lock.join("owner"), format!("999999999 999999999-{i}-1\n"))
                    .unwrap(),
                2 => std::fs::write(lock.join("pid"), "999999999\n").unwrap(),
                _ => {
                    std::fs::write(lock.join("owner"), "999999999 t\n").unwrap();
                    std::fs::write(lock.join("done"), "").unwrap();
                }
            }
        }
        let barrier = Arc::new(Barrier::new(6));
        let threads: Vec<_> = (0..6)
            .map(|_| {
                let (claims, barrier) = (claims.clone(), barrier.clone());
                std::thread::spawn(move || {
                    barrier.wait();
                    (0..40)
                        .filter(|i| claims.claim(&format!("s{i}")).unwrap().is_some())
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        let mut won: Vec<u32> = threads
            .into_iter()
            .flat_map(|t| t.join().unwrap())
            .collect();
        won.sort();
        assert_eq!(won, (0..30).collect::<Vec<_>>());
        // A claim of this (live) process holds; done, it holds for good.
        let c = claims.claim("s40").unwrap().unwrap();
        assert!(claims.claim("s40").unwrap().is_none());
        c.done().unwrap();
        assert!(claims.claim("s40").unwrap().is_none());
        // Nothing left behind but the claims and the stale ones moved aside (20 of them).
        let names: Vec<String> = std::fs::read_dir(tmp.path().join("claims"))
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        assert_eq!(
            names.iter().filter(|n| n.starts_with(".claim")).count(),
            0,
            "{names:?}"
        );
        assert_eq!(
            names.iter().filter(|n| n.contains(".stale-")).count(),
            20,
            "{names:?}"
        );
        assert!(names.iter().any(|n| n.ends_with(".stale-pid999999999")));
    }
}
