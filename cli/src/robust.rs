//! `cabc robust RUN [--policy best|final|FILE] [study options] [--out DIR]`: a run's policy driven from random
//! spawns under action and state noise ([`cabc_robust`]); the summary as JSON on stdout, the full report (with every
//! spawn and its outcome per level) in OUT/robust.json, the figure in OUT/robust.png.

use crate::show::run_config;
use cabc_robust::RobustOptions;
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args)]
pub struct Args {
    /// The run folder (its config.toml, and its policy files unless --policy names another).
    pub run: PathBuf,
    /// The policy: `best` (RUN/best-policy.safetensors), `final` (RUN/final-policy.safetensors) or a safetensors
    /// file of the run's architecture.
    #[arg(long, default_value = "best")]
    pub policy: String,
    #[command(flatten)]
    pub options: RobustOptions,
    /// Where to write robust.json and robust.png (default: RUN/robust/, or RUN/robust-<track>/ with --track).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Drive this track instead of the run's (a circuit the policy never saw): a name (l-track-barc, oval, chicane,
    /// long) or a file (.csv, .toml), sized by --track-scale and --track-half-width (docs/TRACKS.md).
    #[arg(long)]
    pub track: Option<String>,
    /// With --track: multiply its lengths and widths by this.
    #[arg(long, default_value_t = 1.0, requires = "track")]
    pub track_scale: f64,
    /// With --track: the constraint's half-width (m) instead of the file's narrowest.
    #[arg(long, requires = "track")]
    pub track_half_width: Option<f64>,
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    let mut config = run_config(&args.run)?;
    let mut folder = "robust".to_string();
    if let Some(track) = &args.track {
        config.sim = cabc_proto::config::SimSection {
            track: track.clone(),
            track_scale: args.track_scale,
            track_half_width: args.track_half_width,
            actor_tracks: Vec::new(),
        };
        let name = std::path::Path::new(track)
            .file_stem()
            .map_or(track.clone(), |s| s.to_string_lossy().into_owned());
        folder = format!("robust-{name}");
    }
    let settings = args.options.settings(&config)?;
    let policy = cabc_robust::policy_path(&args.run, &args.policy);
    let out = args.out.clone().unwrap_or_else(|| args.run.join(folder));
    // One libtorch thread: a policy of one observation at a time gains nothing from more.
    cabc_models::device::one_cpu_thread();
    let started = Instant::now();
    let written = cabc_robust::study_policy_file(&config, &settings, &policy, &out)?;
    crate::print_json(&written.report.summary())?;
    eprintln!(
        "{} episodes in {:.1} s; wrote {} and {}",
        settings.spawns * settings.levels.len(),
        started.elapsed().as_secs_f64(),
        written.json.display(),
        written.png.display()
    );
    Ok(())
}
