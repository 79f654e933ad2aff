//! Camera checks: symmetry, sun dependence, determinism.
use std::sync::OnceLock;

use cabc_sim::camera::{Camera, Frame, Sun, TrackLookup};
use cabc_sim::Track;

fn lookup() -> &'static TrackLookup {
    static L: OnceLock<TrackLookup> = OnceLock::new();
    L.get_or_init(|| TrackLookup::new(&Track::l_track_barc(), 0.01))
}

fn render(w: usize, h: usize, s: f64, e: f64, p: f64, sun: Sun) -> Frame {
    let track = Track::l_track_barc();
    let mut cam = Camera::new(w, h, 110.0);
    cam.render(lookup(), track.local_to_global(s, e, p), sun)
        .clone()
}

#[test]
fn centred_car_sees_a_symmetric_road() {
    let overhead = Sun {
        azimuth: 0.0,
        elevation: std::f64::consts::FRAC_PI_2,
    };
    let img = render(96, 96, 0.3, 0.0, 0.0, overhead);
    // Compare the near field (ground closer than ~1.2 m: rows well below the horizon), where the first
    // straight is the whole view.
    let (mut diff, mut total) = (0, 0);
    for y in 64..96 {
        for x in 0..48 {
            total += 1;
            if img.pixel(x, y) != img.pixel(95 - x, y) {
                diff += 1;
            }
        }
    }
    assert!(
        diff * 100 <= total,
        "{diff} of {total} mirrored pixels differ"
    );
    // The centre of the bottom row is road, the bottom corners are walls (brighter than the road).
    let road = img.pixel(48, 95);
    let corner = img.pixel(0, 52);
    assert!(corner[0] > road[0] + 30, "wall {corner:?} vs road {road:?}");
    // The top row is sky (blue dominates).
    let sky = img.pixel(48, 0);
    assert!(sky[2] > sky[0] && sky[2] > 150);
}

#[test]
fn sun_direction_changes_the_image_and_rendering_is_deterministic() {
    let a = render(
        64,
        64,
        4.0,
        0.2,
        0.1,
        Sun {
            azimuth: 0.5,
            elevation: 0.4,
        },
    );
    let b = render(
        64,
        64,
        4.0,
        0.2,
        0.1,
        Sun {
            azimuth: 3.5,
            elevation: 1.1,
        },
    );
    let a2 = render(
        64,
        64,
        4.0,
        0.2,
        0.1,
        Sun {
            azimuth: 0.5,
            elevation: 0.4,
        },
    );
    assert_eq!(a, a2);
    let differing = a
        .rgb
        .chunks(3)
        .zip(b.rgb.chunks(3))
        .filter(|(p, q)| p != q)
        .count();
    assert!(
        differing > 64 * 64 / 20,
        "only {differing} pixels differ between suns"
    );
}

#[test]
fn low_sun_casts_wall_shadows_on_the_road() {
    // Sun low in the +y direction (left of a car on the first straight): the left wall shades the road.
    let sun = Sun {
        azimuth: std::f64::consts::FRAC_PI_2,
        elevation: 20f64.to_radians(),
    };
    let img = render(96, 96, 0.3, 0.0, 0.0, sun);
    let row = 80;
    let left = img.pixel(5, row);
    let right = img.pixel(90, row);
    assert!(
        right[0] > left[0] + 10,
        "left road {left:?} should be in shadow vs right {right:?}"
    );
}

#[test]
fn any_resolution_and_png() {
    let img = render(17, 5, 10.0, -0.3, 0.4, Sun::default());
    assert_eq!(img.rgb.len(), 17 * 5 * 3);
    let path = std::env::temp_dir().join(format!("cabc_sim_cam_{}.png", std::process::id()));
    img.write_png(&path).unwrap();
    assert!(std::fs::metadata(&path).unwrap().len() > 50);
    let _ = std::fs::remove_file(path);
}

fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x100_0000_01b3)
    })
}

/// Issue 56: a frame of 224x224 is drawn on all cores, and its bits are those the renderer drew on one core before
/// (the digests of `cabc-sim render --size 224x224 --s S --x-tran X --e-psi E --sun AZ,EL` at 7d4e9b9, read off its
/// PNGs), whatever the number of threads.
#[test]
fn a_frame_drawn_on_all_cores_is_the_one_drawn_on_one() {
    let track = Track::l_track_barc();
    let cases = [
        ((2.0, 0.3, 0.2), (30.0, 15.0), 0xf320_c498_cdc8_2e5a_u64),
        ((11.5, -0.4, -0.3), (200.0, 8.0), 0x02f2_e2aa_f86c_92a5),
        ((7.0, 0.0, 0.0), (100.0, 60.0), 0x9750_9e65_cedb_65f6),
    ];
    for threads in [1, 4] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        for (pose, (azimuth, elevation), digest) in cases {
            let sun = Sun {
                azimuth: f64::to_radians(azimuth),
                elevation: f64::to_radians(elevation),
            };
            let camera = Camera::new(224, 224, 110.0);
            let mut frame = Frame::new(1, 1);
            let at = track.local_to_global(pose.0, pose.1, pose.2);
            pool.install(|| camera.render_into(lookup(), at, sun, &mut frame));
            assert_eq!((frame.width, frame.height), (224, 224));
            assert_eq!(
                fnv1a(&frame.rgb),
                digest,
                "{threads} threads, pose {pose:?}, sun {azimuth},{elevation}"
            );
        }
    }
}
