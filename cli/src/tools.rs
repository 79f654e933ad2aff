//! The subcommands that hand their arguments to a library whole: `cabc compare` (cabc-analysis), `cabc plots`
//! (cabc-outputs), `cabc demo`, `cabc bench`, `cabc bench-vision` and `cabc bench-bus` (cabc-bench), and a secure deployment's
//! `cabc zenohd-config` and `cabc acl-denials` (cabc-bus, deploy/SCALE-OUT.md §2).

use anyhow::Context;
use cabc_proto::config::RunConfig;
use std::path::PathBuf;

/// `cabc compare RUN...`: the paper's figures and the table of runs (Markdown on stdout).
pub fn compare(options: &cabc_analysis::compare::CompareOptions) -> anyhow::Result<()> {
    print!("{}", cabc_analysis::compare::run(options)?);
    Ok(())
}

#[derive(clap::Args)]
pub struct PlotsArgs {
    /// The run folder.
    run: PathBuf,
    /// Where to write the PNG files (default: RUN/plots/).
    #[arg(long)]
    out: Option<PathBuf>,
}

/// `cabc plots RUN [--out DIR]`: the run's plots redrawn from its small files; the files written on stdout, what was
/// missing and what is left out on stderr.
pub fn plots(args: &PlotsArgs) -> anyhow::Result<()> {
    let run = &args.run;
    let redrawn = cabc_outputs::redraw::redraw(run, args.out.as_deref())
        .with_context(|| format!("redrawing the plots of {}", run.display()))?;
    for note in &redrawn.notes {
        eprintln!("note: {note}");
    }
    for left_out in redrawn.left_out {
        eprintln!("left out: {left_out}");
    }
    for path in &redrawn.drawn {
        println!("{}", path.display());
    }
    Ok(())
}

#[derive(clap::Args)]
pub struct DemoArgs {
    #[command(flatten)]
    options: cabc_bench::demo::DemoOptions,
    /// Print the report as JSON on stdout.
    #[arg(long)]
    json: bool,
}

/// `cabc demo`: the paper's Fig. 3.
pub fn demo(args: &DemoArgs) -> anyhow::Result<()> {
    let o = &args.options;
    let report =
        cabc_bench::demo::autolabel_demo(&o.rho, o.seed, &o.out).context("auto-labelling demo")?;
    report.log();
    if args.json {
        crate::print_json(&report)?;
    }
    Ok(())
}

#[derive(clap::Args)]
pub struct BenchArgs {
    #[command(flatten)]
    options: cabc_bench::throughput::BenchOptions,
    /// Print the report as JSON on stdout.
    #[arg(long)]
    json: bool,
}

/// `cabc bench`: auto-labelling's and training's throughput.
pub fn bench(args: &BenchArgs) -> anyhow::Result<()> {
    let report = cabc_bench::throughput::run_bench(&args.options);
    if args.json {
        crate::print_json(&report)?;
    }
    Ok(())
}

/// `cabc bench-vision`: the camera policy's images per second (JSON).
pub fn bench_vision(options: &cabc_bench::vision::VisionBenchOptions) -> anyhow::Result<()> {
    let report = cabc_bench::vision::run(options).context("bench-vision")?;
    crate::print_json(&report)
}

#[derive(clap::Args)]
pub struct BenchEpochArgs {
    /// Run configuration: a preset or a TOML file.
    #[arg(long, short, default_value = cabc_proto::config::DEFAULT_PRESET)]
    config: String,
    /// A configuration value, `key=value`; repeatable.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    #[command(flatten)]
    options: cabc_bench::epoch::EpochBenchOptions,
}

/// `cabc bench-epoch`: an epoch of a configuration, timed per phase against its floor (JSON).
pub fn bench_epoch(args: &BenchEpochArgs) -> anyhow::Result<()> {
    let config = load(&args.config)?
        .with_overrides(&args.set)
        .context("applying --set")?;
    let report = cabc_bench::epoch::run(&config, &args.options).context("bench-epoch")?;
    crate::print_json(&report)
}

