//! Tests of the whole controller: a QP at a straight-line state and closed-loop laps (expert.md §13).

use super::*;
use crate::drive::{drive, DriveEnd, DriveOptions};
use cabc_sim::env::{fixed_spawn_state, DT, SUBSTEPS};

fn assert_send_sync<T: Send + Sync>() {}

#[test]
fn controller_and_streams_can_cross_threads() {
    assert_send_sync::<Mpcc>();
    assert_send_sync::<MpccStream>();
}

#[test]
fn qp_at_a_straight_line_state() {
    let mpcc = Mpcc::reference();
    let p = mpcc.track().local_to_global(0.5, 0.0, 0.0);
    let q: State = [2.0, 0.0, 0.0, p.x, p.y, p.psi];
    let mut stream = mpcc.start(&q).unwrap();
    // Drive the warm start to the state's own plan: a few steps at the same state.
    for _ in 0..3 {
        mpcc.step(&mut stream, &q).unwrap();
    }
    let sol = mpcc.probe_qp(&stream, &q).unwrap();
    assert_eq!(sol.status, QpStatus::Solved);
    let z1 = sol.stages[1];
    eprintln!("stage 1: {z1:?}\nslacks: {:?}", sol.slacks);
    assert!(z1[8].abs() < 0.05, "δ* = {}", z1[8]);
    // v_s tracks v_x over the first stages (the lag cost is stiff).
    for k in 1..=5 {
        let z = sol.stages[k];
        assert!(
            (z[VS] - z[0]).abs() < 0.15,
            "stage {k}: v_s {} vs v_x {}",
            z[VS],
            z[0]
        );
    }
    assert!(
        sol.slacks.iter().all(|&s| s.abs() < 1e-4),
        "{:?}",
        sol.slacks
    );

    let step = mpcc.step(&mut stream, &q).unwrap();
    assert!(step.success, "{}", step.status);
    assert!(
        step.action[1].abs() < 0.05 && step.action[0] > 0.0,
        "{:?}",
        step.action
    );
}

/// The QPs of the first `steps` steps of a closed-loop lap of `mpcc`, each solved by `mpcc` and by `other` from the
/// same warm start: both must solve every one, `check` sees `other`'s solutions, and the largest scaled difference of
/// their minimisers comes back.
fn largest_difference_over_a_lap(
    mpcc: &Mpcc,
    other: &Mpcc,
    steps: usize,
    check: impl Fn(usize, &QpSolution),
) -> f64 {
    let r = drive(
        mpcc,
        &VehicleParams::default(),
        &DriveOptions {
            laps: 1,
            max_steps: steps,
            stop_on_failure: true,
        },
    );
    let mut stream = mpcc.start(&r.steps[0].state).unwrap();
    let mut worst: f64 = 0.0;
    for (k, step) in r.steps.iter().enumerate() {
        let (a, b) = (
            mpcc.probe_qp(&stream, &step.state).unwrap(),
            other.probe_qp(&stream, &step.state).unwrap(),
        );
        assert_eq!(a.status, QpStatus::Solved, "step {k}");
        assert_eq!(b.status, QpStatus::Solved, "step {k}");
        check(k, &b);
        for (za, zb) in a.stages.iter().zip(&b.stages) {
            for j in 0..NZ {
                worst = worst.max((za[j] - zb[j]).abs() / mpcc.layout.scale[j]);
            }
        }
        mpcc.step(&mut stream, &step.state).unwrap();
    }
    worst
}

/// Leaving out the rate rows that can never bind (the acceleration's, after stage 1) must not change the QP's
/// minimiser: solve the QPs of a closed-loop lap with and without them.
#[test]
fn pruned_rows_do_not_change_the_qp_solution() {
    let mpcc = Mpcc::reference();
    let mut full = mpcc.clone();
    full.layout = QpLayout::build(mpcc.config(), mpcc.track().length(), false, false);
    assert!(full.layout.m() > mpcc.layout.m());
    let worst = largest_difference_over_a_lap(&mpcc, &full, 60, |_, _| ());
    // Both are interior-point solutions to 1e-5/1e-6 tolerances of the same QP.
    assert!(worst < 2e-3, "largest scaled difference {worst:e}");
    eprintln!("largest scaled difference between pruned and full QPs: {worst:e}");
}

