//! Tracks from files (issue 76): the shipped tracks, F1TENTH centre lines and pieces files, and the errors a bad
//! file gets.
use cabc_sim::env::{Env, EnvConfig};
use cabc_sim::track::load::{self, Size, SHIPPED};
use cabc_sim::track::{Track, TrackError};
use cabc_sim::VehicleParams;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::PI;
use std::sync::Arc;

/// A circle of radius `r` as an F1TENTH centre line of `n` points, counter-clockwise from (r, 0).
fn circle_csv(r: f64, n: usize, width: f64) -> String {
    let mut text = String::from("# x_m, y_m, w_tr_right_m, w_tr_left_m\n");
    for i in 0..n {
        let a = 2.0 * PI * i as f64 / n as f64;
        text += &format!("{}, {}, {width}, {width}\n", r * a.cos(), r * a.sin());
    }
    text
}

fn parse(text: &str, file: &str, size: Size) -> Result<Track, TrackError> {
    load::parse(text, file, size)
}

fn load(name: &str, size: Size) -> Result<Track, TrackError> {
    load::load(name, size)
}

fn scaled(scale: f64) -> Size {
    Size {
        scale,
        half_width: None,
    }
}

fn file_error(e: TrackError) -> (String, Option<usize>, String) {
    match e {
        TrackError::File { file, line, why } => (file, line, why),
        other => panic!("not a file error: {other}"),
    }
}

#[test]
fn a_circles_curvature_is_one_over_its_radius() {
    let t = parse(&circle_csv(4.0, 50, 0.5), "circle.csv", Size::default()).unwrap();
    assert!((t.length() - 2.0 * PI * 4.0).abs() < 1e-3, "{}", t.length());
    // The spline through 50 points (0.5 m apart) bends with the circle to 0.5 %.
    for p in t.pieces() {
        assert!((p.radius / 4.0 - 1.0).abs() < 5e-3, "{p:?}");
    }
    assert_eq!(t.half_width(), 0.5);
    // Every point of the centre line is 4 m from the centre, which the start (4, 0) puts at (0, 4).
    for k in 0..100 {
        let p = t.local_to_global(t.length() * k as f64 / 100.0, 0.0, 0.0);
        assert!((p.x.hypot(p.y - 4.0) - 4.0).abs() < 5e-3, "{p:?}");
    }
    // Scaled by 2: twice as long and wide.
    let t2 = parse(&circle_csv(4.0, 50, 0.5), "circle.csv", scaled(2.0)).unwrap();
    assert!((t2.length() - 2.0 * t.length()).abs() < 1e-6);
    assert_eq!(t2.half_width(), 1.0);
}

