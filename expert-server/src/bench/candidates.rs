//! The ways of cutting an MPCC step (issue 75) measured side by side with the reference's:
//! `expert-server bench --candidates`.

use cabc_proto::stats;
use cabc_sim::vehicle::VehicleParams;
use serde::{Deserialize, Serialize};

use super::{bench, ms, BenchReport};
use crate::drive::{drive, drive_from, DriveEnd, DriveOptions};
use crate::mpcc::{Mpcc, MpccConfig, MpccError};

/// One way of running MPCC-conv that `expert-server bench --candidates` measures beside the reference's.
#[derive(Debug, Clone)]
pub struct Candidate {
    /// Short name.
    pub name: &'static str,
    /// What it changes, against the reference.
    pub change: &'static str,
    /// The controller's configuration.
    pub config: MpccConfig,
}

/// The candidates of issue 75, the reference first.
pub fn candidates() -> Vec<Candidate> {
    let reference = MpccConfig::default();
    let with = |f: &dyn Fn(&mut MpccConfig)| {
        let mut c = reference.clone();
        f(&mut c);
        c
    };
    #[allow(unused_mut)]
    let mut all = vec![
        Candidate {
            name: "reference",
            change: "none: 2 QPs a step, gap 1e-5, feasibility 1e-6, every row",
            config: reference.clone(),
        },
        Candidate {
            name: "lazy-boxes",
            change: "the v_y, ω, ψ boxes only when the minimiser leaves them (the same minimiser)",
            config: with(&|c| c.lazy_state_boxes = true),
        },
        Candidate {
            name: "tol-1e-4",
            change: "gap 1e-4, feasibility 1e-5",
            config: with(&|c| (c.tol_gap, c.tol_feas) = (1e-4, 1e-5)),
        },
        Candidate {
            name: "tol-3e-4",
            change: "gap 3e-4, feasibility 3e-5",
            config: with(&|c| (c.tol_gap, c.tol_feas) = (3e-4, 3e-5)),
        },
        Candidate {
            name: "tol-1e-3",
            change: "gap 1e-3, feasibility 1e-4",
            config: with(&|c| (c.tol_gap, c.tol_feas) = (1e-3, 1e-4)),
        },
        Candidate {
            name: "tol-3e-3",
            change: "gap 3e-3, feasibility 3e-4",
            config: with(&|c| (c.tol_gap, c.tol_feas) = (3e-3, 3e-4)),
        },
        Candidate {
            name: "converged-1e-2",
            change: "the second QP only when the first moved a scaled variable by 1e-2 or more",
            config: with(&|c| c.qp_converged_step = 1e-2),
        },
        Candidate {
            name: "one-qp",
            change: "one QP a step",
            config: with(&|c| c.qp_iters = 1),
        },
        Candidate {
            name: "one-qp-undamped",
            change: "one QP a step, its minimiser taken whole (damping 0)",
            config: with(&|c| (c.qp_iters, c.damping) = (1, 0.0)),
        },
        Candidate {
            name: "one-qp-damping-0.1",
            change: "one QP a step, damping 0.1",
            config: with(&|c| (c.qp_iters, c.damping) = (1, 0.1)),
        },
        Candidate {
            name: "lead-1e-2",
            change: "the first QP of a step at gap 1e-2, feasibility 1e-3",
            config: with(&|c| c.lead_qp_tol = Some((1e-2, 1e-3))),
        },
        Candidate {
            name: "lead-1e-3",
            change: "the first QP of a step at gap 1e-3, feasibility 1e-4",
            config: with(&|c| c.lead_qp_tol = Some((1e-3, 1e-4))),
        },
        Candidate {
            name: "lead-1e-2-tol-1e-3",
            change: "lead-1e-2 and the last at tol-1e-3",
            config: with(&|c| {
                c.lead_qp_tol = Some((1e-2, 1e-3));
                (c.tol_gap, c.tol_feas) = (1e-3, 1e-4);
            }),
        },
        Candidate {
            name: "tol-1e-2",
            change: "gap 1e-2, feasibility 1e-3",
            config: with(&|c| (c.tol_gap, c.tol_feas) = (1e-2, 1e-3)),
        },
        Candidate {
            name: "tol-3e-2",
            change: "gap 3e-2, feasibility 3e-3",
            config: with(&|c| (c.tol_gap, c.tol_feas) = (3e-2, 3e-3)),
        },
        Candidate {
            name: "tol-1e-1",
            change: "gap 1e-1, feasibility 1e-2",
            config: with(&|c| (c.tol_gap, c.tol_feas) = (1e-1, 1e-2)),
        },
        Candidate {
            name: "lazy-tol-1e-2",
            change: "lazy-boxes and tol-1e-2",
            config: with(&|c| {
                c.lazy_state_boxes = true;
                (c.tol_gap, c.tol_feas) = (1e-2, 1e-3);
            }),
        },
        Candidate {
            name: "gap-1e-2",
            change: "gap 1e-2, feasibility 1e-6",
            config: with(&|c| c.tol_gap = 1e-2),
        },
        Candidate {
            name: "feas-1e-3",
            change: "gap 1e-5, feasibility 1e-3",
            config: with(&|c| c.tol_feas = 1e-3),
        },
        Candidate {
            name: "gap-rel-1e-2",
            change: "gap 1e-5 absolute, 1e-2 relative",
            config: with(&|c| c.tol_gap_rel = Some(1e-2)),
        },
        Candidate {
            name: "step-0.999",
            change: "max step fraction 0.999",
            config: with(&|c| c.max_step_fraction = 0.999),
        },
        Candidate {
            name: "step-0.999-tol-1e-2",
            change: "max step fraction 0.999, tol-1e-2",
            config: with(&|c| {
                c.max_step_fraction = 0.999;
                (c.tol_gap, c.tol_feas) = (1e-2, 1e-3);
            }),
        },
        Candidate {
            name: "lazy-tol-1e-3",
            change: "lazy-boxes and tol-1e-3",
            config: with(&|c| {
                c.lazy_state_boxes = true;
                (c.tol_gap, c.tol_feas) = (1e-3, 1e-4);
            }),
        },
    ];
    #[cfg(feature = "faer")]
    all.push(Candidate {
        name: "faer",
        change: "faer's sparse LDLᵀ instead of QDLDL (the same KKT system)",
        config: with(&|c| c.ldl = crate::mpcc::Ldl::Faer),
    });
    all
}