/// Issue 75: with `lazy_state_boxes` each QP's minimiser is the full QP's (the lean QP is a relaxation, and one
/// whose minimiser leaves a lazy box is solved again in full): over a lap's QPs the two agree to the solver's
/// tolerance, and the lean layout is smaller.
#[test]
fn lazy_boxes_give_the_full_qps_minimiser() {
    let mpcc = Mpcc::reference();
    let lazy = Mpcc::new(
        Track::l_track_barc(),
        VehicleParams::default(),
        MpccConfig {
            lazy_state_boxes: true,
            ..MpccConfig::default()
        },
    )
    .unwrap();
    let lean = lazy
        .lean
        .as_ref()
        .expect("a lean layout under lazy_state_boxes");
    assert_eq!(lean.m() + 2 * 3 * 20, mpcc.layout.m());
    let worst = largest_difference_over_a_lap(&mpcc, &lazy, 120, |k, sol| {
        assert!(mpcc.layout.within_lazy_boxes(sol), "step {k}");
    });
    // Two interior-point solutions to 1e-5/1e-6 of the same QP (3.6e-3 measured over these 120 steps; the flat
    // (X, Y, s) direction of the contour residuals is where they differ most).
    assert!(worst < 1e-2, "largest scaled difference {worst:e}");
    // A lazy drive laps like the reference's, with no failure.
    let laps = drive(
        &lazy,
        &VehicleParams::default(),
        &DriveOptions {
            laps: 3,
            max_steps: 2000,
            stop_on_failure: true,
        },
    );
    assert_eq!(laps.end, DriveEnd::Laps, "laps {:?}", laps.lap_times);
    assert_eq!(laps.failures, 0);
}

/// faer's LDL needs the crate's `faer` feature: without it the controller is refused with a message saying so.
#[test]
#[cfg(not(feature = "faer"))]
fn faer_without_its_feature_is_refused() {
    let cfg = MpccConfig {
        ldl: Ldl::Faer,
        ..MpccConfig::default()
    };
    let err = Mpcc::new(Track::l_track_barc(), VehicleParams::default(), cfg).unwrap_err();
    assert!(err.to_string().contains("faer"), "{err}");
}

/// A looser first QP (`lead_qp_tol`) is solved at its own tolerance and the step's last at the configuration's: the
/// step's iterations fall and its action stays near the reference's. With the lazy boxes, which share its solver
/// memory, it is refused.
#[test]
fn a_lead_qp_is_solved_at_its_own_tolerance() {
    let lead = MpccConfig {
        lead_qp_tol: Some((1e-2, 1e-3)),
        ..MpccConfig::default()
    };
    let first_steps = |cfg: MpccConfig| {
        let mpcc = Mpcc::new(Track::l_track_barc(), VehicleParams::default(), cfg).unwrap();
        let q = fixed_spawn_state(mpcc.track());
        let mut stream = mpcc.start(&q).unwrap();
        (0..5)
            .map(|_| mpcc.step(&mut stream, &q).unwrap())
            .collect::<Vec<_>>()
    };
    let (reference, loose) = (
        first_steps(MpccConfig::default()),
        first_steps(lead.clone()),
    );
    let iterations = |steps: &[MpccStep]| steps.iter().map(|s| s.qp_iterations).sum::<u32>();
    assert!(loose.iter().all(|s| s.success && s.qps == 2));
    assert!(
        iterations(&loose) < iterations(&reference),
        "{} {}",
        iterations(&loose),
        iterations(&reference)
    );
    for (a, b) in loose.iter().zip(&reference) {
        assert!(
            (a.action[0] - b.action[0]).abs() < 0.1 && (a.action[1] - b.action[1]).abs() < 0.05
        );
    }
    let both = MpccConfig {
        lazy_state_boxes: true,
        ..lead
    };
    let err = Mpcc::new(Track::l_track_barc(), VehicleParams::default(), both).unwrap_err();
    assert!(err.to_string().contains("lead_qp_tol"), "{err}");
}

/// `expert-server bench --kkt` times the three factorisations of the reference layout's KKT system: the scheduled
/// one reproduces QDLDL's factors (checked inside), and the eliminated system keeps the variables and equalities.
#[test]
fn kkt_timings_cover_the_three_systems() {
    let layout = Mpcc::reference().layout().clone();
    let timings = layout.kkt_timings(1, 2);
    assert_eq!(timings.len(), 3);
    assert_eq!(timings[0].rows, layout.n() + layout.m());
    assert_eq!(timings[0].nnz_l, timings[1].nnz_l);
    assert_eq!(timings[2].rows, layout.n() + layout.m_eq());
    assert!(timings[0].multiply_adds > timings[0].nnz_l);
    assert!(timings.iter().all(|t| t.factor_us > 0.0));
}

