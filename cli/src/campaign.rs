//! `cabc campaign list | status | run | tables`: a campaign's plan (`deploy/campaign/<plan>.toml`) listed, its runs'
//! states, a lane that runs its slices, its tables ([`cabc_campaign`]; `deploy/campaign.sh` wraps it); and `cabc
//! reproduce`, the per-run step a lane runs each slice with ([`cabc_campaign::reproduce`]; `deploy/reproduce.sh`
//! wraps it).

use anyhow::{bail, Context};
use cabc_campaign::lane::{Lane, LaneOptions};
use cabc_campaign::plan::{plan_path, Method, PLAN_DIR};
use cabc_campaign::reproduce::{Reproduce, Seeds};
use cabc_campaign::Plan;
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(clap::Args)]
struct Common {
    /// The plan: a name in deploy/campaign/ (recipe, issue-18) or a TOML file's path.
    #[arg(long, default_value = "recipe")]
    plan: String,
    /// The repository's root: deploy/campaign/, runs/ and docs/reproduction/ are under it.
    #[arg(long, default_value = ".")]
    root: PathBuf,
}

impl Common {
    fn plan(&self) -> anyhow::Result<Plan> {
        Plan::load(&plan_path(&self.root, &self.plan))
    }
}

#[derive(clap::Subcommand)]
enum Command {
    /// The plan's slices, each as the arguments of deploy/reproduce.sh, numbered for `run --only`.
    List(Common),
    /// Each slice's runs: ended (and how), in progress (at which epoch) or not started.
    Status(Common),
    /// One lane of the campaign: takes the next slice no other lane has claimed (runs/campaign-claims/) and runs it
    /// with the runner, on the loopback port 7447 + I, until none is left; an ended run is skipped, an interrupted
    /// one resumed. Fails when a slice failed (after the others ran).
    Run {
        #[command(flatten)]
        common: Common,
        /// This lane, I of N lanes that share the slices (one lane claims nothing).
        #[arg(long, default_value = "0/1")]
        lane: Lane,
        /// Runs these slices alone (their numbers in `list`: `--only 17` or `--only 17,41`), in the plan's order,
        /// unclaimed.
        #[arg(long, value_delimiter = ',', value_name = "N[,N...]")]
        only: Vec<usize>,
        /// The runs' binaries (CABC_BIN for the runner), under the root unless absolute.
        #[arg(long, default_value = ".deps/campaign-bin/current")]
        bin: PathBuf,
        /// The per-run step, called with the bus's settings and a slice's arguments, under the root unless absolute
        /// (default: this program's `cabc reproduce`).
        #[arg(long)]
        runner: Option<PathBuf>,
    },
    /// Redraws every group's table and figures in docs/reproduction/ and every plan's views (also into
    /// docs/REPRODUCTION.md between their markers).
    Tables {
        /// The repository's root.
        #[arg(long, default_value = ".")]
        root: PathBuf,
        /// The drawing command, followed by `--out PREFIX FOLDER...` (and `--by-group` for a view).
        #[arg(long, default_value = "target/release/cabc compare")]
        compare: String,
        /// Redraws this view alone (its table, figures and place in docs/REPRODUCTION.md), no group's.
        #[arg(long, value_name = "NAME")]
        view: Option<String>,
    },
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    match &args.command {
        Command::List(common) => print!("{}", cabc_campaign::list(&common.plan()?)),
        Command::Status(common) => print!(
            "{}",
            cabc_campaign::status::status(&common.root, &common.plan()?)
        ),
        Command::Run {
            common,
            lane,
            only,
            bin,
            runner,
        } => {
            let root = absolute(&common.root)?;
            let under = |p: &Path| root.join(p);
            let runner = match runner {
                Some(runner) => vec![under(runner).into_os_string()],
                None => vec![
                    std::env::current_exe()
                        .context("this program's path (the default runner)")?
                        .into_os_string(),
                    "reproduce".into(),
                ],
            };
            let opts = LaneOptions {
                root: root.clone(),
                lane: *lane,
                only: only.clone(),
                bin: under(bin),
                runner,
            };
            let failed = cabc_campaign::lane::run_lane(&common.plan()?, &opts)?;
            if failed > 0 {
                bail!("{failed} slice(s) failed");
            }
        }
        Command::Tables {
            root,
            compare,
            view,
        } => {
            let root = &absolute(root)?;
            let views = cabc_campaign::plans_in(&root.join(PLAN_DIR))
                .with_context(|| format!("the plans in {}", root.join(PLAN_DIR).display()))?
                .into_iter()
                .flat_map(|(_, plan)| plan.views)
                .collect::<Vec<_>>();
            let mut compare: Vec<String> = compare.split_whitespace().map(str::to_string).collect();
            if let Some(program) = compare.first_mut().filter(|p| p.contains('/')) {
                *program = root.join(&*program).display().to_string();
            }
            match view {
                None => cabc_campaign::tables::tables(root, &compare, &views)?,
                Some(name) => {
                    let Some(view) = views.iter().find(|v| &v.name == name) else {
                        bail!(
                            "no view {name:?} in the plans of {} (views: {})",
                            root.join(PLAN_DIR).display(),
                            views
                                .iter()
                                .map(|v| v.name.as_str())
                                .collect::<Vec<_>>()
                                .join(", ")
                        );
                    };
                    cabc_campaign::tables::view(root, &compare, view)?;
                }
            }
        }
    }
    Ok(())
}

