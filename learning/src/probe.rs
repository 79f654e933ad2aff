//! What a run's data lets a policy copy (issue 58, `cabc probe RUN`): predictors of the expert's action fitted on
//! the run's D+ (its checkpoint's replay), their imitation loss on held-out rows beside a constant predictor's.
//!
//! A camera policy whose velocities predict the expert's label nearly as well as the whole observation can take the
//! copycat shortcut (Wen et al. 2020; de Haan et al. 2019's causal confusion): at 1 m/s the yaw rate and the lateral
//! velocity are close to a readout of the last steering, and a policy that copies it has no feedback on the car's
//! place in the lane. The probe fits, each from its own random weights, for the same Adam steps:
//! * `constant`: the training rows' mean label (the floor any input has to beat);
//! * `velocities`: an MLP of the policy's size on [v_long, v_tran, omega] alone;
//! * `camera`: the run's own policy architecture (the image and the velocities it sees);
//! * `image`: the same network with every velocity masked (`observation.velocity_inputs = []`).
//!
//! If `velocities` comes close to `camera` and far below `constant`, the labels are readable from the velocities and
//! the copycat is there to be taken. The held-out rows are whole blocks of D+'s consecutive steps (every fifth block
//! of [`ProbeOptions::block`]), so that a neighbour of a training row is rarely a held-out one.

use crate::replay::{ReplayError, ReplaySnapshot};
use cabc_models::init::{kaiming_normal, Fan};
use cabc_models::{Mlp, ModelError, Network, Policy, PolicyArch, PolicyInput, VelocityMask};
use cabc_proto::config::{ObservationKind, RunConfig};
use cabc_proto::messages::{velocity_of, ACTION_DIM, STATE_DIM, VELOCITY_DIM};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use tch::nn::{self, Module, OptimizerConfig};
use tch::{Device, Kind, Reduction, Tensor};

