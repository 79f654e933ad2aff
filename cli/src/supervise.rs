//! `cabc supervise`: a run's processes under [`cabc_supervise::Supervisor`]: the main job's (deploy/run-local.sh),
//! or those a machine adds to a running run (`--roles actor`, deploy/SCALE-OUT.md). `cabc chaos`: the same under a
//! seeded schedule of faults ([`cabc_supervise::chaos`]), with its report.

use anyhow::{Context, Result};
use cabc_proto::config::RunConfig;
use cabc_supervise::chaos::{Chaos, FaultKind};
use cabc_supervise::roster::{Role, Roster};
use cabc_supervise::{Ended, Supervisor};
use std::io::IsTerminal;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// The run's configuration file (the run folder's config.toml: `learner prepare` writes it).
    #[arg(long, short)]
    config: PathBuf,
    /// The run folder: the logs (logs/<process>.log) and supervision.json go there.
    #[arg(long)]
    run_dir: PathBuf,
    /// The folder of the binaries (learner, actor, expert-server).
    #[arg(long)]
    bin: PathBuf,
    /// The roles run here, comma-separated: learner, expert, actor, evaluator (default: all four), and router: a
    /// standalone zenohd on bus.connect that every process dials, the learner too (bus.listen = []), restarted when
    /// it dies like the others (deploy/run-local.sh --router).
    #[arg(long, value_delimiter = ',')]
    roles: Vec<Role>,
    /// Collecting actors started here (default: actors.count).
    #[arg(long)]
    actors: Option<u32>,
    /// The number of the first actor's id (actor-<first>, actor-<first+1>, ...): another machine's actors take ids
    /// the run does not use yet.
    #[arg(long, default_value_t = 0)]
    first_actor: u32,
    /// The bus endpoints every process but the learner dials (default: bus.connect).
    #[arg(long)]
    connect: Vec<String>,
    /// This machine's name where machines share the run folder (deploy/slurm/): without the learner, this
    /// supervisor's record is supervision-<NODE>.json instead of supervision.json.
    #[arg(long)]
    node: Option<String>,
    /// The learner's full log lines on the terminal instead of its progress bar.
    #[arg(long)]
    verbose: bool,
    /// Arguments for the learner (--resume, --fresh, ...), after `--`.
    #[arg(last = true)]
    learner_args: Vec<String>,
}

/// A secured run's supervised router configuration (zenohd's, with the run's TLS and access control, as `cabc
/// zenohd-config` writes it), listening where the others dial; None where no router runs here or the bus is plain
/// (and where the endpoints are refused: the supervisor says why).
fn secured_router_config(roster: &Roster, config: &RunConfig) -> Result<Option<String>> {
    if !roster.roles.contains(&Role::Router) || !config.bus.security.enabled() {
        return Ok(None);
    }
    let Ok(endpoints) = cabc_supervise::roster::router_endpoints(config, &roster.connect, true)
    else {
        return Ok(None);
    };
    let keys = cabc_proto::keys::Keys::new(&config.run.name)?;
    let text = cabc_bus::zenohd::config(&config.bus, &keys, &endpoints)
        .context("the supervised router's configuration")?;
    Ok(Some(text))
}

/// The supervisor of `args`'s run, and its configuration: the processes' programs checked to be built.
fn supervisor(args: &Args) -> Result<(Supervisor, RunConfig)> {
    let config = RunConfig::load(&args.config.display().to_string())
        .with_context(|| format!("loading {}", args.config.display()))?;
    let roster = Roster {
        bin: args.bin.clone(),
        config_file: args.config.clone(),
        run_dir: args.run_dir.clone(),
        roles: if args.roles.is_empty() {
            Role::ALL.to_vec()
        } else {
            args.roles.clone()
        },
        actors: args.actors,
        first_actor: args.first_actor,
        connect: args.connect.clone(),
        learner_args: args.learner_args.clone(),
        node: args.node.clone(),
        router_config: None,
    };
    let roster = Roster {
        router_config: secured_router_config(&roster, &config)?,
        ..roster
    };
    for program in roster.specs(&config).iter().map(|s| &s.program) {
        anyhow::ensure!(
            program.is_file(),
            "{} was not built (cargo build --release)",
            program.display()
        );
    }
    // On a terminal the learner draws its progress bar; --verbose or RUST_LOG bring its lines instead.
    let brief =
        std::io::stderr().is_terminal() && !args.verbose && std::env::var_os("RUST_LOG").is_none();
    Ok((Supervisor::new(roster, &config, brief), config))
}

