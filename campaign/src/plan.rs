//! A campaign's plan: a TOML file of slices of `deploy/reproduce.sh`, in order of priority.
//!
//! ```toml
//! # Named lists of `--set KEY=VALUE` (the learner's syntax: the value is TOML, a bare word a string).
//! [keys]
//! warmup = ["algorithm.lambda_start=1", "algorithm.lambda_growth=1.007"]
//! dminus = ['algorithm.critic_negatives="d-minus"']
//!
//! # A block: its slices for each seed in turn (seed-major: every slice at the first seed, then at the second, ...).
//! [[block]]
//! seeds = [2, 3, 1]       # k: run.seed = 41 + k, run folders <group>-s<k>[-baseline]
//! epochs = 200            # run.max_epochs of the block's slices (default: the preset's)
//! slices = [
//!   { preset = "v-b-ref", methods = ["proposed"], tag = "warmup-dminus", keys = ["warmup", "dminus"] },
//!   { preset = "v-b", tag = "rerun" },   # both methods (the default), the preset's keys
//! ]
//!
//! # A view over groups (`cabc compare --by-group`), redrawn by `cabc campaign tables`.
//! [[view]]
//! name = "v-b-recipe-view"
//! groups = ["v-b-ref", "v-b-ref-warmup"]
//! # More comparisons than each group against its own baseline (`cabc compare --versus A=B`): a label is a group's
//! # name, its baseline runs `<group> (baseline)`.
//! versus = [["v-b-ref-warmup", "v-b-ref (baseline)"]]
//! ```
//!
//! A slice's fields: `preset`, and optionally `tag` (the group is `<preset>-<tag>`), `methods` (`proposed`,
//! `baseline`; default both), `epochs` (overrides the block's), `keys` (names from `[keys]`, their settings in that
//! order) and `set` (settings of its own, after the keys'). A slice runs one seed; its text ([`Slice::text`]) is the
//! argument list of `deploy/reproduce.sh` exactly as the bash campaign wrote it (`--seeds k-k [--epochs E]
//! [--methods M] [--tag T] [--set KEY=VALUE ...] PRESET`), which also names its claim ([`crate::claims`]).

use anyhow::{bail, Context, Result};
use cabc_proto::run_name::RunName;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};

/// Where `--plan NAME` is looked for: `deploy/campaign/NAME.toml` under the repository's root.
pub const PLAN_DIR: &str = "deploy/campaign";

/// The plan's file for `--plan`: a path when it names a file (has a '/' or ends with `.toml`), else
/// `<root>/deploy/campaign/<plan>.toml`.
pub fn plan_path(root: &Path, plan: &str) -> PathBuf {
    if plan.contains('/') || plan.ends_with(".toml") {
        PathBuf::from(plan)
    } else {
        root.join(PLAN_DIR).join(format!("{plan}.toml"))
    }
}

/// A method of reproduce.sh's `--methods`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    Proposed,
    Baseline,
}

impl Method {
    fn as_str(self) -> &'static str {
        match self {
            Method::Proposed => "proposed",
            Method::Baseline => "baseline",
        }
    }
}

impl std::str::FromStr for Method {
    type Err = String;