/// `cabc bench-bus`: one learner's intake under N synthetic actors; the table on stdout, every figure in `--json`;
/// fails when a segment was lost.
pub fn bench_bus(options: &cabc_bench::capacity::BusBenchOptions) -> anyhow::Result<()> {
    let exe =
        std::env::current_exe().context("this executable's path (the actors run as its child)")?;
    let report = cabc_bench::capacity::run(options, &exe).context("bench-bus")?;
    print!("{}", report.table());
    if let Some(path) = &options.json {
        std::fs::write(path, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    match report.lost() {
        0 => Ok(()),
        lost => anyhow::bail!(
            "{lost} segments (or their steps) published and not stored: see the books in the JSON"
        ),
    }
}

/// `cabc bench-bus-actors`: the synthetic actors of `cabc bench-bus` (its child process); their report on stdout.
pub fn bench_bus_actors(args: &cabc_bench::capacity::actors::ActorsArgs) -> anyhow::Result<()> {
    let report = cabc_bench::capacity::actors::serve(args).context("bench-bus's actors")?;
    println!("{}", serde_json::to_string(&report)?);
    Ok(())
}

#[derive(clap::Args)]
pub struct ZenohdConfigArgs {
    /// Run configuration: a preset or a TOML file.
    #[arg(long, short, default_value = cabc_proto::config::DEFAULT_PRESET)]
    config: String,
    /// Endpoints zenohd listens on (default: the protocol and port of every bus.connect endpoint, on every
    /// address); repeatable.
    #[arg(long)]
    listen: Vec<String>,
    /// A configuration value, `key=value`; repeatable.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
}

/// `cabc zenohd-config`: zenohd's JSON5 configuration for a run.
pub fn zenohd_config(args: &ZenohdConfigArgs) -> anyhow::Result<()> {
    let config = crate::load(&args.config)?
        .with_overrides(&args.set)
        .context("applying --set")?;
    let listen = match args.listen.is_empty() {
        true => cabc_bus::zenohd::default_listen(&config.bus.connect),
        false => args.listen.clone(),
    };
    let keys = cabc_proto::keys::Keys::new(&config.run.name)?;
    print!("{}", cabc_bus::zenohd::config(&config.bus, &keys, &listen)?);
    Ok(())
}

#[derive(clap::Args)]
pub struct AclDenialsArgs {
    /// zenohd's log file.
    log: PathBuf,
}

/// `cabc acl-denials LOG`: the messages zenohd's access control dropped, as JSON.
pub fn acl_denials(args: &AclDenialsArgs) -> anyhow::Result<()> {
    let text = std::fs::read_to_string(&args.log)
        .with_context(|| format!("reading {}", args.log.display()))?;
    crate::print_json(&cabc_proto::telemetry::acl_denials_in_log(&text))
}

#[derive(clap::Args)]
pub struct AuditArgs {
    /// The run folder (its journal/ and its checkpoint).
    run: PathBuf,
    /// The audit as JSON on stdout instead of the report.
    #[arg(long)]
    json: bool,
}

/// `cabc audit RUN`: every segment the actors journalled, accounted for against the learner's final ledger. Exits 1
/// when a segment is lost or the ledger and the journals disagree.
pub fn audit(args: &AuditArgs) -> anyhow::Result<i32> {
    let audit = cabc_runfolder::audit::Audit::of(&args.run)
        .with_context(|| format!("auditing {}", args.run.display()))?;
    if args.json {
        crate::print_json(&audit)?;
    } else {
        print!("{audit}");
    }
    Ok(if audit.ok() { 0 } else { 1 })
}

/// The configuration `name` (a preset or a TOML file) resolved.
pub fn load(name: &str) -> anyhow::Result<RunConfig> {
    RunConfig::load_variant(name, false).with_context(|| format!("loading configuration {name}"))
}
