//! `cabc campaign tables`: every group's figures and table in docs/reproduction/ redrawn (the groups with a
//! `<group>-table.md`, less the views), and the views over groups of the plans (`[[view]]`), each also into
//! docs/REPRODUCTION.md between its markers (`<!-- NAME-table ...` and `<!-- end NAME-table -->`) where it has them.
//! The drawing is `cabc compare` (`--by-group` for a view) of the groups' run folders, with their paths relative
//! to the root, as the bash campaign passed them. `cabc campaign tables --view NAME` redraws one view alone.

use crate::plan::View;
use crate::status::RESULTS_DIR;
use anyhow::{bail, Context, Result};
use cabc_proto::run_name::RunName;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// The document whose markers receive the views' tables.
pub const REPORT: &str = "docs/REPRODUCTION.md";

/// The run folders of a group in docs/reproduction/ (`<group>-s<k>`, `<group>-s<k>-baseline` with a metrics.csv),
/// relative to the root, in byte order of their names (the shell's glob in the C locale).
pub fn group_folders(root: &Path, group: &str) -> Result<Vec<PathBuf>> {
    let out = root.join(RESULTS_DIR);
    let mut names: Vec<String> = std::fs::read_dir(&out)
        .with_context(|| format!("reading {}", out.display()))?
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| n.parse::<RunName>().is_ok_and(|r| r.group() == group))
        .filter(|n| out.join(n).join(cabc_runfolder::METRICS).is_file())
        .collect();
    names.sort();
    Ok(names
        .into_iter()
        .map(|n| Path::new(RESULTS_DIR).join(n))
        .collect())
}

/// The groups with a table in docs/reproduction/ (`<group>-table.md`), the views' (`-ablation`, `-protocols`,
/// `-view`) left out, in byte order.
pub fn tabled_groups(root: &Path) -> Result<Vec<String>> {
    let mut groups: Vec<String> = std::fs::read_dir(root.join(RESULTS_DIR))?
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter_map(|n| n.strip_suffix("-table.md").map(str::to_string))
        .filter(|g| {
            !["-ablation", "-protocols", "-view"]
                .iter()
                .any(|s| g.ends_with(s))
        })
        .collect();
    groups.sort();
    Ok(groups)
}

/// Whether `folders` hold runs of a group label as `cabc compare --by-group` names it ([`RunName::label`]).
fn has_runs(folders: &[PathBuf], label: &str) -> bool {
    folders.iter().any(|f| {
        f.file_name()
            .and_then(|n| n.to_str())
            .and_then(|n| n.parse::<RunName>().ok())
            .is_some_and(|r| r.label() == label)
    })
}

/// Runs `compare` (a program and its first arguments) with `args` in `root`; its stdout, which becomes the table.
fn draw(root: &Path, compare: &[String], args: &[String], folders: &[PathBuf]) -> Result<String> {
    let (program, first) = compare.split_first().context("no compare command")?;
    let out = Command::new(program)
        .args(first)
        .args(args)
        .args(folders)
        .current_dir(root)
        .stderr(Stdio::inherit())
        .output()
        .with_context(|| format!("starting {program}"))?;
    if !out.status.success() {
        bail!(
            "{} {} failed: {}",
            compare.join(" "),
            args.join(" "),
            out.status
        );
    }
    Ok(String::from_utf8(out.stdout)?)
}

/// Puts a table's rows (its lines starting with '|') and its comparisons (`* P(...`, [`crate::plan::View`]'s pairs
/// and each group against its baseline) after the line starting with `<!-- NAME-table` in `doc`, in place of what
/// was there up to the line starting with `<!-- end NAME-table -->`; `doc` unchanged without markers. Where the
/// table file holds several tables (a view's per-seed table, then its statistics over seeds), a blank line keeps
/// them apart: Markdown would read the second one's rows as the first one's.
pub fn splice(doc: &str, name: &str, table: &str) -> String {
    let (start, end) = (
        format!("<!-- {name}-table"),
        format!("<!-- end {name}-table -->"),
    );
    let mut out = String::new();
    let mut skip = false;
    for line in doc.lines() {
        if line.starts_with(&end) {
            skip = false;
        }
        if !skip {
            out.push_str(line);
            out.push('\n');
        }
        if line.starts_with(&start) {
            let (mut seen, mut gap) = (false, false);
            for row in table.lines() {
                if !row.starts_with('|') && !row.starts_with("* P(") {
                    gap = seen;
                    continue;
                }
                if gap {
                    out.push('\n');
                    gap = false;
                }
                out.push_str(row);
                out.push('\n');
                seen = true;
            }
            skip = true;
        }
    }
    out
}

