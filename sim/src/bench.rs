//! Throughput of the simulator: env steps per second under the PID on one core, and camera frames per second on one
//! core and on all of them (frames of at least `camera::PARALLEL_PIXELS` pixels are drawn on every core).

use std::fmt;
use std::time::Instant;

use crate::camera::{Camera, Sun, TrackLookup, REFERENCE_FOV_DEG};
use crate::env::{Env, Spawn};
use crate::pid::PidLaneFollower;
use crate::track::Pose;

/// Camera sizes measured (square images, pixels a side).
pub const CAMERA_SIZES: [usize; 2] = [64, 224];

/// Frames per second of one camera size on `threads` cores.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CameraRate {
    pub size: usize,
    pub threads: usize,
    pub frames_per_s: f64,
    /// A sum of pixels, so the renderer cannot be optimised away (and frames can be compared).
    pub checksum: u64,
}

/// The measurements.
#[derive(Clone, Debug, serde::Serialize)]
pub struct BenchReport {
    pub env_steps_per_s: f64,
    /// Time to build the camera's track lookup grid (once per track), ms.
    pub lookup_build_ms: f64,
    pub camera: Vec<CameraRate>,
}

impl fmt::Display for BenchReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "env: {:.0} steps/s (state only, PID, one core)",
            self.env_steps_per_s
        )?;
        writeln!(
            f,
            "camera lookup grid build: {:.1} ms (once per track)",
            self.lookup_build_ms
        )?;
        for c in &self.camera {
            writeln!(
                f,
                "camera {0}x{0}: {1:.0} frames/s ({2} threads) [checksum {3}]",
                c.size, c.frames_per_s, c.threads, c.checksum
            )?;
        }
        Ok(())
    }
}

/// Measures for `seconds` (at least 1) each: env steps (PID from the fixed spawn, random respawn on truncation),
/// then frames of each of [`CAMERA_SIZES`] along the first 200 poses of that drive.
pub fn run(seconds: f64) -> BenchReport {
    let seconds = if seconds.is_finite() {
        seconds.max(1.0)
    } else {
        1.0
    };
    let mut env = Env::barc();
    let mut rng = Env::rng(0, 0);
    let mut pid = PidLaneFollower::default();
    let mut obs = env.reset(Spawn::Fixed, &mut rng);
    let (start, mut n) = (Instant::now(), 0u64);
    let mut poses = Vec::with_capacity(200);
    while start.elapsed().as_secs_f64() < seconds {
        for _ in 0..1000 {
            let r = env.step(&pid.action(obs.state[0], obs.state[4], obs.state[5]));
            obs = r.obs;
            if poses.len() < 200 {
                let [x, y, psi] = obs.pose;
                poses.push(Pose { x, y, psi });
            }
            if r.truncation.is_some() {
                obs = env.reset(Spawn::Random, &mut rng);
                pid.reset();
            }
        }
        n += 1000;
    }
    let env_steps_per_s = n as f64 / start.elapsed().as_secs_f64();

    let track = env.track().clone();
    let t0 = Instant::now();
    let lookup = TrackLookup::new(&track, 0.01);
    let lookup_build_ms = t0.elapsed().as_secs_f64() * 1e3;
    let sun = Sun::default();
    let all = rayon::current_num_threads();
    let camera = CAMERA_SIZES
        .iter()
        .flat_map(|&size| [(size, 1), (size, all)])
        .filter_map(|(size, threads)| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .ok()?;
            let mut cam = Camera::new(size, size, REFERENCE_FOV_DEG);
            let (start, mut n) = (Instant::now(), 0usize);
            let mut checksum = 0u64;
            while start.elapsed().as_secs_f64() < seconds {
                let img = pool.install(|| cam.render(&lookup, poses[n % poses.len()], sun));
                checksum = checksum.wrapping_add(img.rgb[img.rgb.len() / 2] as u64);
                n += 1;
            }
            Some(CameraRate {
                size,
                threads,
                frames_per_s: n as f64 / start.elapsed().as_secs_f64(),
                checksum,
            })
        })
        .collect();
    BenchReport {
        env_steps_per_s,
        lookup_build_ms,
        camera,
    }
}