    /// `proposed` or `baseline`.
    fn from_str(s: &str) -> Result<Self, String> {
        [Method::Proposed, Method::Baseline]
            .into_iter()
            .find(|m| m.as_str() == s)
            .ok_or_else(|| format!("--methods: proposed and/or baseline, not {s}"))
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PlanFile {
    #[serde(default)]
    keys: BTreeMap<String, Vec<String>>,
    #[serde(default, rename = "block")]
    blocks: Vec<BlockFile>,
    #[serde(default, rename = "view")]
    views: Vec<View>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct BlockFile {
    seeds: Vec<u32>,
    epochs: Option<u32>,
    slices: Vec<SliceFile>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SliceFile {
    preset: String,
    tag: Option<String>,
    methods: Option<Vec<Method>>,
    epochs: Option<u32>,
    #[serde(default)]
    keys: Vec<String>,
    #[serde(default)]
    set: Vec<String>,
}

/// A view over groups: `cabc compare --by-group` of their runs into `docs/reproduction/<name>-table.md` (and
/// into docs/REPRODUCTION.md between its markers).
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct View {
    pub name: String,
    pub groups: Vec<String>,
    /// Pairs (A, B) of group labels: P(A reaches its first 50-lap version before B) under the view's tables.
    #[serde(default)]
    pub versus: Vec<[String; 2]>,
}

impl View {
    /// `cabc compare`'s arguments for the pairs: `--versus A=B` each.
    pub fn versus_args(&self) -> Vec<String> {
        self.versus
            .iter()
            .flat_map(|[a, b]| ["--versus".to_string(), format!("{a}={b}")])
            .collect()
    }
}

/// A plan: its slices in order, and its views.
#[derive(Debug, Clone)]
pub struct Plan {
    pub slices: Vec<Slice>,
    pub views: Vec<View>,
}

/// One slice: `deploy/reproduce.sh` over one seed of one group, with one or both methods.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Slice {
    pub preset: String,
    pub tag: Option<String>,
    /// k of the seed (run.seed = 41 + k).
    pub k: u32,
    pub epochs: Option<u32>,
    /// None: reproduce.sh's default, both.
    pub methods: Option<Vec<Method>>,
    /// `--set KEY=VALUE`, each as written in the plan (shell quoting included).
    pub sets: Vec<String>,
}

impl Plan {
    /// Reads and checks a plan file.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("reading the plan {}", path.display()))?;
        Self::parse(&text).with_context(|| format!("the plan {}", path.display()))
    }

    /// Parses and checks a plan's TOML.
    pub fn parse(text: &str) -> Result<Self> {
        let file: PlanFile = toml::from_str(text)?;
        let mut slices = vec![];
        for (b, block) in file.blocks.iter().enumerate() {
            let at = |s: usize| format!("block {} (from 1), slice {}", b + 1, s + 1);
            if block.seeds.is_empty() {
                bail!("block {}: no seeds", b + 1);
            }
            for &k in &block.seeds {
                for (s, spec) in block.slices.iter().enumerate() {
                    let mut sets = vec![];
                    for key in &spec.keys {
                        let of = file
                            .keys
                            .get(key)
                            .with_context(|| format!("{}: no key {key:?} in [keys]", at(s)))?;
                        sets.extend(of.iter().cloned());
                    }
                    sets.extend(spec.set.iter().cloned());
                    let slice = Slice {
                        preset: spec.preset.clone(),
                        tag: spec.tag.clone(),
                        k,
                        epochs: spec.epochs.or(block.epochs),
                        methods: spec.methods.clone(),
                        sets,
                    };
                    slice.check().with_context(|| at(s))?;
                    slices.push(slice);
                }
            }
        }
        for view in &file.views {
            if view.groups.is_empty() {
                bail!("view {}: no groups", view.name);
            }
            for label in view.versus.iter().flatten() {
                let (group, _) = cabc_proto::run_name::label_group(label);
                if !view.groups.iter().any(|g| g == group) {
                    bail!(
                        "view {}: versus names {label:?}, whose group {group:?} is not among its groups",
                        view.name
                    );
                }
            }
        }
        Ok(Self {
            slices,
            views: file.views,
        })
    }
}

impl Slice {
    fn check(&self) -> Result<()> {
        if self.k == 0 {
            bail!("seeds count from 1 (run.seed = 41 + k)");
        }
        if self.epochs == Some(0) {
            bail!("epochs: a positive number");
        }
        if let Some(tag) = &self.tag {
            if tag.is_empty()
                || !tag
                    .bytes()
                    .all(|b| b.is_ascii_alphanumeric() || b"-_.".contains(&b))
            {
                bail!("tag {tag:?}: letters, digits, '-', '_' or '.'");
            }
        }
        if let Some(methods) = &self.methods {
            if methods.is_empty() {
                bail!("methods: proposed and/or baseline");
            }
        }
        // The preset and tag make the run names.
        RunName::new(self.experiment(), self.k, false)?;
        for set in &self.sets {
            match shell_words(set)?.as_slice() {
                [word] if word.contains('=') => {}
                _ => bail!("set {set:?}: one KEY=VALUE"),
            }
        }
        let args = shell_words(&self.text())?;
        if args.last() != Some(&self.preset) {
            bail!(
                "preset {:?}: one word, letters, digits, '-', '_' or '.'",
                self.preset
            );
        }
        Ok(())
    }

    /// The group of its runs: `<preset>[-<tag>]`.
    pub fn experiment(&self) -> String {
        RunName::experiment_of(&self.preset, self.tag.as_deref())
    }

    /// Its runs, in reproduce.sh's order (the methods' order; proposed, then baseline, by default).
    pub fn runs(&self) -> Vec<RunName> {
        let methods = self
            .methods
            .clone()
            .unwrap_or(vec![Method::Proposed, Method::Baseline]);
        methods
            .into_iter()
            .map(|m| {
                RunName::new(self.experiment(), self.k, m == Method::Baseline)
                    .expect("checked when loaded")
            })
            .collect()
    }

    /// The arguments of `deploy/reproduce.sh` that the text stands for, as bash's word splitting and quote removal
    /// make them (`--set training.clip_scope="policy"` passes `training.clip_scope=policy`).
    pub fn args(&self) -> Vec<String> {
        shell_words(&self.text()).expect("checked when loaded")
    }

    /// The slice's text: reproduce.sh's arguments as the bash campaign listed them (and named their claims by).
    pub fn text(&self) -> String {
        self.to_string()
    }
}

impl fmt::Display for Slice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "--seeds {k}-{k}", k = self.k)?;
        if let Some(e) = self.epochs {
            write!(f, " --epochs {e}")?;
        }
        if let Some(methods) = &self.methods {
            let m: Vec<&str> = methods.iter().map(|m| m.as_str()).collect();
            match m.as_slice() {
                [one] => write!(f, " --methods {one}")?,
                _ => write!(f, " --methods \"{}\"", m.join(" "))?,
            }
        }
        if let Some(tag) = &self.tag {
            write!(f, " --tag {tag}")?;
        }
        for set in &self.sets {
            write!(f, " --set {set}")?;
        }
        write!(f, " {}", self.preset)
    }
}