/// A lean layout's check refuses a solution outside a box it left out, and an unsolved QP.
#[test]
fn a_minimiser_outside_a_lazy_box_is_refused() {
    let cfg = MpccConfig::default();
    let lean = QpLayout::lean(&cfg, 17.46);
    let inside = [1.0, 0.1, 0.5, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0];
    let mut sol = QpSolution {
        status: QpStatus::Solved,
        iterations: 1,
        solve_time: std::time::Duration::ZERO,
        stages: vec![inside; 21],
        slacks: Vec::new(),
        rates: Vec::new(),
    };
    assert!(lean.within_lazy_boxes(&sol));
    sol.stages[7][2] = cfg.state_ub[2] + 0.01; // ω above its bound
    assert!(!lean.within_lazy_boxes(&sol));
    sol.stages[7][2] = 0.0;
    sol.stages[3][5] = cfg.state_lb[3] - 0.01; // ψ below its bound
    assert!(!lean.within_lazy_boxes(&sol));
    sol.stages.clear();
    assert!(!lean.within_lazy_boxes(&sol));
    // The full layout leaves nothing out.
    let full = QpLayout::new(&cfg, 17.46);
    sol.stages = vec![inside; 21];
    sol.stages[7][2] = 100.0;
    assert!(full.within_lazy_boxes(&sol));
}

/// Clarabel's timers are read by name ([`phases`]): a recorded drive has time in each phase that runs every
/// iteration, and the size of its KKT system's factor.
#[test]
fn a_recorded_drive_has_clarabels_phases() {
    phases::start();
    drive(
        &Mpcc::reference(),
        &VehicleParams::default(),
        &DriveOptions {
            laps: 1,
            max_steps: 20,
            stop_on_failure: true,
        },
    );
    let p = phases::take();
    assert!(p.qps >= 40 && p.iterations > p.qps, "{p:?}");
    for (name, d) in [
        ("kkt update", p.kkt_update),
        ("kkt solve", p.kkt_solve),
        ("scale cones", p.scale_cones),
        ("default start", p.default_start),
    ] {
        assert!(d > std::time::Duration::ZERO, "{name}: {p:?}");
    }
    assert!(p.ldl_nnz > p.kkt_nnz / 2 && p.kkt_nnz > 1000, "{p:?}");
    assert_eq!(phases::take(), phases::SolverPhases::default(), "stopped");
}

/// The prediction is the plan rolled out from the measurement; in the nominal plant (the prediction model itself)
/// its first transition is exactly where the car goes when the step's action is applied.
#[test]
fn prediction_starts_where_the_plant_goes() {
    let mpcc = Mpcc::reference();
    let plant = VehicleParams::default();
    let q = fixed_spawn_state(mpcc.track());
    let mut stream = mpcc.start(&q).unwrap();
    let step = mpcc.step(&mut stream, &q).unwrap();
    assert!(step.success);
    let p = mpcc.predict(&step);
    let n = mpcc.config().horizon;
    assert_eq!((p.states.len(), p.s.len()), (n + 1, n + 1));
    assert_eq!(p.s[0], step.measured[S]);
    let next = plant.step(&q, &step.action, DT, SUBSTEPS);
    for i in 0..6 {
        let expected = if i == 5 {
            next[5] - q[5] + step.measured[5]
        } else {
            next[i]
        };
        assert!(
            (p.states[1][i] - expected).abs() < 1e-9,
            "component {i}: {} vs {expected}",
            p.states[1][i]
        );
    }
    // Progress advances by dt·v_s of the plan.
    assert!((p.s[1] - p.s[0] - DT * step.plan[0][2]).abs() < 1e-12);
}

#[test]
fn rejects_bad_states_without_panicking() {
    let mpcc = Mpcc::reference();
    let mut stream = mpcc.start(&fixed_spawn_state(mpcc.track())).unwrap();
    assert!(matches!(
        mpcc.step(&mut stream, &[f64::NAN, 0.0, 0.0, 1.0, 0.0, 0.0]),
        Err(MpccError::NonFinite(_))
    ));
    assert!(matches!(
        mpcc.step(&mut stream, &[1.0, 0.0, 0.0, 10.0, 10.0, 0.0]),
        Err(MpccError::OffTrack(_))
    ));
    assert!(mpcc
        .start(&[1.0, 0.0, 0.0, 1.0, f64::INFINITY, 0.0])
        .is_err());
}

