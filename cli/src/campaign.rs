//! `cabc campaign list | status | run | tables`: a campaign's plan (`deploy/campaign/<plan>.toml`) listed, its runs'
//! states, a lane that runs its slices, its tables ([`cabc_campaign`]; `deploy/campaign.sh` wraps it).

use anyhow::{bail, Context};
use cabc_campaign::lane::{Lane, LaneOptions};
use cabc_campaign::plan::{plan_path, PLAN_DIR};
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
        /// Runs slice N alone (its number in `list`), unclaimed.
        #[arg(long)]
        only: Option<usize>,
        /// The runs' binaries (CABC_BIN for the runner), under the root unless absolute.
        #[arg(long, default_value = ".deps/campaign-bin/current")]
        bin: PathBuf,
        /// The per-run step, called with the bus's settings and a slice's arguments, under the root unless absolute.
        #[arg(long, default_value = "deploy/reproduce.sh")]
        runner: PathBuf,
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
            let opts = LaneOptions {
                root: root.clone(),
                lane: *lane,
                only: *only,
                bin: under(bin),
                runner: under(runner),
            };
            let failed = cabc_campaign::lane::run_lane(&common.plan()?, &opts)?;
            if failed > 0 {
                bail!("{failed} slice(s) failed");
            }
        }
        Command::Tables { root, compare } => {
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
            cabc_campaign::tables::tables(root, &compare, &views)?;
        }
    }
    Ok(())
}

/// The root as an absolute path (the runner and the drawing command run there, with paths under it).
fn absolute(root: &Path) -> anyhow::Result<PathBuf> {
    std::fs::canonicalize(root).with_context(|| format!("the root {}", root.display()))
}
