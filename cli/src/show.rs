//! A run's evaluation videos on request: `cabc show RUN --gif [VERSION]` and `cabc video RUN [--final]`.
//!
//! Which policy a video can show: the learner keeps the weights of two policies only, the best evaluated version's
//! (`best-policy.safetensors`) and the final one (`final-policy.safetensors`); and it drew a video of every
//! evaluation that completed its laps (`plots/eval-v<N>.gif`, from the report's line). So VERSION is
//! * `best` (the default): the best version's weights evaluated anew, from the fixed spawn under that version's
//!   evaluation seed (the same episode as its evaluation, on this machine's CPU);
//! * `final`: the final policy evaluated anew;
//! * a number N: `plots/eval-v<N>.gif` when the learner drew it; otherwise, when N is the best version, its weights
//!   evaluated anew; otherwise an error that says which versions can be shown.
//!
//! An evaluation anew knows the car's full state at every step: the video draws its poses and, in a camera run, the
//! camera's view from them under the evaluation's sun ([`cabc_outputs::video::gif`]).

use anyhow::{bail, Context, Result};
use cabc_learning::checkpoint::Checkpoint;
use cabc_learning::state::{LearnerState, CHECKPOINT};
use cabc_outputs::rundir::{load_policy, KeptPolicy, RunDir};
use cabc_outputs::video::Watched;
use cabc_proto::config::RunConfig;
use cabc_proto::messages::EvalReport;
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct ShowArgs {
    /// Run configuration: a preset (v-b-ref, v-b, v-a-cpu, smoke, ...) or a TOML file.
    #[arg(long, short, default_value = cabc_proto::config::DEFAULT_PRESET)]
    config: String,
    /// A configuration value applied before the key is read, `key=value` (as `learner prepare --set`); repeatable.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// The configuration's key; with --gif, the run folder.
    key: String,
    /// A GIF of VERSION: `best` (the default: best-policy.safetensors evaluated anew), `final` (the final policy
    /// evaluated anew) or a version number (its evaluation's plots/eval-v<N>.gif, or the best version's weights
    /// evaluated anew; no other version's weights are kept).
    #[arg(long, value_name = "VERSION", num_args = 0..=1, default_missing_value = "best")]
    gif: Option<Which>,
    /// Where to write the GIF (default: in the run folder).
    #[arg(long, requires = "gif")]
    out: Option<PathBuf>,
}

#[derive(clap::Args)]
pub struct VideoArgs {
    /// The run folder.
    run: PathBuf,
    /// The final policy instead of the best.
    #[arg(long = "final")]
    final_: bool,
    /// Where to write the GIF (default: RUN/best-policy.gif or RUN/final-policy.gif).
    #[arg(long)]
    out: Option<PathBuf>,
}

/// Which policy of a run a video shows: a kept one's weights, or a version's video.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Which {
    Kept(KeptPolicy),
    Version(u64),
}

impl std::str::FromStr for Which {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match KeptPolicy::named(s) {
            Some(kept) => Ok(Which::Kept(kept)),
            None => s.parse().map(Which::Version).map_err(|_| {
                format!("{s:?}: a policy version is `best`, `final` or a version number")
            }),
        }
    }
}

/// What `cabc show RUN --gif` did.
#[derive(Debug)]
pub struct Shown {
    pub gif: PathBuf,
    /// The evaluation run anew, when there was one.
    pub evaluated: Option<EvalReport>,
}

/// `cabc show`: with `--gif`, a video of run folder `key`'s policy (its path printed, and the evaluation's laps when
/// one was driven anew); else the value of configuration `config`'s dotted `key`.
pub fn run(args: &ShowArgs) -> Result<()> {
    let key = &args.key;
    if let Some(which) = args.gif {
        let shown = gif(Path::new(key), which, args.out.clone())?;
        if let Some(report) = shown.evaluated {
            println!("{} laps, ended by {}", report.laps, report.end_reason);
        }
        println!("{}", shown.gif.display());
        return Ok(());
    }
    let value = crate::load(&args.config)?
        .with_overrides(&args.set)
        .context("applying --set")?
        .show(key);
    println!(
        "{}",
        value.with_context(|| format!("no key {key} in the configuration"))?
    );
    Ok(())
}