#[test]
fn drives_laps_from_the_fixed_spawn() {
    let mpcc = Mpcc::reference();
    let opts = DriveOptions {
        laps: 3,
        max_steps: 400,
        stop_on_failure: true,
    };
    let r = drive(&mpcc, &VehicleParams::default(), &opts);
    let last = r.steps.last().unwrap();
    eprintln!(
        "end {:?}, laps {:?}, failures {}, last {:?}",
        r.end, r.lap_times, r.failures, last
    );
    assert_eq!(r.end, DriveEnd::Laps, "laps {:?}", r.lap_times);
    assert_eq!(r.failures, 0);
    // The first lap starts at 0.5 m/s; the flying laps should be near the paper's 4.805 s mean.
    for &t in &r.lap_times[1..] {
        assert!((4.3..=5.3).contains(&t), "lap {t} s");
    }
    let max_ey = r
        .steps
        .iter()
        .map(|s| s.frenet.x_tran.abs())
        .fold(0.0, f64::max);
    eprintln!("max |e_y| = {max_ey:.3}");
}

#[test]
#[ignore]
fn bench_print() {
    for (reuse, eq) in [(true, false), (false, false), (true, true)] {
        let cfg = MpccConfig {
            reuse_solver: reuse,
            equilibrate: eq,
            ..MpccConfig::default()
        };
        let mpcc = Mpcc::new(Track::l_track_barc(), VehicleParams::default(), cfg).unwrap();
        let r = crate::bench::bench(&mpcc, &VehicleParams::default(), 200).unwrap();
        eprintln!("reuse {reuse} equilibrate {eq}: {r}");
    }
}

