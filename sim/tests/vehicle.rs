//! Vehicle checks: simulator.md §7 check values and analytic Jacobians.
use cabc_sim::{PidLaneFollower, Track, VehicleParams};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// PID from the fixed spawn (s 0.1, v 0.5), 10 sub-steps of one RK4 step each, Frenet after each step.
fn pid_rollout(n: usize) -> Vec<[f64; 6]> {
    let track = Track::l_track_barc();
    let p = VehicleParams::default();
    let mut pid = PidLaneFollower::default();
    let pose = track.local_to_global(0.1, 0.0, 0.0);
    let mut q = [0.5, 0.0, 0.0, pose.x, pose.y, pose.psi];
    let mut f = track.global_to_local(pose.x, pose.y, pose.psi).unwrap();
    let mut out = vec![[q[0], q[1], q[2], f.s, f.x_tran, f.e_psi]];
    for _ in 0..n {
        let u = pid.action(q[0], f.x_tran, f.e_psi);
        for _ in 0..10 {
            q = p.rk4(&q, &u, 0.01);
            f = track.global_to_local(q[3], q[4], q[5]).unwrap();
        }
        out.push([q[0], q[1], q[2], f.s, f.x_tran, f.e_psi]);
    }
    out
}

#[test]
fn check_values_pid_fixed_spawn() {
    let traj = pid_rollout(50);
    let v = [0.5, 0.575, 0.63875, 0.692938, 0.738997, 0.778147];
    let s = [0.1, 0.15375, 0.214438, 0.281022, 0.352619, 0.428476];
    for k in 0..6 {
        let x = traj[k];
        assert!((x[0] - v[k]).abs() < 1e-5, "k={k} v {} vs {}", x[0], v[k]);
        assert!((x[3] - s[k]).abs() < 1e-5, "k={k} s {} vs {}", x[3], s[k]);
        for i in [1, 2, 4, 5] {
            assert_eq!(x[i], 0.0, "k={k} entry {i}");
        }
    }
    let k10 = [0.9015628, 0.0, 0.0, 0.85236961, 0.0, 0.0];
    let k50 = [
        0.99490123,
        0.09910894,
        0.82484078,
        4.66046105,
        -0.06474356,
        -0.1043586,
    ];
    for i in 0..6 {
        assert!(
            (traj[10][i] - k10[i]).abs() < 1e-5,
            "k=10 entry {i}: {} vs {}",
            traj[10][i],
            k10[i]
        );
        assert!(
            (traj[50][i] - k50[i]).abs() < 3e-4,
            "k=50 entry {i}: {} vs {}",
            traj[50][i],
            k50[i]
        );
    }
}

#[test]
fn step_is_repeated_rk4() {
    let p = VehicleParams::default();
    let q = [1.2, 0.1, 0.5, 0.3, -0.2, 0.7];
    let u = [0.5, 0.2];
    let mut r = q;
    for _ in 0..10 {
        r = p.rk4(&r, &u, 0.01);
    }
    assert_eq!(p.step(&q, &u, 0.1, 10), r);
}

#[test]
fn jacobians_match_central_differences() {
    let p = VehicleParams::default();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for _ in 0..20 {
        let q = [
            rng.gen_range(0.5..3.0),
            rng.gen_range(-0.5..0.5),
            rng.gen_range(-2.0..2.0),
            rng.gen_range(-2.0..2.0),
            rng.gen_range(-2.0..2.0),
            rng.gen_range(-3.0..3.0),
        ];
        let u = [rng.gen_range(-2.0..2.0), rng.gen_range(-0.45..0.45)];
        let (a, b) = p.jacobians(&q, &u);
        let h = 1e-6;
        for j in 0..8 {
            let (mut qp, mut qm, mut up, mut um) = (q, q, u, u);
            if j < 6 {
                qp[j] += h;
                qm[j] -= h;
            } else {
                up[j - 6] += h;
                um[j - 6] -= h;
            }
            let fp = p.derivatives(&qp, &up);
            let fm = p.derivatives(&qm, &um);
            for i in 0..6 {
                let fd = (fp[i] - fm[i]) / (2.0 * h);
                let an = if j < 6 { a[(i, j)] } else { b[(i, j - 6)] };
                let err = (fd - an).abs() / an.abs().max(1.0);
                assert!(
                    err < 1e-6,
                    "d f{i}/d x{j}: analytic {an} vs fd {fd} at {q:?} {u:?}"
                );
            }
        }
    }
}