/// The reference and the candidates named in `only` (all of them when it is empty), in [`candidates`]' order; an
/// unknown name is an error that lists the names.
pub fn chosen(only: &[String]) -> anyhow::Result<Vec<Candidate>> {
    let all = candidates();
    if let Some(unknown) = only.iter().find(|n| !all.iter().any(|c| c.name == **n)) {
        let names: Vec<_> = all.iter().map(|c| c.name).collect();
        anyhow::bail!("no candidate {unknown:?}; candidates: {}", names.join(", "));
    }
    Ok(all
        .into_iter()
        .enumerate()
        .filter(|(i, c)| *i == 0 || only.is_empty() || only.iter().any(|n| n == c.name))
        .map(|(_, c)| c)
        .collect())
}

/// A candidate's figures: its step time side by side with the others, its laps from the fixed spawn, and its
/// failures from random spawns.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CandidateRow {
    pub name: String,
    pub change: String,
    /// Median over the repeats of each drive's step p50 [ms].
    pub step_ms_p50: f64,
    /// Its ratio to the reference's.
    pub step_ratio: f64,
    pub solve_ms_p50: f64,
    /// Clarabel iterations per step, mean.
    pub iterations_per_step: f64,
    /// QPs per step, mean.
    pub qps_per_step: f64,
    /// QPs solved again with every row, per step (`lazy_state_boxes`).
    pub full_resolves_per_step: f64,
    /// Flying laps (all but the first) of the drive from the fixed spawn: mean [s] and count.
    pub flying_lap_mean_s: Option<f64>,
    pub flying_laps: usize,
    /// Failed steps of the drive from the fixed spawn.
    pub failures: usize,
    /// Random spawns (the training distribution, `Spawn::Random`): episodes, failed steps, episodes that ended
    /// off the band or stalled before `spawn_steps`.
    pub spawn_episodes: usize,
    pub spawn_failed_steps: usize,
    pub spawn_truncated: usize,
    /// The random-spawn episodes' steps (states off the racing line, as an actor's policy visits them): mean step
    /// time [ms] and Clarabel iterations per step.
    pub spawn_step_ms_mean: f64,
    pub spawn_iterations_per_step: f64,
}