/// `cabc show RUN --gif [VERSION]`: the GIF of `which` (see the module doc), written to `out` (default
/// `RUN/best-policy.gif`, `RUN/final-policy.gif`, `RUN/plots/eval-v<N>.gif`).
pub fn gif(run: &Path, which: Which, out: Option<PathBuf>) -> Result<Shown> {
    let config = run_config(run)?;
    let state = state(run);
    let best = state
        .as_ref()
        .and_then(|s| s.evaluations.best())
        .map(|e| e.version);
    // The video's file unless `out` names one (None: the kept policy's, RunDir::policy_video).
    let (weights, version, default_out) = match which {
        Which::Kept(KeptPolicy::Best) => (KeptPolicy::Best, best.unwrap_or(0), None),
        // The version the final policy would have been published as.
        Which::Kept(KeptPolicy::Final) => (
            KeptPolicy::Final,
            state.as_ref().map_or(0, |s| s.next_epoch),
            None,
        ),
        Which::Version(n) => {
            let drawn = run.join(RunDir::eval_video(n));
            if drawn.exists() {
                let gif = match out {
                    Some(out) => {
                        std::fs::copy(&drawn, &out).with_context(|| {
                            format!("copying {} to {}", drawn.display(), out.display())
                        })?;
                        out
                    }
                    None => drawn,
                };
                return Ok(Shown {
                    gif,
                    evaluated: None,
                });
            }
            if best != Some(n) {
                bail!(
                    "{}: no video of version {n} (plots/eval-v{n}.gif is drawn for evaluations that complete {} \
                     laps; versions with one: {:?}), and its weights are not kept (only the best version's, {}, \
                     and the final policy's): try --gif best or --gif final",
                    run.display(),
                    config.collection.eval_laps,
                    RunDir::eval_videos(run),
                    best.map_or("none yet".into(), |b| b.to_string()),
                );
            }
            (KeptPolicy::Best, n, Some(drawn))
        }
    };
    let out = out
        .or(default_out)
        .unwrap_or_else(|| run.join(RunDir::policy_video(weights)));
    let report = evaluate_anew(run, &config, weights, version, &out)?;
    Ok(Shown {
        gif: out,
        evaluated: Some(report),
    })
}

/// `cabc video RUN`: the best policy (or the final one with `--final`) evaluated anew; its video written to `--out`
/// (default `RUN/<which>-policy.gif`) and its laps printed.
pub fn video(args: &VideoArgs) -> Result<()> {
    let kept = match args.final_ {
        true => KeptPolicy::Final,
        false => KeptPolicy::Best,
    };
    let shown = gif(&args.run, Which::Kept(kept), args.out.clone())?;
    let report = shown.evaluated.context("no evaluation was run")?;
    println!("{} laps, ended by {}", report.laps, report.end_reason);
    Ok(())
}

/// The run folder's configuration, RUN/config.toml.
pub(crate) fn run_config(run: &Path) -> Result<RunConfig> {
    let config_path = run.join(RunDir::CONFIG);
    RunConfig::load(&config_path.display().to_string())
        .with_context(|| format!("{} is not a run folder", run.display()))
}

/// The run's learner state, from its checkpoint (None without one: logged).
fn state(run: &Path) -> Option<LearnerState> {
    let read = Checkpoint::open(&run.join(CHECKPOINT))
        .map_err(|e| e.to_string())
        .and_then(|ck| LearnerState::load(&ck).map_err(|e| e.to_string()));
    read.map_err(|e| tracing::warn!("the run's evaluations are unknown: {e}"))
        .ok()
}

