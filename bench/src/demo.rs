//! The paper's Fig. 3, reproduced: safety auto-labelling and the critic it trains on a constructed 2-d example.
//!
//! The true safe set R is a chevron inside X = [-1, 1]^2: a square with a V-shaped notch cut from the top, whose tip
//! is a sharp concave corner. D+ is uniform in R, D? uniform in X. For each rho, D? is auto-labelled against D+
//! (eq. (19)), a critic MLP (the configured critic size, on 2-d input) is trained on D+ (label 1) and D-
//! (label `negative_label`), and one panel shows: the true boundary (dotted black), D+ (grey), D- (orange), the
//! points wrongly removed from D? (red: outside R, yet in the local hull), and the critic's level curves p = 0.5
//! (blue), 0.7 (purple) and 0.9 (green). A larger rho bridges the notch and removes more points wrongly.

use cabc_learning::autolabel::{autolabel, AutolabelOptions};
use cabc_learning::train::CriticTrainer;
use cabc_proto::config::RunConfig;
use plotters::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::path::Path;
use tch::{Device, Kind, Tensor};

/// The example's own numbers (the paper gives none): sample sizes, critic passes, evaluation grid, picture size.
const N_PLUS: usize = 1500;
const N_UNCERTAIN: usize = 2000;
const CRITIC_PASSES: usize = 40;
const GRID: usize = 161;
const PANEL_PX: u32 = 560;
/// The level curves drawn, with their colours.
const LEVELS: [(f64, RGBColor); 3] = [
    (0.5, BLUE),
    (0.7, RGBColor(128, 0, 160)),
    (0.9, RGBColor(0, 150, 0)),
];

/// The true safe set: a chevron (counter-clockwise vertices).
pub const TRUE_SET: [(f64, f64); 5] = [
    (-0.8, -0.8),
    (0.8, -0.8),
    (0.8, 0.8),
    (0.0, -0.1),
    (-0.8, 0.8),
];

#[derive(Debug, thiserror::Error)]
pub enum DemoError {
    #[error("drawing {path}: {message}")]
    Plot { path: String, message: String },
}

/// One rho of the figure.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DemoPanel {
    pub rho: f64,
    /// Removed from D? and truly safe.
    pub removed_correctly: usize,
    /// Removed from D? but outside the true set (the red points).
    pub removed_wrongly: usize,
    /// Left in D- (not removed).
    pub kept: usize,
    /// Of those kept, truly safe (false negatives the critic still sees).
    pub kept_inside: usize,
    pub too_few_neighbours: usize,
    /// Critic's p > 0.5 against the true set on a GRID x GRID grid over X.
    pub accuracy: f64,
    pub critic_loss: f64,
    pub autolabel_seconds: f64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DemoReport {
    pub seed: u64,
    pub n_plus: usize,
    pub n_uncertain: usize,
    pub png: String,
    pub panels: Vec<DemoPanel>,
}

/// Whether `p` lies in the polygon `poly` (even-odd rule).
pub fn in_polygon(p: (f64, f64), poly: &[(f64, f64)]) -> bool {
    let mut inside = false;
    let mut j = poly.len() - 1;
    for i in 0..poly.len() {
        let (xi, yi) = poly[i];
        let (xj, yj) = poly[j];
        if (yi > p.1) != (yj > p.1) && p.0 < (xj - xi) * (p.1 - yi) / (yj - yi) + xi {
            inside = !inside;
        }
        j = i;
    }
    inside
}

impl DemoReport {
    /// Logs one line per panel and where the figure went.
    pub fn log(&self) {
        for p in &self.panels {
            tracing::info!(
                rho = p.rho,
                removed_correctly = p.removed_correctly,
                removed_wrongly = p.removed_wrongly,
                kept = p.kept,
                accuracy = p.accuracy,
                "panel"
            );
        }
        tracing::info!(png = %self.png, "written");
    }
}

