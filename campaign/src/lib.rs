//! cabc-campaign: the reproduction campaign as data, run by `cabc campaign`.
//!
//! A campaign is a plan file, `deploy/campaign/<plan>.toml` ([`plan`]: blocks of slices over seeds, each slice a
//! preset with its tag, methods, epochs and `--set` keys, in order of priority, with the commentary on their results
//! as TOML comments beside them), and one typed command over it:
//!
//! * `cabc campaign list`: the slices, as `deploy/reproduce.sh` arguments ([`list`]);
//! * `cabc campaign status`: each slice's runs ended (and how), in progress (at which epoch) or not started, and
//!   about how long what is left takes one lane ([`status`]);
//! * `cabc campaign run --lane I/N [--only N]`: a lane; lanes share the slices through claims ([`claims`], the lock
//!   that deploy/claim.sh was, compatible with its claims) and run each with the per-run step ([`lane`]);
//! * `cabc campaign tables`: the groups' tables and figures, and the plans' views over groups ([`tables`]);
//! * `cabc reproduce`: the per-run step a lane runs a slice with, and the tool for runs over seeds ([`reproduce`]).
//!
//! The run names and seeds (`<preset>[-<tag>]-s<k>[-baseline]`, seed 41 + k) are [`cabc_proto::run_name`]'s.
//!
//! What stays in bash, and why: `deploy/run-local.sh`, the main job (set-up, the processes of a run, their logs);
//! `deploy/reproduce.sh`, a wrapper that builds the binaries (unless `CABC_BIN` names them) and calls `cabc
//! reproduce`; `deploy/campaign.sh`, a wrapper that builds and calls `cabc campaign`, keeps the pinning of binaries
//! (`--pin`: a build and copies) and `--snapshot` (copies of run folders and one `cabc compare`).

pub mod claims;
pub mod lane;
mod md5;
pub mod plan;
pub mod reproduce;
pub mod status;
pub mod tables;

pub use plan::{Plan, Slice};

/// The text of `cabc campaign list` (the bash campaign's `--list`): `<i>: deploy/reproduce.sh <slice>` per slice.
pub fn list(plan: &Plan) -> String {
    plan.slices
        .iter()
        .enumerate()
        .map(|(i, s)| format!("{i}: deploy/reproduce.sh {s}\n"))
        .collect()
}

/// The plans in a folder of plans (`deploy/campaign/*.toml`), by file name, each with its name (the file's stem).
pub fn plans_in(dir: &std::path::Path) -> anyhow::Result<Vec<(String, Plan)>> {
    let mut paths: Vec<_> = std::fs::read_dir(dir)?
        .filter_map(|e| Some(e.ok()?.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    paths.sort();
    paths
        .into_iter()
        .map(|p| {
            let name = p
                .file_stem()
                .unwrap_or_default()
                .to_string_lossy()
                .into_owned();
            Ok((name, Plan::load(&p)?))
        })
        .collect()
}