/// Redraws every group's table and figures, then the views'.
pub fn tables(root: &Path, compare: &[String], views: &[View]) -> Result<()> {
    let out = Path::new(RESULTS_DIR);
    for group in tabled_groups(root)? {
        let folders = group_folders(root, &group)?;
        if folders.is_empty() {
            continue;
        }
        eprintln!("[campaign] {group}: {} runs", folders.len());
        let prefix = out.join(&group).display().to_string();
        let table = draw(root, compare, &["--out".into(), prefix], &folders)?;
        std::fs::write(root.join(out).join(format!("{group}-table.md")), table)?;
    }
    for view in views {
        self::view(root, compare, view)?;
    }
    Ok(())
}

/// Redraws one view: its table and figures in docs/reproduction/, and its place in docs/REPRODUCTION.md.
pub fn view(root: &Path, compare: &[String], view: &View) -> Result<()> {
    let out = Path::new(RESULTS_DIR);
    let mut folders = vec![];
    for group in &view.groups {
        folders.extend(group_folders(root, group)?);
    }
    if folders.is_empty() {
        return Ok(());
    }
    eprintln!("[campaign] view {}: {} runs", view.name, folders.len());
    let prefix = out.join(&view.name).display().to_string();
    let mut args = vec!["--by-group".into(), "--out".into(), prefix];
    // A pair whose runs have not ended yet (a group of a campaign still running) waits for them.
    let mut view = view.clone();
    view.versus
        .retain(|pair| pair.iter().all(|label| has_runs(&folders, label)));
    args.extend(view.versus_args());
    let table = draw(root, compare, &args, &folders)?;
    std::fs::write(
        root.join(out).join(format!("{}-table.md", view.name)),
        &table,
    )?;
    let report = root.join(REPORT);
    if let Ok(doc) = std::fs::read_to_string(&report) {
        std::fs::write(&report, splice(&doc, &view.name, &table))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pair_waits_for_the_runs_of_both_its_labels() {
        let folders: Vec<PathBuf> = [
            "v-c-ref-ten-s1",
            "v-c-ref-ten-s1-baseline",
            "v-c-ref-bc-ten-s2-baseline",
        ]
        .iter()
        .map(|n| Path::new(RESULTS_DIR).join(n))
        .collect();
        assert!(has_runs(&folders, "v-c-ref-ten"));
        assert!(has_runs(&folders, "v-c-ref-ten (baseline)"));
        assert!(has_runs(&folders, "v-c-ref-bc-ten (baseline)"));
        assert!(!has_runs(&folders, "v-c-ref-bc-ten"));
        assert!(!has_runs(&folders, "v-c-ref-variant-ten"));
    }

    #[test]
    fn a_table_goes_between_its_markers() {
        let doc = "a\n<!-- v-table: refreshed -->\n| old |\n|---|\n<!-- end v-table -->\nb\n<!-- w-table -->\n| w |\n";
        let table = "Intro.\n\n| new |\n|---|\n| 1 |\n\nAfter.\n";
        assert_eq!(
            splice(doc, "v", table),
            "a\n<!-- v-table: refreshed -->\n| new |\n|---|\n| 1 |\n<!-- end v-table -->\nb\n<!-- w-table -->\n| w |\n"
        );
        assert_eq!(splice(doc, "x", table), doc);
        // A view's two tables stay two tables.
        let two =
            "Per seed.\n\n| a |\n|---|\n| 1 |\n\nOver seeds.\n\n| b | c |\n|---|---|\n| 2 | 3 |\n\n* P(x) 0.5\n* P(y) 0.6\n";
        assert_eq!(
            splice(doc, "v", two),
            "a\n<!-- v-table: refreshed -->\n| a |\n|---|\n| 1 |\n\n| b | c |\n|---|---|\n| 2 | 3 |\n\n* P(x) 0.5\n* P(y) 0.6\n<!-- end v-table -->\nb\n<!-- w-table -->\n| w |\n"
        );
    }

    #[test]
    fn groups_and_their_folders() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join(RESULTS_DIR);
        for run in [
            "g-s1",
            "g-s10",
            "g-s2-baseline",
            "g-s2",
            "g-x-s1",
            "g-s3",
            "g-s1-to-300",
            "h-s1",
        ] {
            std::fs::create_dir_all(out.join(run)).unwrap();
            if run != "g-s3" {
                std::fs::write(out.join(run).join("metrics.csv"), "").unwrap();
            }
        }
        for table in ["g", "h", "g-ablation", "v-b-recipe-view", "x-protocols"] {
            std::fs::write(out.join(format!("{table}-table.md")), "").unwrap();
        }
        let names = |v: Vec<PathBuf>| {
            v.iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
        };
        assert_eq!(
            names(group_folders(tmp.path(), "g").unwrap()),
            [
                "docs/reproduction/g-s1",
                "docs/reproduction/g-s10",
                "docs/reproduction/g-s2",
                "docs/reproduction/g-s2-baseline"
            ]
        );
        assert_eq!(tabled_groups(tmp.path()).unwrap(), ["g", "h"]);
    }
}
