//! `learner`: a thin shell over the cabc-learner library. Each subcommand is one variant of [`Command`] and one
//! function; the distributed run (`run`) is added beside the others.

use anyhow::Context;
use cabc_learner::bench::run_bench;
use cabc_learner::compare;
use cabc_learner::demo::autolabel_demo;
use cabc_learner::rundir::RunDir;
use cabc_proto::config::RunConfig;
use clap::Parser;
use cli::{Cli, Command};

mod cli;

fn main() -> anyhow::Result<()> {
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
            let mut config = load(&config, false)?
                .with_overrides(&set)
                .context("applying --set")?;
            if baseline {
                config.make_baseline();
            }
            if !listen.is_empty() {
                config.bus.listen = listen;
            }
            let run_dir =
                RunDir::prepare(&config, run_dir, fresh).context("preparing the run folder")?;
            cabc_proto::telemetry::log_to_file(&run_dir.path().join("logs").join("learner.log"));
            if local {
                cabc_learner::serve::run_local(config, run_dir, resume)
            } else {
                cabc_learner::serve::run(config, run_dir, resume)
            }
        }
        Command::Prepare {
            config,
            baseline,
            set,
        } => {
            // --set first, so that it can change what --baseline makes (algorithm.baseline_lambda, baseline_rho).
            let mut config = load(&config, false)?
                .with_overrides(&set)
                .context("applying --set")?;
            if baseline {
                config.make_baseline();
            }
            let run_dir =
                RunDir::prepare(&config, None, false).context("preparing the run folder")?;
            println!("{}", run_dir.path().display());
            Ok(())
        }
        Command::Video { run, final_, out } => {
            let report = cabc_learner::show::video(&run, final_, out)?;
            println!("{} laps, ended by {}", report.laps, report.end_reason);
            Ok(())
        }
        Command::Show {
            key: run,
            gif: Some(which),
            out,
            ..
        } => {
            let shown = cabc_learner::show::gif(std::path::Path::new(&run), which, out)?;
            if let Some(report) = shown.evaluated {
                println!("{} laps, ended by {}", report.laps, report.end_reason);
            }
            println!("{}", shown.gif.display());
            Ok(())
        }
        Command::Show {
            config,
            key,
            gif: None,
            ..
        } => {
            let value = load(&config, false)?.show(&key);
            println!(
                "{}",
                value.with_context(|| format!("no key {key} in the configuration"))?
            );
            Ok(())
        }
        Command::ZenohdConfig {
            config,
            listen,
            set,
        } => {
            let config = load(&config, false)?
                .with_overrides(&set)
                .context("applying --set")?;
            let listen = match listen.is_empty() {
                true => cabc_bus::zenohd::default_listen(&config.bus.connect),
                false => listen,
            };
            let keys = cabc_proto::keys::Keys::new(&config.run.name)?;
            print!("{}", cabc_bus::zenohd::config(&config.bus, &keys, &listen)?);
            Ok(())
        }
        Command::AclDenials { log } => {
            let text = std::fs::read_to_string(&log)
                .with_context(|| format!("reading {}", log.display()))?;
            let denials = cabc_proto::telemetry::acl_denials_in_log(&text);
            println!("{}", serde_json::to_string_pretty(&denials)?);
            Ok(())
        }
        Command::Compare(options) => {
            print!("{}", compare::run(&options)?);
            Ok(())
        }
        Command::AutolabelDemo { options, json } => {
            let report = autolabel_demo(&options.rho, options.seed, &options.out)
                .context("auto-labelling demo")?;
            report.log();
            print_json(json, &report)
        }
        Command::Bench { options, json } => print_json(json, &run_bench(&options)),
        Command::BenchVision(options) => {
            let report = cabc_learner::bench_vision::run(&options).context("bench-vision")?;
            print_json(true, &report)
        }
    }
}

fn print_json(json: bool, report: &impl serde::Serialize) -> anyhow::Result<()> {
    if json {
        println!("{}", serde_json::to_string_pretty(report)?);
    }
    Ok(())
}

fn load(name: &str, baseline: bool) -> anyhow::Result<RunConfig> {
    RunConfig::load_variant(name, baseline).with_context(|| format!("loading configuration {name}"))
}