/// `cabc demo`'s command-line arguments.
#[derive(Clone, Debug, clap::Args)]
pub struct DemoOptions {
    /// Radii to compare, one panel each.
    #[arg(long = "rho", num_args = 1.., default_values_t = [0.5, 0.25, 0.1])]
    pub rho: Vec<f64>,
    #[arg(long, default_value = "autolabel-demo.png")]
    pub out: std::path::PathBuf,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// Runs the example for each rho, draws one panel per rho into `out_png`, and reports the counts.
pub fn autolabel_demo(rhos: &[f64], seed: u64, out_png: &Path) -> Result<DemoReport, DemoError> {
    let config = RunConfig::default();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut plus = Vec::with_capacity(2 * N_PLUS);
    while plus.len() < 2 * N_PLUS {
        let p = (rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0));
        if in_polygon(p, &TRUE_SET) {
            plus.extend([p.0, p.1]);
        }
    }
    let uncertain: Vec<f64> = (0..2 * N_UNCERTAIN)
        .map(|_| rng.gen_range(-1.0..1.0))
        .collect();
    let truth: Vec<bool> = uncertain
        .chunks_exact(2)
        .map(|p| in_polygon((p[0], p[1]), &TRUE_SET))
        .collect();
    let grid: Vec<f64> = (0..GRID * GRID)
        .flat_map(|k| [cell(k % GRID), cell(k / GRID)])
        .collect();
    let grid_truth: Vec<bool> = grid
        .chunks_exact(2)
        .map(|p| in_polygon((p[0], p[1]), &TRUE_SET))
        .collect();

    let mut panels = Vec::new();
    let mut drawn = Vec::new();
    for &rho in rhos {
        let labels = autolabel(&plus, &uncertain, 2, &AutolabelOptions::fixed(rho));
        let mut removed = vec![false; N_UNCERTAIN];
        for &i in &labels.removed {
            removed[i] = true;
        }
        let minus: Vec<f64> = uncertain
            .chunks_exact(2)
            .zip(&removed)
            .filter(|(_, &r)| !r)
            .flat_map(|(p, _)| [p[0], p[1]])
            .collect();
        // Critic on D+ (1) and D- (negative_label).
        let x: Vec<f32> = plus.iter().chain(&minus).map(|&v| v as f32).collect();
        let n_minus = minus.len() / 2;
        let x = Tensor::from_slice(&x).view([(N_PLUS + n_minus) as i64, 2]);
        let y = Tensor::cat(
            &[
                Tensor::ones([N_PLUS as i64], (Kind::Float, Device::Cpu)),
                Tensor::full(
                    [n_minus as i64],
                    config.algorithm.negative_label,
                    (Kind::Float, Device::Cpu),
                ),
            ],
            0,
        );
        let mut critic = CriticTrainer::new(2, &config, Device::Cpu, seed);
        let fit = critic.fit(&x, &y, CRITIC_PASSES, &config);
        let grid_t =
            Tensor::from_slice(&grid.iter().map(|&v| v as f32).collect::<Vec<_>>()).view([-1, 2]);
        let p_grid: Vec<f32> =
            Vec::try_from(&tch::no_grad(|| critic.critic.probability(&grid_t))).expect("floats");
        let correct = p_grid
            .iter()
            .zip(&grid_truth)
            .filter(|(p, &t)| (**p > 0.5) == t)
            .count();
        let removed_wrongly = labels.removed.iter().filter(|&&i| !truth[i]).count();
        panels.push(DemoPanel {
            rho,
            removed_correctly: labels.removed.len() - removed_wrongly,
            removed_wrongly,
            kept: labels.kept(),
            kept_inside: (0..N_UNCERTAIN)
                .filter(|&i| !removed[i] && truth[i])
                .count(),
            too_few_neighbours: labels.too_few_neighbours,
            accuracy: correct as f64 / grid_truth.len() as f64,
            critic_loss: fit.loss,
            autolabel_seconds: labels.seconds,
        });
        drawn.push((removed, p_grid));
    }
    draw(out_png, &plus, &uncertain, &truth, &panels, &drawn).map_err(|e| DemoError::Plot {
        path: out_png.display().to_string(),
        message: e.to_string(),
    })?;
    Ok(DemoReport {
        seed,
        n_plus: N_PLUS,
        n_uncertain: N_UNCERTAIN,
        png: out_png.display().to_string(),
        panels,
    })
}

