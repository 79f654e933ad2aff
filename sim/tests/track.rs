//! Track checks against simulator.md §2.
use cabc_sim::track::{Track, TrackError, TrackPiece};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::{FRAC_PI_2, PI};

#[test]
fn length_and_widths() {
    let t = Track::l_track_barc();
    assert_eq!(t.length(), 17.461412207630154);
    assert_eq!(t.half_width(), 0.55);
    assert!((t.band() - 0.85).abs() < 1e-15);
}

#[test]
fn key_points_match_reference() {
    let t = Track::l_track_barc();
    let expect = [
        (0.0, 0.0, 0.0, 0.0),
        (2.251, 0.0, 0.0, 2.251),
        (2.251, 2.305, PI, 5.87169),
        (1.35, 2.305, PI, 6.77269),
        (0.3298325, 3.3251675, FRAC_PI_2, 8.37516),
        (0.3298325, 3.4751675, FRAC_PI_2, 8.52516),
        (-2.1265325, 3.4751675, -FRAC_PI_2, 12.38361),
        (-2.1265325, 1.2206275, -FRAC_PI_2, 14.63815),
        (-0.905905, 0.0, 0.0, 16.55551),
        (0.0, 0.0, 0.0, 17.46141),
    ];
    let kp = t.key_points();
    assert_eq!(kp.len(), expect.len());
    for (i, ((p, s), e)) in kp.iter().zip(expect.iter()).enumerate() {
        assert!(
            (p.x - e.0).abs() < 1e-6 && (p.y - e.1).abs() < 1e-6,
            "key point {i}: {p:?} vs {e:?}"
        );
        // ψ = ±π are the same heading; compare on the circle.
        let dpsi = (p.psi - e.2).rem_euclid(2.0 * PI);
        assert!(
            dpsi.min(2.0 * PI - dpsi) < 1e-6,
            "key point {i} heading {} vs {}",
            p.psi,
            e.2
        );
        assert!((s - e.3).abs() < 1e-5, "key point {i} cum_s {s} vs {}", e.3);
    }
    let (x0, y0, x1, y1) = t.centreline_bounds();
    assert!(
        (x0 + 2.1265).abs() < 1e-3 && (x1 - 3.4035).abs() < 1e-3,
        "{x0} {x1}"
    );
    assert!(y0.abs() < 1e-3 && (y1 - 4.7033).abs() < 1e-3, "{y0} {y1}");
}

#[test]
fn centreline_sample_on_first_straight() {
    let t = Track::l_track_barc();
    let p = t.local_to_global(1.0, 0.0, 0.0);
    assert!((p.x - 1.0).abs() < 1e-12 && p.y.abs() < 1e-12 && p.psi == 0.0);
    let p = t.local_to_global(1.0, 0.3, 0.2);
    assert!((p.y - 0.3).abs() < 1e-12 && (p.psi - 0.2).abs() < 1e-12);
}

#[test]
fn round_trip_3000_points() {
    let t = Track::l_track_barc();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut worst = 0.0f64;
    for _ in 0..3000 {
        let s = rng.gen_range(0.0..t.length());
        let e = rng.gen_range(-0.85..=0.85);
        let p = rng.gen_range(-1.0..=1.0);
        let pose = t.local_to_global(s, e, p);
        let f = t
            .global_to_local(pose.x, pose.y, pose.psi)
            .expect("inside the band");
        let ds = (f.s - s).abs().min(t.length() - (f.s - s).abs());
        worst = worst
            .max(ds)
            .max((f.x_tran - e).abs())
            .max((f.e_psi - p).abs());
    }
    assert!(worst < 1e-9, "worst round-trip error {worst}");
}

#[test]
fn unwrapped_heading_gives_same_e_psi() {
    let t = Track::l_track_barc();
    let pose = t.local_to_global(9.0, 0.2, 0.3);
    let a = t.global_to_local(pose.x, pose.y, pose.psi).unwrap();
    let b = t
        .global_to_local(pose.x, pose.y, pose.psi + 4.0 * PI)
        .unwrap();
    assert!((a.e_psi - b.e_psi).abs() < 1e-9);
}

#[test]
fn out_of_band_is_an_error() {
    let t = Track::l_track_barc();
    let pose = t.local_to_global(1.0, 0.86, 0.0);
    assert!(matches!(
        t.global_to_local(pose.x, pose.y, 0.0),
        Err(TrackError::OutOfBand { .. })
    ));
    assert!(t.global_to_local(0.5, 1.2, 0.0).is_err()); // infield
    assert!(t.global_to_local(20.0, -5.0, 0.0).is_err());
    assert!(t.global_to_local(f64::NAN, 0.0, 0.0).is_err());
}

#[test]
fn start_line_crossing() {
    let t = Track::l_track_barc();
    assert!(t.crosses_start_line((-0.05, 0.1), (0.05, 0.1)));
    assert!(!t.crosses_start_line((0.05, 0.1), (0.15, 0.1)));
    assert!(!t.crosses_start_line((-0.05, 0.7), (0.05, 0.7))); // beyond the ±0.55 line
}

#[test]
fn tracks_are_data() {
    // A 2 m × circle-ended stadium.
    let r = 1.0;
    let segs = vec![
        TrackPiece {
            length: 2.0,
            radius: 0.0,
        },
        TrackPiece {
            length: PI * r,
            radius: r,
        },
        TrackPiece {
            length: 2.0,
            radius: 0.0,
        },
        TrackPiece {
            length: PI * r,
            radius: r,
        },
    ];
    let t = Track::new(segs, 0.3, 0.1).unwrap();
    assert!((t.length() - (4.0 + 2.0 * PI)).abs() < 1e-12);
    let p = t.local_to_global(3.0, 0.0, 0.0);
    let f = t.global_to_local(p.x, p.y, p.psi).unwrap();
    assert!((f.s - 3.0).abs() < 1e-9);
    // Open or degenerate tracks are rejected.
    assert!(matches!(
        Track::new(
            vec![TrackPiece {
                length: 1.0,
                radius: 0.0
            }],
            0.3,
            0.1
        ),
        Err(TrackError::NotClosed { .. })
    ));
    assert!(Track::new(
        vec![TrackPiece {
            length: -1.0,
            radius: 0.0
        }],
        0.3,
        0.1
    )
    .is_err());
    assert!(Track::new(
        vec![TrackPiece {
            length: 1.0,
            radius: 0.2
        }],
        0.3,
        0.1
    )
    .is_err());
    assert!(Track::new(vec![], 0.3, 0.1).is_err());
    assert!(Track::new(
        vec![TrackPiece {
            length: 1.0,
            radius: 0.0
        }],
        f64::NAN,
        0.1
    )
    .is_err());
}
