//! Tests of the whole controller: a QP at a straight-line state and closed-loop laps (expert.md §13).

use super::*;
use crate::drive::{drive, DriveEnd, DriveOptions};

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
    assert!(z1[8].abs() < 1e-2, "δ* = {}", z1[8]);
    // v_s tracks v_x over the first stages (the lag cost is stiff).
    for k in 1..=5 {
        let z = sol.stages[k];
        assert!((z[VS] - z[0]).abs() < 0.15, "stage {k}: v_s {} vs v_x {}", z[VS], z[0]);
    }
    assert!(sol.slacks.iter().all(|&s| s.abs() < 1e-6), "{:?}", sol.slacks);

    let step = mpcc.step(&mut stream, &q).unwrap();
    assert!(step.success, "{}", step.status);
    assert!(step.action[1].abs() < 1e-2 && step.action[0] > 0.0, "{:?}", step.action);
}

#[test]
fn rejects_bad_states_without_panicking() {
    let mpcc = Mpcc::reference();
    let mut stream = mpcc.start(&crate::drive::fixed_spawn(mpcc.track())).unwrap();
    assert!(matches!(mpcc.step(&mut stream, &[f64::NAN, 0.0, 0.0, 1.0, 0.0, 0.0]), Err(MpccError::NonFinite(_))));
    assert!(matches!(mpcc.step(&mut stream, &[1.0, 0.0, 0.0, 1.0, 2.0, 0.0]), Err(MpccError::OffTrack(_))));
    assert!(mpcc.start(&[1.0, 0.0, 0.0, 1.0, f64::INFINITY, 0.0]).is_err());
}

#[test]
fn drives_laps_from_the_fixed_spawn() {
    let mpcc = Mpcc::reference();
    let opts = DriveOptions { laps: 3, max_steps: 400, stop_on_failure: true };
    let r = drive(&mpcc, &VehicleParams::default(), &opts);
    let last = r.steps.last().unwrap();
    eprintln!("end {:?}, laps {:?}, failures {}, last {:?}", r.end, r.lap_times, r.failures, last);
    assert_eq!(r.end, DriveEnd::Laps, "laps {:?}", r.lap_times);
    assert_eq!(r.failures, 0);
    // The first lap starts at 0.5 m/s; the flying laps should be near the paper's 4.805 s mean.
    for &t in &r.lap_times[1..] {
        assert!((4.3..=5.3).contains(&t), "lap {t} s");
    }
    let max_ey = r.steps.iter().map(|s| s.frenet.x_tran.abs()).fold(0.0, f64::max);
    eprintln!("max |e_y| = {max_ey:.3}");
}