/// Supervises the run; returns the exit status for the command.
pub fn run(args: &Args) -> Result<i32> {
    let (mut supervisor, _) = supervisor(args)?;
    let ended = supervisor.run();
    match &ended {
        Ok(Ended::Learner { code, after }) => {
            let s = after.as_secs();
            eprintln!(
                "[run-local] learner finished (exit {code}) after {} min {} s; summary: {}",
                s / 60,
                s % 60,
                args.run_dir.join(cabc_outputs::RunDir::SUMMARY).display()
            );
        }
        Ok(Ended::Interrupted) => eprintln!("[run-local] stopped"),
        Ok(Ended::Finished) => {}
        Ok(Ended::Stopped(why)) => eprintln!("[run-local] stopped: {why}"),
        Err(e) => eprintln!("[run-local] error: {e}"),
    }
    Ok(cabc_supervise::exit_code(&ended))
}

#[derive(clap::Args)]
pub struct ChaosArgs {
    /// The seed of the schedule: the same seed, the same gaps and the same draws of a target.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Seconds between two faults, drawn uniformly in MIN-MAX.
    #[arg(long, default_value = "10-30")]
    every: String,
    /// The roles whose processes may be struck, comma-separated (default: those run, --roles).
    #[arg(long, value_delimiter = ',')]
    kill: Vec<Role>,
    /// The kinds of fault drawn from, comma-separated: kill (SIGKILL; the supervisor restarts the process), pause
    /// (SIGSTOP for --pause seconds, then SIGCONT: its links go silent, and past zenoh's lease its peers drop them).
    #[arg(long, value_delimiter = ',', default_value = "kill,pause")]
    faults: Vec<FaultKind>,
    /// A pause's seconds, drawn uniformly in MIN-MAX.
    #[arg(long, default_value = "5-30")]
    pause: String,
    /// Seconds the run may take: past them a run that has not ended is stopped and counted as a stall.
    #[arg(long, default_value_t = 3600.0)]
    limit: f64,
    #[command(flatten)]
    run: Args,
}

/// The supervised run under the schedule; prints the report (also in <run>/chaos.json). Returns the exit status.
pub fn chaos(args: &ChaosArgs) -> Result<i32> {
    let seconds = |flag: &str, range: &str| {
        range
            .split_once('-')
            .and_then(|(a, b)| Some((a.parse::<f64>().ok()?, b.parse::<f64>().ok()?)))
            .filter(|(a, b)| *a > 0.0 && a <= b)
            .with_context(|| format!("--{flag} {range}: MIN-MAX seconds, 0 < MIN <= MAX"))
    };
    let (lo, hi) = seconds("every", &args.every)?;
    let pause_s = seconds("pause", &args.pause)?;
    anyhow::ensure!(
        args.limit.is_finite() && args.limit > 0.0,
        "--limit {}: seconds, more than 0",
        args.limit
    );
    let (mut supervisor, config) = supervisor(&args.run)?;
    let run = &args.run;
    let chaos = Chaos {
        seed: args.seed,
        gap_s: (lo, hi),
        roles: if !args.kill.is_empty() {
            args.kill.clone()
        } else if !run.roles.is_empty() {
            run.roles.clone()
        } else {
            Role::ALL.to_vec()
        },
        kinds: args.faults.clone(),
        pause_s,
        run_dir: run.run_dir.clone(),
        epoch_timeout_s: config.bus.epoch_timeout_s,
        limit: std::time::Duration::from_secs_f64(args.limit),
    };
    let report = chaos.run(&mut supervisor).context("running the chaos")?;
    println!("{}", serde_json::to_string_pretty(&report)?);
    Ok(report.exit)
}
