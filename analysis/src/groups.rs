//! `cabc compare --by-group`: the ablation view of many runs. Runs are grouped by their name less the seed's
//! suffix (`<group>-s<k>`, `<group>-s<k>-baseline`), proposed and baseline apart, in the order the groups first
//! appear on the command line; per group and seed one cell says the first 50-lap version (and the early stop), the
//! laps completed over all evaluations and the late evaluations' steps ([`RunRecord::late_steps`]), a second table
//! gives the statistics over seeds ([`crate::intervals`]), and `<out>-groups.png` draws the late steps per group, a
//! dot per seed, filled where the run reached `eval_laps` laps, with the group's IQM and its bootstrap 95 % interval
//! (`<out>-first50.png` the same for the first 50-lap version). Under the tables, each group with both methods
//! against its own baseline, and each pair asked for (`--versus A=B`, e.g. the proposed method against a baseline
//! run as a group of its own), by rliable's probability of improvement of the first 50-lap version.

use crate::runs::{CompareError, RunRecord, LATE_VERSIONS};
use crate::stats::{bootstrap_95, iqm};
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::prelude::*;
use std::path::{Path, PathBuf};

/// The group of a run: its name without `-s<k>` (and `-baseline`, which marks the method instead), by the naming
/// convention's one reader (`cabc_proto::run_name`).
pub fn group_of(name: &str) -> String {
    cabc_proto::run_name::group_of(name).to_string()
}

/// A group's label: the group, "(baseline)" for the baseline runs.
fn label(r: &RunRecord) -> String {
    cabc_proto::run_name::group_label(&group_of(&r.name), r.is_baseline())
}

/// The groups' labels in first-appearance order, each with its runs.
fn grouped(runs: &[RunRecord]) -> Vec<(String, Vec<&RunRecord>)> {
    let mut groups: Vec<(String, Vec<&RunRecord>)> = Vec::new();
    for r in runs {
        let l = label(r);
        match groups.iter_mut().find(|(g, _)| *g == l) {
            Some((_, of)) => of.push(r),
            None => groups.push((l, vec![r])),
        }
    }
    groups
}

/// The seeds of the runs, sorted (None, a folder without config.toml, last).
fn seeds(runs: &[RunRecord]) -> Vec<Option<u64>> {
    let mut seeds: Vec<Option<u64>> = runs.iter().map(|r| r.seed).collect();
    seeds.sort_by_key(|s| s.unwrap_or(u64::MAX));
    seeds.dedup();
    seeds
}

/// One run's cell: "first 50-lap version (stop S) · laps · late steps".
fn cell(r: &RunRecord) -> String {
    let first = match (r.full().next(), r.early_stop) {
        (Some(e), Some(stop)) => format!("**{}** (stop {stop})", e.version),
        (Some(e), None) => format!("**{}**", e.version),
        (None, _) => "none".into(),
    };
    let late = r.late_steps().map_or("-".into(), |s| format!("{s:.0}"));
    format!("{first} · {} · {late}", r.laps_completed())
}