/// Random spawns of the training distribution (inside the track), IR on and off: failure statistics.
#[test]
#[ignore]
fn stress_random_spawns() {
    let mut seed = 0x2545F4914F6CDD1Du64;
    let mut unif = move |lo: f64, hi: f64| {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        lo + (hi - lo) * (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    let track = Track::l_track_barc();
    let spawns: Vec<State> = (0..40)
        .map(|_| {
            let (s, ey, ep, v) = (
                unif(0.1, track.length() - 2.0),
                unif(-0.5, 0.5),
                unif(-0.5, 0.5),
                unif(0.5, 2.0),
            );
            let p = track.local_to_global(s, ey, ep);
            [v, 0.0, 0.0, p.x, p.y, p.psi]
        })
        .collect();
    for (ir, eq) in [(false, true), (true, true), (false, false), (true, false)] {
        let cfg = MpccConfig {
            iterative_refinement: ir,
            equilibrate: eq,
            ..MpccConfig::default()
        };
        let mpcc = Mpcc::new(track.clone(), VehicleParams::default(), cfg).unwrap();
        let opts = DriveOptions {
            laps: 100,
            max_steps: 60,
            stop_on_failure: false,
        };
        let (mut steps, mut fails, mut trunc, mut its) = (0, 0, 0, 0u64);
        let mut statuses = std::collections::BTreeMap::new();
        for q in &spawns {
            let r = crate::drive::drive_from(&mpcc, &VehicleParams::default(), *q, &opts);
            steps += r.steps.len();
            fails += r.failures;
            trunc += matches!(r.end, DriveEnd::Truncated(_)) as usize;
            for s in &r.steps {
                its += s.qp_iterations as u64;
                *statuses.entry(s.status.name()).or_insert(0) += 1;
            }
        }
        eprintln!(
            "IR {ir} equilibrate {eq}: {steps} steps, {fails} failed, {trunc} truncated episodes, \
             {:.1} IPM it/step, {statuses:?}",
            its as f64 / steps as f64
        );
    }
}

/// Ten laps from the fixed spawn: lap-time statistics.
#[test]
#[ignore]
fn ten_laps_print() {
    let mpcc = Mpcc::reference();
    let opts = DriveOptions {
        laps: 10,
        max_steps: 1000,
        stop_on_failure: false,
    };
    let r = drive(&mpcc, &VehicleParams::default(), &opts);
    let flying = &r.lap_times[1..];
    let mean = flying.iter().sum::<f64>() / flying.len() as f64;
    let max_ey = r
        .steps
        .iter()
        .map(|s| s.frenet.x_tran.abs())
        .fold(0.0, f64::max);
    let vmax = r.steps.iter().map(|s| s.state[0]).fold(0.0, f64::max);
    eprintln!(
        "end {:?}; laps {:?}; flying mean {mean:.3} s; failures {}; max |e_y| {max_ey:.3}; max v_x {vmax:.2}",
        r.end, r.lap_times, r.failures
    );
}

#[test]
fn streams_step_concurrently_like_sequentially() {
    use rayon::prelude::*;
    let mpcc = Mpcc::reference();
    let starts: Vec<State> = [0.3, 1.5, 2.0, 13.0]
        .iter()
        .map(|&s| {
            let p = mpcc.track().local_to_global(s, 0.1, 0.0);
            [1.5, 0.0, 0.0, p.x, p.y, p.psi]
        })
        .collect();
    let run = |q: &State| {
        let mut stream = mpcc.start(q).unwrap();
        (0..5)
            .map(|_| mpcc.step(&mut stream, q).unwrap().action)
            .collect::<Vec<_>>()
    };
    let seq: Vec<_> = starts.iter().map(run).collect();
    let par: Vec<_> = starts.par_iter().map(run).collect();
    assert_eq!(seq, par);
}

/// The MPCC of a run's configuration is the construction every caller wrote out before (`Mpcc::new` on
/// `L_track_barc`, the reference vehicle and `MpccConfig::default()`): its first steps from the fixed spawn give the
/// same actions, bit for bit, for every preset, and so does `Mpcc::reference`. `expert.mpcc_lazy_boxes` (issue 75)
/// turns on the lazy boxes: the same minimisers, so the same actions to the solver's tolerance.
#[test]
fn the_configured_mpcc_is_the_reference_construction() {
    let written_out = Mpcc::new(
        Track::l_track_barc(),
        VehicleParams::default(),
        MpccConfig::default(),
    )
    .unwrap();
    let actions = |mpcc: &Mpcc| -> Vec<[f64; 2]> {
        let q = fixed_spawn_state(mpcc.track());
        let mut stream = mpcc.start(&q).unwrap();
        (0..3)
            .map(|_| mpcc.step(&mut stream, &q).unwrap().action)
            .collect()
    };
    let bits = |a: Vec<[f64; 2]>| {
        a.into_iter()
            .map(|x| x.map(f64::to_bits))
            .collect::<Vec<_>>()
    };
    let expected = actions(&written_out);
    assert_eq!(bits(actions(&Mpcc::reference())), bits(expected.clone()));
    let config = RunConfig::load(cabc_proto::config::DEFAULT_PRESET).unwrap();
    let configured = Mpcc::from_config(&config).unwrap();
    assert_eq!(configured.track().length(), written_out.track().length());
    assert_eq!(configured.config(), written_out.config());
    assert_eq!(bits(actions(&configured)), bits(expected.clone()));
    match crate::relabel::Expert::from_config(&config).unwrap() {
        crate::relabel::Expert::Mpcc(mpcc) => {
            assert_eq!(bits(actions(&mpcc)), bits(expected.clone()))
        }
        crate::relabel::Expert::Pid(_) => panic!("v-b's expert is the MPCC"),
    }
    let lazy_config = config
        .clone()
        .with_overrides(&["expert.mpcc_lazy_boxes=true".into()])
        .unwrap();
    let lazy = Mpcc::from_config(&lazy_config).unwrap();
    assert!(lazy.config().lazy_state_boxes && lazy.lean.is_some());
    let close = actions(&lazy)
        .iter()
        .zip(&expected)
        .all(|(x, y)| (x[0] - y[0]).abs() < 1e-4 && (x[1] - y[1]).abs() < 1e-4);
    assert!(close, "{:?} against {expected:?}", actions(&lazy));
    let loose_config = config
        .with_overrides(&[
            "expert.mpcc_tol_gap=1e-2".into(),
            "expert.mpcc_tol_feas=1e-3".into(),
        ])
        .unwrap();
    let loose = Mpcc::from_config(&loose_config).unwrap();
    assert_eq!(
        (loose.config().tol_gap, loose.config().tol_feas),
        (1e-2, 1e-3)
    );
    let loose_actions = actions(&loose);
    assert_ne!(bits(loose_actions.clone()), bits(expected.clone()));
    let near = loose_actions
        .iter()
        .zip(&expected)
        .all(|(x, y)| (x[0] - y[0]).abs() < 0.1 && (x[1] - y[1]).abs() < 0.05);
    assert!(near, "{loose_actions:?} against {expected:?}");
    let pid = RunConfig::load("v-a").unwrap();
    assert!(matches!(
        crate::relabel::Expert::from_config(&pid).unwrap(),
        crate::relabel::Expert::Pid(v) if v == pid.expert.pid_target_speed
    ));
}
