//! `learner`: the learner process of a run, a thin shell over cabc-learning (Algorithm 1) and cabc-outputs (the run
//! folder): `run` trains, `prepare` makes a run folder. The tools for finished runs and deployments are `cabc`'s.

use anyhow::Context;
use cabc_outputs::RunDir;
use cabc_proto::config::RunConfig;
use cabc_proto::ports::PortError;
use clap::Parser;
use cli::{Cli, Command};

mod cli;
mod serve;
mod watch;

fn main() -> std::process::ExitCode {
    match learner() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            // One line, the causes after colons (a backtrace, with RUST_BACKTRACE, is no user's error message).
            eprintln!("Error: {e:#}");
            let no_actors = e.chain().any(|c| {
                matches!(
                    c.downcast_ref::<PortError>(),
                    Some(PortError::NoActors { .. })
                )
            });
            // Gave up for want of actors: not a crash, so a supervisor ends the run instead of restarting it.
            let code = if no_actors {
                cabc_runfolder::exit::NO_ACTORS
            } else {
                1
            };
            std::process::ExitCode::from(code as u8)
        }
    }
}

fn learner() -> anyhow::Result<()> {
    cabc_proto::telemetry::init();
    cabc_models::flush_denormals();
    match Cli::parse().command {
        Command::Run {
            config,
            run_dir,
            resume,
            fresh,
            baseline,
            listen,
            local,
            set,
        } => {
            let mut config = resolve(&config, &set, baseline)?;
            if !listen.is_empty() {
                config.bus.listen = listen;
            }
            let run_dir =
                RunDir::prepare(&config, run_dir, fresh).context("preparing the run folder")?;
            cabc_proto::telemetry::log_to_file(&run_dir.path().join("logs").join("learner.log"));
            if local {
                serve::run_local(config, run_dir, resume)
            } else {
                serve::run(config, run_dir, resume)
            }
        }
        Command::Prepare {
            config,
            baseline,
            set,
        } => {
            let config = resolve(&config, &set, baseline)?;
            let run_dir =
                RunDir::prepare(&config, None, false).context("preparing the run folder")?;
            println!("{}", run_dir.path().display());
            Ok(())
        }
    }
}

/// The run's configuration: the preset or file `name`, then `--set`, then `--baseline` (--set first, so that it can
/// change what --baseline makes: algorithm.baseline_lambda, baseline_rho).
fn resolve(name: &str, set: &[String], baseline: bool) -> anyhow::Result<RunConfig> {
    let mut config = RunConfig::load_variant(name, false)
        .with_context(|| format!("loading configuration {name}"))?
        .with_overrides(set)
        .context("applying --set")?;
    if baseline {
        config.make_baseline();
    }
    Ok(config)
}