/// The Markdown table: a row per group, a column per seed, then the group's count of runs that reached the laps
/// and the median [range] of its laps and late steps.
///
/// `versus` names more pairs (A, B) of group labels to compare; a label that no group has is an error.
pub fn table(runs: &[RunRecord], versus: &[(String, String)]) -> Result<String, CompareError> {
    let seeds = seeds(runs);
    let seed_name = |s: &Option<u64>| s.map_or("seed ?".into(), |s| format!("seed {s}"));
    let mut out = format!(
        "Each seed's cell: the version of the first 50-lap evaluation (bold; the early stop), or none · the laps \
         completed over all evaluations · the median steps of the evaluations of the last {LATE_VERSIONS} versions.\n\n\
         | group | {} | reached the laps | laps, all evals | eval steps, last {LATE_VERSIONS} |\n|---|{}---|---|---|\n",
        seeds.iter().map(seed_name).collect::<Vec<_>>().join(" | "),
        "---|".repeat(seeds.len()),
    );
    for (group, of) in grouped(runs) {
        let cells: Vec<String> = seeds
            .iter()
            .map(|s| {
                of.iter()
                    .filter(|r| r.seed == *s)
                    .map(|r| cell(r))
                    .collect::<Vec<_>>()
                    .join("; ")
            })
            .collect();
        let reached = of.iter().filter(|r| r.full().next().is_some()).count();
        let laps: Vec<f64> = of.iter().map(|r| r.laps_completed() as f64).collect();
        let late: Vec<f64> = of.iter().filter_map(|r| r.late_steps()).collect();
        out.push_str(&format!(
            "| {group} | {} | {reached} of {} | {} | {} |\n",
            cells.join(" | "),
            of.len(),
            crate::stats::median_range(&laps, 0),
            crate::stats::median_range(&late, 0),
        ));
    }
    out.push_str(&format!(
        "\nOver seeds, per group: the share that reached the early stop with its Wilson \
         interval; the interquartile mean of the first 50-lap version (a run that never got there at its budget) \
         and of the late steps, with stratified-bootstrap 95 % intervals ({} resamples).\n\n{}",
        crate::stats::BOOTSTRAP_RESAMPLES,
        crate::intervals::interval_header("group")
    ));
    let groups = grouped(runs);
    for (group, of) in &groups {
        out.push_str(&crate::intervals::interval_row(group, of));
    }
    // Each group with both methods: the proposed method against its own baseline.
    let mut pairs = String::new();
    for (group, proposed) in &groups {
        let baseline = cabc_proto::run_name::group_label(group, true);
        if let Some((_, baselines)) = groups.iter().find(|(g, _)| *g == baseline) {
            pairs.push_str(&format!(
                "* {}",
                crate::intervals::improvement_line(group, proposed, &baseline, baselines)
            ));
        }
    }
    let of = |label: &str, pair: &(String, String)| {
        groups
            .iter()
            .find(|(g, _)| g == label)
            .map(|(_, runs)| runs)
            .ok_or_else(|| CompareError::Versus {
                pair: format!("{}={}", pair.0, pair.1),
                why: format!(
                    "no group {label:?} among {}",
                    groups
                        .iter()
                        .map(|(g, _)| format!("{g:?}"))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            })
    };
    for pair in versus {
        let (a, b) = (of(&pair.0, pair)?, of(&pair.1, pair)?);
        pairs.push_str(&format!(
            "* {}",
            crate::intervals::improvement_line(&pair.0, a, &pair.1, b)
        ));
    }
    if !pairs.is_empty() {
        out.push('\n');
        out.push_str(&pairs);
    }
    Ok(out)
}

/// Distinct colours for the seeds (Tableau 10).
const SEED_COLOURS: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

/// One number per run, drawn per group by [`draw`]: the file's suffix, the caption, the x axis's name, the value
/// (none: the run has no dot) and whether the axis is logarithmic.
struct Figure {
    suffix: &'static str,
    caption: String,
    x_desc: &'static str,
    value: fn(&RunRecord) -> Option<f64>,
    log: bool,
}

/// Draws the two figures of the ablation view and returns their paths:
/// * `<out>-groups.png`: per group (a row), each seed's late evaluation steps (log axis);
/// * `<out>-first50.png`: each seed's first 50-lap version, a run that never got there at its budget
///   ([`crate::intervals::first_full_or_budget`], the statistic the interval table gives).
///
/// In each, a dot per seed (filled where the run reached the laps), the group's interquartile mean (a black bar)
/// and its bootstrap 95 % interval (a line).
pub fn draw(runs: &[RunRecord], out: &Path) -> Result<Vec<PathBuf>, Box<dyn std::error::Error>> {
    let figures = [
        Figure {
            suffix: "groups",
            caption: format!(
                "Late eval steps (median of the last {LATE_VERSIONS} versions): a dot per seed, filled: 50 laps; bar: IQM, line: its 95 % CI"
            ),
            x_desc: "steps",
            value: RunRecord::late_steps,
            log: true,
        },
        Figure {
            suffix: "first50",
            caption: "First 50-lap version (never: the budget): a dot per seed, filled: 50 laps; bar: IQM, line: its 95 % CI".into(),
            x_desc: "policy version",
            value: |r| Some(crate::intervals::first_full_or_budget(r)),
            log: false,
        },
    ];
    figures.iter().map(|f| draw_figure(runs, out, f)).collect()
}

/// Draws one [`Figure`] to `<out>-<suffix>.png`.
fn draw_figure(
    runs: &[RunRecord],
    out: &Path,
    figure: &Figure,
) -> Result<PathBuf, Box<dyn std::error::Error>> {
    let name = out
        .file_name()
        .map(|n| n.to_string_lossy().to_string())
        .unwrap_or_default();
    let path = out.with_file_name(format!("{name}-{}.png", figure.suffix));
    let values: Vec<f64> = runs.iter().filter_map(figure.value).collect();
    let max = values.iter().copied().fold(10.0, f64::max);
    let rows = grouped(runs).len().max(1);
    let height = 140 + 44 * rows as u32;
    cabc_outputs::plots::png(&path, (1000, height), |root| {
        root.fill(&WHITE)?;
        let chart = cabc_outputs::plots::chart(root, &figure.caption, 230);
        // Room on the right for the legend.
        if figure.log {
            let lo = values
                .iter()
                .copied()
                .fold(f64::INFINITY, f64::min)
                .min(10.0)
                / 1.5;
            rows_of_dots(chart, (lo..max * 3.0).log_scale(), runs, figure)
        } else {
            rows_of_dots(chart, 0.0..max * 1.45, runs, figure)
        }
    })?;
    Ok(path)
}

/// The rows of a [`Figure`] on the x axis `x`.
fn rows_of_dots<'a, 'b, X>(
    mut builder: ChartBuilder<'a, 'static, BitMapBackend<'b>>,
    x: X,
    runs: &[RunRecord],
    figure: &Figure,
) -> Result<(), Box<dyn std::error::Error>>
where
    X: AsRangedCoord<Value = f64>,
    X::CoordDescType: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let groups = grouped(runs);
    let seeds = seeds(runs);
    let labels: Vec<String> = groups.iter().map(|(g, _)| g.clone()).collect();
    let rows = groups.len().max(1);
    // The first group on top.
    let row = |i: usize| SegmentValue::CenterOf(rows - 1 - i);
    let mut chart = builder.build_cartesian_2d(x, (0..rows).into_segmented())?;
    chart
        .configure_mesh()
        .x_desc(figure.x_desc)
        .y_labels(rows)
        .y_label_formatter(&|v| match v {
            SegmentValue::CenterOf(i) | SegmentValue::Exact(i) if *i < rows => {
                labels[rows - 1 - i].clone()
            }
            _ => String::new(),
        })
        .x_label_formatter(&|v| format!("{v:.0}"))
        .draw()?;
    // Each seed a few pixels apart, so that equal values stay visible, all within the row's 44 px.
    let step = (36 / seeds.len().max(1) as i32).clamp(1, 5);
    for (k, seed) in seeds.iter().enumerate() {
        let c = SEED_COLOURS[k % SEED_COLOURS.len()];
        let dy = (k as i32 - seeds.len() as i32 / 2) * step;
        let dots = groups.iter().enumerate().flat_map(|(i, (_, of))| {
            of.iter().filter(|r| r.seed == *seed).filter_map(move |r| {
                let style = if r.full().next().is_some() {
                    c.filled()
                } else {
                    c.stroke_width(2)
                };
                Some(
                    EmptyElement::at(((figure.value)(r)?, row(i))) + Circle::new((0, dy), 6, style),
                )
            })
        });
        let seed_label = seed.map_or("seed ?".into(), |s| format!("seed {s}"));
        chart
            .draw_series(dots)?
            .label(seed_label)
            .legend(move |(x, y)| Circle::new((x + 10, y), 5, c.filled()));
    }
    let values =
        |of: &[&RunRecord]| -> Vec<f64> { of.iter().filter_map(|r| (figure.value)(r)).collect() };
    let iqms = groups.iter().enumerate().filter_map(|(i, (_, of))| {
        Some(
            EmptyElement::at((iqm(&values(of))?, row(i)))
                + Rectangle::new([(-1, -16), (1, 16)], BLACK.filled()),
        )
    });
    chart
        .draw_series(iqms)?
        .label("IQM")
        .legend(|(x, y)| Rectangle::new([(x + 9, y - 6), (x + 11, y + 6)], BLACK.filled()));
    let intervals = groups.iter().enumerate().filter_map(|(i, (_, of))| {
        let (lo, hi) = bootstrap_95(&values(of), iqm)?;
        Some(PathElement::new(
            vec![(lo, row(i)), (hi, row(i))],
            BLACK.stroke_width(2),
        ))
    });
    chart
        .draw_series(intervals)?
        .label("IQM's 95 % CI (bootstrap)")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(2)));
    cabc_outputs::plots::legend(&mut chart, SeriesLabelPosition::UpperRight)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runs::Eval;

    fn record(
        name: &str,
        seed: u64,
        evals: &[(u64, u32, u64)],
        early_stop: Option<u64>,
    ) -> RunRecord {
        RunRecord {
            name: name.into(),
            lambda: if name.ends_with("-baseline") {
                0.0
            } else {
                10.0
            },
            seed: Some(seed),
            eval_laps: 50,
            evals: evals
                .iter()
                .map(|&(version, laps, steps)| Eval {
                    version,
                    laps,
                    lap_mean: (laps > 0).then_some(5.0),
                    lap_std: (laps > 0).then_some(0.1),
                    steps: Some(steps),
                })
                .collect(),
            imitation: vec![],
            epochs: 200,
            wall_s: 0.0,
            incomplete_share: None,
            early_stop,
            expert_lap_time: None,
            ended: None,
            peak_mb: None,
            collection: vec![],
        }
    }

    /// A PNG's width and its RGB bytes.
    fn pixels(path: &Path) -> (u32, Vec<u8>) {
        let decoder = png::Decoder::new(std::fs::File::open(path).unwrap());
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!(info.color_type, png::ColorType::Rgb);
        buf.truncate(info.buffer_size());
        (info.width, buf)
    }

    #[test]
    fn groups_are_names_less_their_seed() {
        assert_eq!(group_of("v-b-ref-abl-clip-s3"), "v-b-ref-abl-clip");
        assert_eq!(group_of("v-b-ref-s12-baseline"), "v-b-ref");
        assert_eq!(group_of("v-b-s1-to-300"), "v-b-s1-to-300");
        assert_eq!(group_of("smoke"), "smoke");
        assert_eq!(group_of("v-b-s"), "v-b-s");
    }

    #[test]
    fn a_pair_asked_for_is_compared_and_an_unknown_label_refused() {
        // The proposed group against a baseline run as a group of its own (plain BC beside the caption's baseline).
        let runs = [
            record("ten-s1", 42, &[(40, 50, 2600)], Some(41)),
            record("ten-s2", 43, &[(50, 50, 2600)], Some(51)),
            record("bc-s1-baseline", 42, &[(60, 50, 2600)], Some(61)),
            record("bc-s2-baseline", 43, &[(45, 50, 2600)], Some(46)),
        ];
        let versus = [("ten".to_string(), "bc (baseline)".to_string())];
        let table = table(&runs, &versus).unwrap();
        let pairs: Vec<&str> = table.lines().filter(|l| l.starts_with("* P(")).collect();
        // 40 and 50 against 60 and 45: three pairs of four won.
        assert_eq!(
            pairs,
            ["* P(ten reaches its first 50-lap version before bc (baseline)), rliable's probability of improvement over every pair of runs: 0.75 [0.00, 1.00] (95 % CI); by seed (2 in common): sooner on 1, later on 1, as soon on 0"]
        );
        // A seed run twice on one side pairs with nothing defined: no count, rather than a guessed one.
        let [ten, bc] = [&runs[..2], &runs[2..]].map(|of| of.iter().collect::<Vec<_>>());
        assert_eq!(crate::intervals::by_seed(&ten, &bc), Some((1, 1, 0)));
        assert_eq!(crate::intervals::by_seed(&[ten[0], ten[0]], &bc), None);
        assert_eq!(
            crate::intervals::by_seed(&ten[..1], &bc[1..]),
            None,
            "no seed in common"
        );
        let wrong = [("ten".to_string(), "bc".to_string())];
        let err = super::table(&runs, &wrong).unwrap_err().to_string();
        assert!(
            err.contains("--versus ten=bc: no group \"bc\"") && err.contains("\"bc (baseline)\""),
            "{err}"
        );
    }

    #[test]
    fn a_row_per_group_a_column_per_seed() {
        let runs = [
            record(
                "ref-s1",
                42,
                &[(0, 0, 10), (100, 50, 2600), (101, 50, 2600)],
                Some(101),
            ),
            record("ref-s1-baseline", 42, &[(0, 0, 10), (1, 0, 20)], None),
            record("ref-s2", 43, &[(0, 0, 30), (1, 2, 120)], None),
            record("abl-s2", 43, &[(5, 0, 12)], None),
        ];
        let table = table(&runs, &[]).unwrap();
        let rows: Vec<&str> = table.lines().filter(|l| l.starts_with("| ")).collect();
        assert_eq!(
            rows[0],
            "| group | seed 42 | seed 43 | reached the laps | laps, all evals | eval steps, last 50 |"
        );
        assert_eq!(
            rows[1],
            "| ref | **100** (stop 101) · 100 · 2600 | none · 2 · 75 | 1 of 2 | 51 [2–100] | 1338 [75–2600] |"
        );
        assert_eq!(
            rows[2],
            "| ref (baseline) | none · 0 · 15 |  | 0 of 1 | 0 | 15 |"
        );
        assert_eq!(rows[3], "| abl |  | none · 0 · 12 | 0 of 1 | 0 | 12 |");
        // ref's 100 and 200 (never: the budget) against its baseline's 200: a win and a tie; abl has no baseline.
        let pairs: Vec<&str> = table.lines().filter(|l| l.starts_with("* P(")).collect();
        assert_eq!(
            pairs,
            ["* P(ref reaches its first 50-lap version before ref (baseline)), rliable's probability of improvement over every pair of runs: 0.75 [0.50, 1.00] (95 % CI); by seed (1 in common): sooner on 1, later on 0, as soon on 0"]
        );
        let tmp = tempfile::tempdir().unwrap();
        let paths = draw(&runs, &tmp.path().join("ablation")).unwrap();
        assert!(paths[0].ends_with("ablation-groups.png"));
        assert!(paths[1].ends_with("ablation-first50.png"));
        for path in paths {
            let (width, rgb) = pixels(&path);
            assert_eq!(
                &rgb[..3],
                &[255, 255, 255],
                "{}: a white page",
                path.display()
            );
            // Seed 42's dots (the first colour) and seed 43's are drawn.
            for c in &SEED_COLOURS[..2] {
                let drawn = rgb.chunks(3).filter(|p| *p == [c.0, c.1, c.2]).count();
                assert!(drawn > 50, "{}: {drawn} pixels of {c:?}", path.display());
            }
            assert_eq!(width, 1000);
        }
    }
}