/// Why a run's replay could not be probed.
#[derive(Debug, thiserror::Error)]
pub enum ProbeError {
    #[error("the replay: {0}")]
    Replay(#[from] ReplayError),
    #[error("a network: {0}")]
    Model(#[from] ModelError),
    #[error("{0}")]
    Tensor(#[from] tch::TchError),
    #[error("D+ holds {held} steps: at least {need} are needed to fit and hold out (run a few epochs more)")]
    TooFew { held: usize, need: usize },
    #[error("{0}")]
    Options(String),
}

/// How the predictors are fitted.
#[derive(Clone, Debug)]
pub struct ProbeOptions {
    /// Adam steps of each fitted predictor (500).
    pub steps: usize,
    /// Rows per mini-batch (64).
    pub batch: usize,
    /// Adam's learning rate (the policy's, 1e-3).
    pub lr: f64,
    /// D+'s rows read at most, evenly spaced over D+ (a camera row holds its image in memory; 20,000).
    pub max_rows: usize,
    /// Consecutive rows per block; every fifth block is held out (200).
    pub block: usize,
    /// The seed of the predictors' weights and mini-batches (0).
    pub seed: u64,
}

impl Default for ProbeOptions {
    fn default() -> Self {
        ProbeOptions {
            steps: 500,
            batch: 64,
            lr: 1e-3,
            max_rows: 20_000,
            block: 200,
            seed: 0,
        }
    }
}

/// One predictor's losses: L_clone (mean over rows and both actions) and the steering's alone.
#[derive(Clone, Debug, Serialize)]
pub struct ProbeRow {
    pub predictor: String,
    /// What it reads of each row.
    pub sees: String,
    /// L_clone over its last 50 mini-batches (0 for the constant).
    pub train_loss: f64,
    pub held_out_loss: f64,
    pub held_out_steering_loss: f64,
    /// `held_out_loss` over the constant predictor's.
    pub share_of_constant: f64,
}

/// The probe of one run's replay.
#[derive(Clone, Debug, Serialize)]
pub struct ProbeReport {
    pub d_plus_steps: usize,
    pub train_rows: usize,
    pub held_out_rows: usize,
    pub steps: usize,
    pub predictors: Vec<ProbeRow>,
}

impl ProbeReport {
    /// The report as a Markdown table.
    pub fn table(&self) -> String {
        let mut out = format!(
            "D+ {} steps; {} rows fitted, {} held out; {} Adam steps each\n\n\
             | predictor | sees | L_clone, fit | L_clone, held out | steering, held out | of the constant's |\n\
             |---|---|---|---|---|---|\n",
            self.d_plus_steps, self.train_rows, self.held_out_rows, self.steps
        );
        for r in &self.predictors {
            out.push_str(&format!(
                "| {} | {} | {:.5} | {:.5} | {:.5} | {:.3} |\n",
                r.predictor,
                r.sees,
                r.train_loss,
                r.held_out_loss,
                r.held_out_steering_loss,
                r.share_of_constant
            ));
        }
        out
    }
}

/// The rows a probe fits: states, the expert's labels and (camera runs) images, in D+'s order.
#[derive(Clone, Debug, Default)]
pub struct Rows {
    pub states: Vec<[f32; STATE_DIM]>,
    pub labels: Vec<[f32; ACTION_DIM]>,
    /// Width, height and the images one after another (HWC RGB).
    pub images: Option<(u16, u16, Vec<u8>)>,
}

impl Rows {
    /// At most `max` rows of `replay`'s D+, evenly spaced.
    pub fn read(
        replay: &ReplaySnapshot,
        config: &RunConfig,
        max: usize,
    ) -> Result<Self, ProbeError> {
        let held = replay.plus.len();
        let stride = held.div_ceil(max.max(1)).max(1);
        let picked: Vec<usize> = (0..held).step_by(stride).collect();
        let images = match (config.observation.kind, replay.image_size()) {
            (ObservationKind::Camera, Some((w, h))) => {
                let len = w as usize * h as usize * 3;
                let mut bytes = vec![0u8; len * picked.len()];
                for (k, &i) in picked.iter().enumerate() {
                    replay.plus_image(i, &mut bytes[k * len..(k + 1) * len])?;
                }
                Some((w, h, bytes))
            }
            (ObservationKind::Camera, None) if held > 0 => {
                return Err(ReplayError::ImagePresence.into())
            }
            _ => None,
        };
        Ok(Rows {
            states: picked.iter().map(|&i| replay.plus.states[i]).collect(),
            labels: picked
                .iter()
                .map(|&i| replay.plus.expert_actions[i])
                .collect(),
            images,
        })
    }

    fn labels(&self, rows: &[usize]) -> Tensor {
        let flat: Vec<f32> = rows.iter().flat_map(|&i| self.labels[i]).collect();
        Tensor::from_slice(&flat).view([-1, ACTION_DIM as i64])
    }

    fn velocities(&self, rows: &[usize]) -> Tensor {
        let flat: Vec<f32> = rows
            .iter()
            .flat_map(|&i| velocity_of(&self.states[i]))
            .collect();
        Tensor::from_slice(&flat).view([-1, VELOCITY_DIM as i64])
    }

    /// The policy's input for `rows`: the camera's (image and velocities) or the state.
    fn policy_input(&self, rows: &[usize]) -> Result<PolicyInput, ProbeError> {
        Ok(match &self.images {
            Some((w, h, bytes)) => {
                let len = *w as usize * *h as usize * 3;
                PolicyInput::camera(
                    *w,
                    *h,
                    rows.iter()
                        .map(|&i| (&bytes[i * len..(i + 1) * len], velocity_of(&self.states[i]))),
                )?
            }
            None => PolicyInput::states(rows.iter().map(|&i| &self.states[i])),
        })
    }
}

/// A predictor being fitted: its variables and its forward pass on rows.
trait Predictor {
    fn var_store(&self) -> &nn::VarStore;
    fn forward(&self, rows: &Rows, at: &[usize]) -> Result<Tensor, ProbeError>;
}

struct Velocities {
    vs: nn::VarStore,
    mlp: Mlp,
}

impl Predictor for Velocities {
    fn var_store(&self) -> &nn::VarStore {
        &self.vs
    }
    fn forward(&self, rows: &Rows, at: &[usize]) -> Result<Tensor, ProbeError> {
        Ok(self.mlp.forward(&rows.velocities(at)))
    }
}

impl Predictor for Policy {
    fn var_store(&self) -> &nn::VarStore {
        Network::var_store(self)
    }
    fn forward(&self, rows: &Rows, at: &[usize]) -> Result<Tensor, ProbeError> {
        Ok(self.forward_t(&rows.policy_input(at)?, true))
    }
}

/// Fits `p` on `train` for `o.steps` Adam steps; returns the mean L_clone of the last 50 mini-batches.
fn fit(
    p: &dyn Predictor,
    rows: &Rows,
    train: &[usize],
    o: &ProbeOptions,
    rng: &mut ChaCha8Rng,
) -> Result<f64, ProbeError> {
    let mut opt = nn::Adam::default().build(p.var_store(), o.lr)?;
    let mut last = Vec::new();
    for step in 0..o.steps {
        let batch: Vec<usize> = (0..o.batch)
            .map(|_| train[rng.gen_range(0..train.len())])
            .collect();
        let loss = p
            .forward(rows, &batch)?
            .mse_loss(&rows.labels(&batch), Reduction::Mean);
        opt.backward_step(&loss);
        if step + 50 >= o.steps {
            last.push(loss.double_value(&[]));
        }
    }
    Ok(last.iter().sum::<f64>() / last.len().max(1) as f64)
}

/// The losses of predictions on `rows` (in chunks): all of L_clone, and the steering's.
fn held_out(
    predict: &dyn Fn(&[usize]) -> Result<Tensor, ProbeError>,
    rows: &Rows,
    at: &[usize],
) -> Result<(f64, f64), ProbeError> {
    let (mut all, mut steering) = (0.0, 0.0);
    for chunk in at.chunks(256) {
        let u = tch::no_grad(|| predict(chunk))?.to_kind(Kind::Float);
        let err = (u - rows.labels(chunk)).square();
        all += err.sum(Kind::Double).double_value(&[]);
        steering += err.select(1, 1).sum(Kind::Double).double_value(&[]);
    }
    let n = at.len() as f64;
    Ok((all / (n * ACTION_DIM as f64), steering / n))
}

/// Fits the probe's predictors on the replay of a run of `config` and returns their losses.
pub fn probe(
    config: &RunConfig,
    replay: &ReplaySnapshot,
    o: &ProbeOptions,
) -> Result<ProbeReport, ProbeError> {
    let rows = Rows::read(replay, config, o.max_rows)?;
    probe_rows(config, &rows, replay.plus.len(), o)
}

/// [`probe`] on rows already read (`held`: D+'s size, for the report).
pub fn probe_rows(
    config: &RunConfig,
    rows: &Rows,
    held: usize,
    o: &ProbeOptions,
) -> Result<ProbeReport, ProbeError> {
    if o.steps == 0 || o.batch == 0 || o.block == 0 || !(o.lr > 0.0 && o.lr.is_finite()) {
        return Err(ProbeError::Options(
            "--steps, --batch and --block must be >= 1 and --lr finite and > 0".into(),
        ));
    }
    let n = rows.labels.len();
    if rows.states.len() != n
        || rows
            .images
            .as_ref()
            .is_some_and(|(w, h, bytes)| bytes.len() != n * *w as usize * *h as usize * 3)
    {
        return Err(ProbeError::Options(
            "rows of states, labels and images of different counts".into(),
        ));
    }
    let need = 5 * o.block;
    if n < need {
        return Err(ProbeError::TooFew { held, need });
    }
    let (train, test): (Vec<usize>, Vec<usize>) = (0..n).partition(|i| (i / o.block) % 5 != 4);
    tch::manual_seed(o.seed as i64);
    let mut rng = ChaCha8Rng::seed_from_u64(o.seed);
    let mut predictors = Vec::new();

    let mean = rows.labels(&train).mean_dim(0, true, Kind::Float);
    let (c_all, c_steer) = held_out(
        &|at| Ok(mean.expand([at.len() as i64, ACTION_DIM as i64], false)),
        rows,
        &test,
    )?;
    let mut push = |predictor: &str, sees: String, train_loss: f64, (all, steer): (f64, f64)| {
        predictors.push(ProbeRow {
            predictor: predictor.into(),
            sees,
            train_loss,
            held_out_loss: all,
            held_out_steering_loss: steer,
            share_of_constant: all / c_all.max(f64::MIN_POSITIVE),
        })
    };
    push("constant", "nothing".into(), 0.0, (c_all, c_steer));

    let vs = nn::VarStore::new(Device::Cpu);
    let velocities = Velocities {
        mlp: Mlp::new(
            &(vs.root() / "mlp"),
            VELOCITY_DIM as i64,
            ACTION_DIM as i64,
            config.networks.policy,
        ),
        vs,
    };
    // Linear layers: fan-in, as the policy's head (the builder leaves them at zero).
    kaiming_normal(&velocities.vs, o.seed, |_, _| Fan::In);
    let loss = fit(&velocities, rows, &train, o, &mut rng)?;
    let losses = held_out(&|at| velocities.forward(rows, at), rows, &test)?;
    push("velocities", "v_long, v_tran, omega".into(), loss, losses);

    let arch = PolicyArch::from_config(config);
    let mut archs = vec![("camera", arch)];
    if let PolicyArch::Camera {
        trunk,
        mlp,
        sees: VelocityMask(seen),
    } = arch
    {
        if seen.contains(&true) {
            let none = VelocityMask([false; VELOCITY_DIM]);
            archs.push((
                "image",
                PolicyArch::Camera {
                    trunk,
                    mlp,
                    sees: none,
                },
            ));
        }
    }
    for (name, arch) in archs {
        let policy = Policy::new(arch, Device::Cpu, o.seed);
        let loss = fit(&policy, rows, &train, o, &mut rng)?;
        let losses = held_out(
            &|at| Ok(policy.forward_t(&rows.policy_input(at)?, false)),
            rows,
            &test,
        )?;
        let name = match arch {
            PolicyArch::State { .. } => "state",
            PolicyArch::Camera { .. } => name,
        };
        push(name, arch.to_string(), loss, losses);
    }
    Ok(ProbeReport {
        d_plus_steps: held,
        train_rows: train.len(),
        held_out_rows: test.len(),
        steps: o.steps,
        predictors,
    })
}