/// Measures `cands` side by side: `repeat` rounds, each timing every candidate's drive of `steps` steps in turn
/// (so that a drift of the machine's speed falls on all of them), then each one's random-spawn episodes
/// (`spawns` of `spawn_steps` steps, spawns drawn from seed 75).
pub fn compare(
    track: &cabc_sim::track::Track,
    cands: &[Candidate],
    steps: usize,
    repeat: usize,
    spawns: usize,
    spawn_steps: usize,
) -> Result<Vec<CandidateRow>, MpccError> {
    let plant = VehicleParams::default();
    let mpccs = cands
        .iter()
        .map(|c| Mpcc::new(track.clone(), plant.clone(), c.config.clone()))
        .collect::<Result<Vec<_>, _>>()?;
    let mut reports: Vec<Vec<BenchReport>> = vec![Vec::new(); cands.len()];
    for _ in 0..repeat.max(1) {
        for (m, out) in mpccs.iter().zip(reports.iter_mut()) {
            out.push(bench(m, &plant, steps)?);
        }
    }
    let opts = DriveOptions {
        laps: usize::MAX,
        max_steps: steps.max(1),
        stop_on_failure: false,
    };
    let spawn_states: Vec<_> = (0..spawns as u64)
        .map(|i| {
            let mut env = cabc_sim::env::Env::new(
                std::sync::Arc::new(track.clone()),
                plant.clone(),
                cabc_sim::env::EnvConfig::default(),
            );
            env.reset(
                cabc_proto::config::Spawn::Random,
                &mut cabc_sim::env::Env::rng(75, i),
            );
            env.vehicle_state()
        })
        .collect();
    let spawn_opts = DriveOptions {
        laps: usize::MAX,
        max_steps: spawn_steps,
        stop_on_failure: false,
    };
    let mut rows = Vec::new();
    for ((c, m), runs) in cands.iter().zip(&mpccs).zip(&reports) {
        let mut p50s: Vec<f64> = runs.iter().map(|r| ms(r.p50)).collect();
        let mut solves: Vec<f64> = runs.iter().map(|r| ms(r.solve_p50)).collect();
        let laps = drive(m, &plant, &opts);
        let flying = laps.lap_times.get(1..).unwrap_or_default();
        let qps: u64 = laps.steps.iter().map(|s| u64::from(s.qps)).sum();
        let its: u64 = laps.steps.iter().map(|s| u64::from(s.qp_iterations)).sum();
        let resolves: u64 = laps.steps.iter().map(|s| u64::from(s.full_resolves)).sum();
        let n = laps.steps.len().max(1) as f64;
        let (mut failed, mut truncated) = (0, 0);
        let (mut spawn_steps_done, mut spawn_secs, mut spawn_its) = (0usize, 0.0, 0u64);
        for q in &spawn_states {
            let r = drive_from(m, &plant, *q, &spawn_opts);
            failed += r.failures;
            truncated += usize::from(matches!(r.end, DriveEnd::Truncated(_) | DriveEnd::Error(_)));
            spawn_steps_done += r.steps.len();
            spawn_secs += r.steps.iter().map(|s| s.step_time).sum::<f64>();
            spawn_its += r
                .steps
                .iter()
                .map(|s| u64::from(s.qp_iterations))
                .sum::<u64>();
        }
        let spawn_n = spawn_steps_done.max(1) as f64;
        rows.push(CandidateRow {
            name: c.name.into(),
            change: c.change.into(),
            step_ms_p50: stats::median(&mut p50s).unwrap_or(0.0),
            step_ratio: 0.0,
            solve_ms_p50: stats::median(&mut solves).unwrap_or(0.0),
            iterations_per_step: its as f64 / n,
            qps_per_step: qps as f64 / n,
            full_resolves_per_step: resolves as f64 / n,
            flying_lap_mean_s: stats::mean(flying),
            flying_laps: flying.len(),
            failures: laps.failures,
            spawn_episodes: spawn_states.len(),
            spawn_failed_steps: failed,
            spawn_truncated: truncated,
            spawn_step_ms_mean: spawn_secs * 1e3 / spawn_n,
            spawn_iterations_per_step: spawn_its as f64 / spawn_n,
        });
    }
    let reference = rows.first().map_or(1.0, |r| r.step_ms_p50);
    for r in &mut rows {
        r.step_ratio = r.step_ms_p50 / reference;
    }
    Ok(rows)
}