/// Grid coordinate k in [-1, 1].
fn cell(k: usize) -> f64 {
    -1.0 + 2.0 * k as f64 / (GRID - 1) as f64
}

type Panels = [(Vec<bool>, Vec<f32>)];

fn draw(
    out: &Path,
    plus: &[f64],
    uncertain: &[f64],
    truth: &[bool],
    panels: &[DemoPanel],
    drawn: &Panels,
) -> Result<(), Box<dyn std::error::Error>> {
    let n = panels.len().max(1) as u32;
    cabc_outputs::plots::png(out, (PANEL_PX * n, PANEL_PX + 40), |root| {
        root.fill(&WHITE)?;
        let areas = root.split_evenly((1, n as usize));
        for ((area, panel), (removed, p_grid)) in areas.iter().zip(panels).zip(drawn) {
            let caption = format!(
                "rho = {}: {} wrongly removed, grid acc {:.3}",
                panel.rho, panel.removed_wrongly, panel.accuracy
            );
            let mut chart = ChartBuilder::on(area)
                .caption(caption, ("sans-serif", 18))
                .margin(10)
                .x_label_area_size(30)
                .y_label_area_size(30)
                .build_cartesian_2d(-1.0f64..1.0, -1.0f64..1.0)?;
            chart.configure_mesh().disable_mesh().draw()?;
            let pts = |v: &[f64]| -> Vec<(f64, f64)> {
                v.chunks_exact(2).map(|p| (p[0], p[1])).collect()
            };
            let grey = RGBColor(150, 150, 150);
            let orange = RGBColor(240, 150, 30);
            chart.draw_series(
                pts(plus)
                    .into_iter()
                    .map(|p| Circle::new(p, 1, grey.filled())),
            )?;
            let q = pts(uncertain);
            chart.draw_series(
                q.iter()
                    .zip(removed)
                    .filter(|(_, &r)| !r)
                    .map(|(&p, _)| Circle::new(p, 2, orange.filled())),
            )?;
            chart.draw_series(
                q.iter()
                    .zip(removed)
                    .zip(truth)
                    .filter(|((_, &r), &t)| r && !t)
                    .map(|((&p, _), _)| Circle::new(p, 3, RED.filled())),
            )?;
            // True boundary, dotted.
            let mut dots = Vec::new();
            for i in 0..TRUE_SET.len() {
                let (a, b) = (TRUE_SET[i], TRUE_SET[(i + 1) % TRUE_SET.len()]);
                let len = ((b.0 - a.0).powi(2) + (b.1 - a.1).powi(2)).sqrt();
                let steps = (len / 0.025) as usize;
                for s in 0..steps {
                    let t = s as f64 / steps as f64;
                    dots.push((a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1)));
                }
            }
            chart.draw_series(dots.into_iter().map(|p| Circle::new(p, 1, BLACK.filled())))?;
            for (level, colour) in LEVELS {
                for seg in contour(p_grid, level as f32) {
                    chart.draw_series(LineSeries::new(seg, colour.stroke_width(2)))?;
                }
            }
        }
        Ok(())
    })
}

/// Marching squares on the GRID x GRID values (x fastest): line segments of the level set.
fn contour(values: &[f32], level: f32) -> Vec<[(f64, f64); 2]> {
    let v = |i: usize, j: usize| values[j * GRID + i] - level;
    let mut segments = Vec::new();
    for j in 0..GRID - 1 {
        for i in 0..GRID - 1 {
            let corners = [(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)];
            let mut crossings = Vec::with_capacity(4);
            for e in 0..4 {
                let (a, b) = (corners[e], corners[(e + 1) % 4]);
                let (va, vb) = (v(a.0, a.1), v(b.0, b.1));
                if (va < 0.0) != (vb < 0.0) {
                    let t = (va / (va - vb)) as f64;
                    let (xa, ya) = (cell(a.0), cell(a.1));
                    let (xb, yb) = (cell(b.0), cell(b.1));
                    crossings.push((xa + t * (xb - xa), ya + t * (yb - ya)));
                }
            }
            for pair in crossings.chunks_exact(2) {
                segments.push([pair[0], pair[1]]);
            }
        }
    }
    segments
}