#[test]
fn the_projection_and_its_inverse_round_trip_on_every_shipped_track() {
    let mut rng = ChaCha8Rng::seed_from_u64(76);
    for (name, _, _) in SHIPPED {
        let t = load(name, Size::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
        for _ in 0..2000 {
            let s = rng.gen_range(0.0..t.length());
            let x_tran = rng.gen_range(-t.band()..t.band()) * 0.999;
            let e_psi = rng.gen_range(-1.0..1.0);
            let p = t.local_to_global(s, x_tran, e_psi);
            let f = t.global_to_local(p.x, p.y, p.psi).unwrap();
            let ds = (f.s - s).abs().min(t.length() - (f.s - s).abs());
            assert!(ds < 1e-7, "{name}: s {s} -> {}", f.s);
            assert!(
                (f.x_tran - x_tran).abs() < 1e-7,
                "{name}: x_tran {x_tran} -> {}",
                f.x_tran
            );
            assert!(
                (f.e_psi - e_psi).abs() < 1e-7,
                "{name}: e_psi {e_psi} -> {}",
                f.e_psi
            );
        }
        // Beyond the band there is no Frenet frame.
        let p = t.local_to_global(1.0, t.band() + 0.05, 0.0);
        assert!(t.global_to_local(p.x, p.y, 0.0).is_err(), "{name}");
    }
}

#[test]
fn the_shipped_tracks_are_what_their_files_say() {
    let oval = load("oval", Size::default()).unwrap();
    assert!((oval.length() - (8.0 + 3.0 * PI)).abs() < 1e-12);
    assert_eq!(oval.half_width(), 0.55);
    let chicane = load("chicane", Size::default()).unwrap();
    assert!(
        (chicane.length() - 32.709_212_856_117_72).abs() < 1e-9,
        "{}",
        chicane.length()
    );
    // The long track's constraint is its narrowest half-width; its centre line is fitted into short pieces.
    let long = load("long", Size::default()).unwrap();
    assert!(
        (long.half_width() - 0.55).abs() < 1e-3,
        "{}",
        long.half_width()
    );
    assert!(
        long.length() > 60.0 && long.length() < 66.0,
        "{}",
        long.length()
    );
    assert!(long.pieces().len() > 1000);
    // Its curvature steps little from one 5 cm piece to the next (docs/TRACKS.md quotes the figure printed here).
    let k: Vec<f64> = long.pieces().iter().map(|p| 1.0 / p.radius).collect();
    let step = k
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .fold(0.0, f64::max);
    println!("long: largest curvature step between pieces {step:.4} 1/m");
    assert!(step < 0.1, "{step}");
    // The names the configuration takes are the shipped ones.
    let names = cabc_proto::config::SimSection::NAMES;
    assert_eq!(names[0], "l-track-barc");
    assert_eq!(&names[1..], SHIPPED.iter().map(|s| s.0).collect::<Vec<_>>());
    let e = load("monza", Size::default()).unwrap_err().to_string();
    assert!(e.contains("monza") && e.contains("oval"), "{e}");
}

#[test]
fn crossing_the_start_line_counts_one_lap_on_a_file_track() {
    // Drive the oval's centre line with a lap's worth of poses: one lap, and its reward is the lap's length.
    let t = Arc::new(load("oval", Size::default()).unwrap());
    let mut env = Env::new(t.clone(), VehicleParams::default(), EnvConfig::default());
    env.set_spawn(t.length() - 0.3, 0.0, 0.0, 1.0);
    let mut laps = 0;
    for _ in 0..10 {
        let r = env.step(&[0.0, 0.0]);
        if r.lap_completed {
            laps += 1;
        }
    }
    assert_eq!(laps, 1, "the car crossed the start line once");
}

#[test]
fn a_bad_file_is_refused_naming_the_file_and_line() {
    // Too few points.
    let (file, line, why) =
        file_error(parse("0,0,1,1\n1,0,1,1\n1,1,1,1\n", "few.csv", Size::default()).unwrap_err());
    assert_eq!(file, "few.csv");
    assert_eq!(line, Some(3));
    assert!(why.contains("too few points"), "{why}");
    // Not closed: half a circle.
    let half: String = circle_csv(4.0, 60, 0.5)
        .lines()
        .take(31)
        .map(|l| format!("{l}\n"))
        .collect();
    let (_, line, why) = file_error(parse(&half, "half.csv", Size::default()).unwrap_err());
    assert!(why.contains("not closed"), "{why}");
    assert_eq!(line, Some(31));
    // A width of 0 on line 5.
    let mut zero: Vec<String> = circle_csv(4.0, 40, 0.5).lines().map(String::from).collect();
    zero[4] = zero[4].replace(", 0.5, 0.5", ", 0, 0.5");
    let (_, line, why) =
        file_error(parse(&zero.join("\n"), "zero.csv", Size::default()).unwrap_err());
    assert_eq!(line, Some(5));
    assert!(why.contains("width"), "{why}");
    // Not a number.
    let mut nan: Vec<String> = circle_csv(4.0, 40, 0.5).lines().map(String::from).collect();
    nan[7] = "1.0, abc, 0.5, 0.5".into();
    let (_, line, why) =
        file_error(parse(&nan.join("\n"), "nan.csv", Size::default()).unwrap_err());
    assert_eq!(line, Some(8));
    assert!(why.contains("y_m"), "{why}");
    // A radius the band cannot follow: a circle of 0.58 m with the car's 1.1 m width (the band keeps 0.05 m).
    let (_, line, why) =
        file_error(parse(&circle_csv(0.58, 40, 0.55), "tight.csv", Size::default()).unwrap_err());
    assert!(line.is_some());
    assert!(why.contains("radius"), "{why}");
    // A crossing: a figure of eight.
    let mut eight = String::new();
    for i in 0..120 {
        let a = 2.0 * PI * i as f64 / 120.0;
        eight += &format!("{}, {}, 0.5, 0.5\n", 10.0 * a.sin(), 6.0 * (2.0 * a).sin());
    }
    let (_, _, why) = file_error(parse(&eight, "eight.csv", Size::default()).unwrap_err());
    assert!(
        why.contains("crosses itself") || why.contains("comes back"),
        "{why}"
    );
    // A peanut whose waist (1.5 m) is narrower than twice the band (1.7 m), its curves gentle (1.8 m and more).
    let mut peanut = String::new();
    for i in 0..200 {
        let t = 2.0 * PI * i as f64 / 200.0;
        let y = t.sin() * (0.75 + 3.0 * t.cos().powi(2));
        peanut += &format!("{}, {y}, 0.55, 0.55\n", 8.0 * t.cos());
    }
    let (_, line, why) = file_error(parse(&peanut, "peanut.csv", Size::default()).unwrap_err());
    assert!(why.contains("comes back"), "{why}");
    assert!(line.is_some());
    // Pieces that do not close; a piece of the wrong shape on its line.
    let open = "half_width = 0.55\npieces = [\n  { straight = 4.0 },\n  { turn = 180, radius = 1.5 },\n  { straight = 3.0 },\n  { turn = 180, radius = 1.5 },\n]\n";
    let (_, _, why) = file_error(parse(open, "open.toml", Size::default()).unwrap_err());
    assert!(why.contains("do not close"), "{why}");
    let wrong = "half_width = 0.55\npieces = [\n  { straight = 4.0 },\n  { turn = 180 },\n]\n";
    let (_, line, why) = file_error(parse(wrong, "wrong.toml", Size::default()).unwrap_err());
    assert_eq!(line, Some(4));
    assert!(why.contains("straight = L"), "{why}");
    let tight = "half_width = 0.55\npieces = [\n  { straight = 4.0 },\n  { turn = 180, radius = 0.5 },\n  { straight = 4.0 },\n  { turn = 180, radius = 0.5 },\n]\n";
    let (_, line, why) = file_error(parse(tight, "tight.toml", Size::default()).unwrap_err());
    assert_eq!(line, Some(4));
    assert!(why.contains("tighter than the car turns"), "{why}");
    // A circle of 2 km radius at scale 1: longer than a track may be.
    let e = parse(&circle_csv(2000.0, 400, 0.5), "huge.csv", Size::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("at most 10000 m"), "{e}");
    // A file that is not there, and one of another kind.
    let e = load("/nonexistent/track.csv", Size::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("/nonexistent/track.csv"), "{e}");
    assert!(parse("", "track.json", Size::default()).is_err());
}

#[test]
fn the_distance_field_of_a_fitted_track_is_its_lateral_offset_inside_the_band() {
    let t: Track = load("long", Size::default()).unwrap();
    let (x0, y0, x1, y1) = t.centreline_bounds();
    let res = 0.05;
    let (nx, ny) = (
        ((x1 - x0 + 4.0) / res) as usize,
        ((y1 - y0 + 4.0) / res) as usize,
    );
    let field = t.distance_field(x0 - 2.0, y0 - 2.0, res, nx, ny, 10.0);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for _ in 0..500 {
        let (ix, iy) = (rng.gen_range(0..nx), rng.gen_range(0..ny));
        let (x, y) = (
            x0 - 2.0 + (ix as f64 + 0.5) * res,
            y0 - 2.0 + (iy as f64 + 0.5) * res,
        );
        let exact = t.distance_to_centreline(x, y).min(10.0);
        let d = field[iy * nx + ix] as f64;
        if exact <= t.band() {
            assert!((d - exact).abs() < 1e-4, "({x}, {y}): {d} vs {exact}");
        } else {
            assert!((d - exact).abs() < 2.0 * res, "({x}, {y}): {d} vs {exact}");
        }
    }
}

#[test]
fn the_curvature_preview_is_the_same_on_every_track_where_the_road_is_the_same() {
    // The oval's straight, then its half circle of 1.5 m to the left: the preview sees the turn before it comes.
    let oval = Arc::new(load("oval", Size::default()).unwrap());
    assert!(oval.mean_curvature(1.0, 1.0).abs() < 1e-12);
    assert!((oval.mean_curvature(5.0, 1.0) - 1.0 / 1.5).abs() < 1e-9);
    assert!((oval.mean_curvature(3.5, 1.0) - 0.5 / 1.5).abs() < 1e-9);
    // The L-track's first straight and left hairpin (radius 1.1525) read the same way.
    let l = Track::l_track_barc();
    assert!(l.mean_curvature(0.5, 1.0).abs() < 1e-12);
    assert!((l.mean_curvature(3.0, 1.0) - 1.0 / 1.1525).abs() < 1e-9);
    // The environment observes it in place of s under `track_feature = curvature-preview`.
    let config = EnvConfig {
        track_feature: cabc_proto::config::TrackFeature::CurvaturePreview,
        preview_m: 1.0,
        ..EnvConfig::default()
    };
    let mut env = Env::new(oval.clone(), VehicleParams::default(), config);
    env.set_spawn(3.5, 0.0, 0.0, 1.0);
    assert!((env.observation().state[3] - 0.5 / 1.5).abs() < 1e-9);
    let mut plain = Env::new(oval, VehicleParams::default(), EnvConfig::default());
    plain.set_spawn(3.5, 0.0, 0.0, 1.0);
    assert!((plain.observation().state[3] - 3.5).abs() < 1e-9);
}