/// Evaluates `RUN/<weights>-policy.safetensors` anew as the evaluator would version `version` (on the CPU), and
/// writes its video with the car's poses and, in a camera run, its view under the evaluation's sun.
fn evaluate_anew(
    run: &Path,
    config: &RunConfig,
    weights: KeptPolicy,
    version: u64,
    out: &Path,
) -> Result<EvalReport> {
    let policy = load_policy(&run.join(RunDir::policy_file(weights)))?;
    let mut watched = Watched::default();
    let report = cabc_actor::evaluate::evaluate_watched(
        "video",
        version,
        config,
        |input| Ok(cabc_actor::run::act(&policy, input)?),
        |env| watched.watch(env),
    )?;
    watched
        .gif(out, config, &report)
        .map_err(|e| anyhow::anyhow!("{}: {e}", out.display()))?;
    tracing::info!(
        version,
        laps = report.laps,
        end = %report.end_reason,
        "wrote {}",
        out.display()
    );
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn versions_are_best_final_or_numbers() {
        assert_eq!("best".parse(), Ok(Which::Kept(KeptPolicy::Best)));
        assert_eq!("final".parse(), Ok(Which::Kept(KeptPolicy::Final)));
        assert_eq!("57".parse(), Ok(Which::Version(57)));
        assert!("v57".parse::<Which>().is_err());
    }

    #[test]
    fn a_version_without_video_or_weights_is_refused_and_a_drawn_one_is_shown() {
        let dir = tempfile::tempdir().unwrap();
        let run = cabc_outputs::rundir::RunDir::prepare(
            &RunConfig::load("smoke").unwrap(),
            Some(dir.path().join("r")),
            false,
        )
        .unwrap();
        let err = gif(run.path(), Which::Version(3), None).unwrap_err();
        assert!(err.to_string().contains("no video of version 3"), "{err}");
        std::fs::write(run.plots().join("eval-v3.gif"), b"GIF89a").unwrap();
        let err = gif(run.path(), Which::Version(4), None).unwrap_err();
        assert!(err.to_string().contains("versions with one: [3]"), "{err}");
        let out = dir.path().join("out.gif");
        let shown = gif(run.path(), Which::Version(3), Some(out.clone())).unwrap();
        assert_eq!((shown.gif, shown.evaluated.is_none()), (out.clone(), true));
        assert_eq!(std::fs::read(out).unwrap(), b"GIF89a");
        let err = gif(run.path(), Which::Kept(KeptPolicy::Best), None).unwrap_err();
        assert!(
            format!("{err:#}").contains("best-policy.safetensors"),
            "{err:#}"
        );
    }

    #[test]
    fn a_camera_policy_evaluated_anew_shows_its_view() {
        let dir = tempfile::tempdir().unwrap();
        let mut config = RunConfig::load("smoke-camera").unwrap();
        config.collection.eval_laps = 1;
        let run = cabc_outputs::rundir::RunDir::prepare(&config, Some(dir.path().join("r")), false)
            .unwrap();
        let arch = cabc_models::PolicyArch::from_config(&config);
        let policy = cabc_models::Policy::new(arch, tch::Device::Cpu, 5);
        use cabc_models::Network;
        run.write_policy(KeptPolicy::Final, &policy.to_bytes())
            .unwrap();
        let shown = gif(run.path(), Which::Kept(KeptPolicy::Final), None).unwrap();
        assert_eq!(shown.gif, run.path().join("final-policy.gif"));
        assert!(shown.evaluated.unwrap().steps > 0);
        let bytes = std::fs::read(&shown.gif).unwrap();
        assert!(bytes.len() < 3 << 20, "{} bytes", bytes.len());
        let mut decoder = gif::DecodeOptions::new()
            .read_info(bytes.as_slice())
            .unwrap();
        assert_eq!((decoder.width(), decoder.height()), (730, 350));
        let mut frames = 0;
        while decoder.read_next_frame().unwrap().is_some() {
            frames += 1;
        }
        assert_eq!(frames, cabc_outputs::video::FRAMES);
    }
}