/// Splits `text` into words as bash does for the words of a command (the campaign eval'ed its slices): at blanks
/// outside quotes, with '…' and "…" removed. What bash would expand or treat specially is refused rather than
/// emulated: `$`, backquotes, backslashes, `;&|<>(){}*?!~`, and `#` at a word's start; `[…]` is kept as written, as
/// bash keeps a pattern that matches no file (`collection.action_noise_std=[0.3,0.05]`).
pub fn shell_words(text: &str) -> Result<Vec<String>> {
    let mut words = vec![];
    let mut word: Option<String> = None;
    let mut chars = text.chars();
    while let Some(c) = chars.next() {
        match c {
            ' ' | '\t' | '\n' => {
                if let Some(w) = word.take() {
                    words.push(w);
                }
            }
            '\'' | '"' => {
                let w = word.get_or_insert_with(String::new);
                loop {
                    match chars.next() {
                        Some(q) if q == c => break,
                        Some('$' | '`' | '\\') if c == '"' => {
                            bail!("{text:?}: no $, ` or \\ inside \"…\"")
                        }
                        Some(other) => w.push(other),
                        None => bail!("{text:?}: an unterminated {c}"),
                    }
                }
            }
            '$' | '`' | '\\' | ';' | '&' | '|' | '<' | '>' | '(' | ')' | '{' | '}' | '*' | '?'
            | '!' | '~' => {
                bail!("{text:?}: {c:?} outside quotes (the shell would treat it specially)")
            }
            '#' if word.is_none() => bail!("{text:?}: a word starting with #"),
            _ => word.get_or_insert_with(String::new).push(c),
        }
    }
    words.extend(word);
    Ok(words)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn words_as_bash_splits_them() {
        let w = |t: &str| shell_words(t).unwrap();
        assert_eq!(
            w("--set training.clip_scope=\"policy\" v-b"),
            ["--set", "training.clip_scope=policy", "v-b"]
        );
        assert_eq!(w("a  'b c'\"d\" [0.3,0.05]"), ["a", "b cd", "[0.3,0.05]"]);
        assert_eq!(w("x=''"), ["x="]);
        for bad in [
            "$HOME", "a;b", "\"a", "'a", "a`b`", "#c", "a{1,2}", "\"$x\"", "a\\ b",
        ] {
            assert!(shell_words(bad).is_err(), "{bad}");
        }
    }

    const PLAN: &str = r#"
[keys]
clip = ['training.clip_scope="policy"']
two = ["a.b=1", "c.d=[0.3,0.05]"]

[[block]]
seeds = [2, 1]
epochs = 200
slices = [
  { preset = "v-b-ref", methods = ["proposed"], tag = "abl-clip", keys = ["clip", "two"] },
  { preset = "v-b", tag = "rerun", epochs = 80, set = ["x.y=0"] },
]

[[block]]
seeds = [3]
slices = [{ preset = "v-c-ref", methods = ["baseline"] }, { preset = "v-a", methods = ["baseline", "proposed"] }]

[[view]]
name = "v"
groups = ["v-b-ref", "v-b-rerun"]
versus = [["v-b-ref", "v-b-rerun (baseline)"]]
"#;

    #[test]
    fn a_plan_expands_seed_major() {
        let plan = Plan::parse(PLAN).unwrap();
        let text: Vec<String> = plan.slices.iter().map(Slice::text).collect();
        assert_eq!(
            text,
            [
                "--seeds 2-2 --epochs 200 --methods proposed --tag abl-clip --set training.clip_scope=\"policy\" \
                 --set a.b=1 --set c.d=[0.3,0.05] v-b-ref",
                "--seeds 2-2 --epochs 80 --tag rerun --set x.y=0 v-b",
                "--seeds 1-1 --epochs 200 --methods proposed --tag abl-clip --set training.clip_scope=\"policy\" \
                 --set a.b=1 --set c.d=[0.3,0.05] v-b-ref",
                "--seeds 1-1 --epochs 80 --tag rerun --set x.y=0 v-b",
                "--seeds 3-3 --methods baseline v-c-ref",
                "--seeds 3-3 --methods \"baseline proposed\" v-a",
            ]
        );
        let names = |i: usize| {
            plan.slices[i]
                .runs()
                .iter()
                .map(|r| r.to_string())
                .collect::<Vec<_>>()
        };
        assert_eq!(names(0), ["v-b-ref-abl-clip-s2"]);
        assert_eq!(names(1), ["v-b-rerun-s2", "v-b-rerun-s2-baseline"]);
        assert_eq!(names(4), ["v-c-ref-s3-baseline"]);
        assert_eq!(names(5), ["v-a-s3-baseline", "v-a-s3"]);
        assert_eq!(
            plan.slices[5].args()[2..4],
            ["--methods", "baseline proposed"]
        );
        assert_eq!(plan.slices[0].args()[9], "training.clip_scope=policy");
        assert_eq!(
            plan.views,
            [View {
                name: "v".into(),
                groups: vec!["v-b-ref".into(), "v-b-rerun".into()],
                versus: vec![["v-b-ref".into(), "v-b-rerun (baseline)".into()]],
            }]
        );
        assert_eq!(
            plan.views[0].versus_args(),
            ["--versus", "v-b-ref=v-b-rerun (baseline)"]
        );
        let stray = PLAN.replace("v-b-rerun (baseline)", "v-b-other (baseline)");
        let err = format!("{:#}", Plan::parse(&stray).unwrap_err());
        assert!(
            err.contains("whose group \"v-b-other\" is not among its groups"),
            "{err}"
        );
    }

    #[test]
    fn a_bad_plan_is_refused_with_where() {
        let bad = |from: &str, to: &str| {
            let err = Plan::parse(&PLAN.replace(from, to)).unwrap_err();
            format!("{err:#}")
        };
        assert!(
            bad("keys = [\"clip\", \"two\"]", "keys = [\"clip\", \"three\"]")
                .contains("block 1 (from 1), slice 1: no key \"three\"")
        );
        assert!(bad("seeds = [3]", "seeds = [0]").contains("count from 1"));
        assert!(bad("tag = \"rerun\"", "tag = \"re run\"").contains("tag"));
        assert!(bad("x.y=0", "x.y=$HOME").contains("outside quotes"));
        assert!(bad("x.y=0", "x.y 0").contains("one KEY=VALUE"));
        assert!(bad("preset = \"v-c-ref\"", "preset = \"v c\"").contains("v c"));
        assert!(bad("epochs = 80", "epoch = 80").contains("unknown field"));
        assert!(bad("methods = [\"baseline\"]", "methods = [\"both\"]").contains("unknown variant"));
    }
}