/// `cabc reproduce`'s arguments: deploy/reproduce.sh's.
#[derive(clap::Args)]
pub struct ReproduceArgs {
    /// The seeds: N (1 to N) or A-B; seed k runs with run.seed = 41 + k.
    #[arg(long, default_value = "1")]
    seeds: Seeds,
    /// run.max_epochs of every run (default: the preset's).
    #[arg(long)]
    epochs: Option<u32>,
    /// Names the ablation: the runs are <preset>-<tag>-s<k>[-baseline].
    #[arg(long)]
    tag: Option<String>,
    /// The methods, in order, separated by blanks or given again: proposed and/or baseline (default both).
    #[arg(long)]
    methods: Vec<String>,
    /// Changes every run's configuration (KEY=VALUE, the learner's syntax), before the run's seed and name.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    sets: Vec<String>,
    /// Prints what would run; runs, copies and draws nothing.
    #[arg(long)]
    dry_run: bool,
    /// The binaries of the runs (learner, actor, expert-server, cabc; default: $CABC_BIN, else this program's
    /// folder).
    #[arg(long)]
    bin: Option<PathBuf>,
    /// The `cabc` whose `compare` draws each group's figures and table (default: this program, which may be newer
    /// than --bin's: a campaign's pinned binaries run, this checkout's tools draw).
    #[arg(long)]
    compare: Option<PathBuf>,
    /// The repository's root: deploy/run-local.sh, runs/ and docs/reproduction/ are under it.
    #[arg(long, default_value = ".")]
    root: PathBuf,
    /// Presets (default: v-b v-a-cpu v-c-cpu).
    experiments: Vec<String>,
}

pub fn reproduce(args: &ReproduceArgs) -> anyhow::Result<()> {
    let methods = args
        .methods
        .iter()
        .flat_map(|m| m.split_whitespace())
        .map(str::parse::<Method>)
        .collect::<Result<Vec<_>, _>>()
        .map_err(anyhow::Error::msg)?;
    if let Some(set) = args.sets.iter().find(|s| !s.contains('=')) {
        bail!("--set needs KEY=VALUE, not {set:?}");
    }
    let call = Reproduce {
        experiments: args.experiments.clone(),
        seeds: args.seeds,
        epochs: args.epochs,
        tag: args.tag.clone(),
        methods,
        sets: args.sets.clone(),
        dry_run: args.dry_run,
    };
    let root = absolute(&args.root)?;
    let this = std::env::current_exe().context("this program's path")?;
    let bin = match (&args.bin, std::env::var_os("CABC_BIN")) {
        (Some(bin), _) => root.join(bin),
        (None, Some(bin)) if !bin.is_empty() => root.join(bin),
        _ => this
            .parent()
            .context("this program's folder")?
            .to_path_buf(),
    };
    let compare = args.compare.as_ref().map_or(this, |cabc| root.join(cabc));
    call.run(&root, &bin, &compare)
}

/// The root as an absolute path (the runner and the drawing command run there, with paths under it).
fn absolute(root: &Path) -> anyhow::Result<PathBuf> {
    std::fs::canonicalize(root).with_context(|| format!("the root {}", root.display()))
}