/// The rows of [`compare`] as a Markdown table.
pub fn candidates_table(rows: &[CandidateRow]) -> String {
    let mut t = String::from(
        "| candidate | change | step p50 | ratio | solve p50 | IPM it. / step | QPs / step | full re-solves / step | \
         flying lap | failures | random spawns: failed steps, truncated | random spawns: step mean, IPM it. / step |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let lap = r
            .flying_lap_mean_s
            .map_or("-".into(), |l| format!("{l:.3} s ({} laps)", r.flying_laps));
        t += &format!(
            "| {} | {} | {:.3} ms | {:.2} | {:.3} ms | {:.1} | {:.2} | {:.3} | {lap} | {} | {}, {} of {} | {:.3} ms, {:.1} |\n",
            r.name,
            r.change,
            r.step_ms_p50,
            r.step_ratio,
            r.solve_ms_p50,
            r.iterations_per_step,
            r.qps_per_step,
            r.full_resolves_per_step,
            r.failures,
            r.spawn_failed_steps,
            r.spawn_truncated,
            r.spawn_episodes,
            r.spawn_step_ms_mean,
            r.spawn_iterations_per_step
        );
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The candidates are measured on the same drives as the reference, which comes first with ratio 1: one QP a step
    /// solves half the QPs, the reference never solves a QP again, and the table has a row per candidate.
    #[test]
    fn candidates_are_measured_beside_the_reference() {
        let picked = chosen(&["one-qp".into(), "lazy-boxes".into()]).unwrap();
        assert!(chosen(&["nonsense".into()])
            .unwrap_err()
            .to_string()
            .contains("lazy-boxes"));
        let track = cabc_sim::track::Track::l_track_barc();
        let rows = compare(&track, &picked, 30, 1, 2, 10).unwrap();
        let names: Vec<&str> = rows.iter().map(|r| r.name.as_str()).collect();
        assert_eq!(names, ["reference", "lazy-boxes", "one-qp"]);
        assert_eq!(rows[0].step_ratio, 1.0);
        assert_eq!((rows[0].qps_per_step, rows[2].qps_per_step), (2.0, 1.0));
        assert_eq!(rows[0].full_resolves_per_step, 0.0);
        assert!(rows
            .iter()
            .all(|r| r.spawn_episodes == 2 && r.step_ms_p50 > 0.0));
        assert_eq!(candidates_table(&rows).lines().count(), 2 + rows.len());
    }
}
