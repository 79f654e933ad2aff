//! The sections of the run configuration ([`super::RunConfig`]), one struct per TOML table, with their defaults.

use super::{
    ClipScope, CriticNegatives, Episodes, ExpertFailureStaged, ExpertKind, ExpertPlacement, Flush,
    ObservationKind, Precision, SafetyStates, SafetyTerm, ScheduleKind, Spawn, StoredAction,
    TrackFeature, Velocity, VisionTrunk,
};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RunSection {
    /// Names the run: the key prefix `cabc/<name>/` and the folder `runs/<name>/`.
    pub name: String,
    /// Which experiment of the paper this reproduces (free text, for reports).
    pub experiment: String,
    pub seed: u64,
    /// Training stops after this many epochs at the latest.
    pub max_epochs: u64,
    /// Where run folders go.
    pub runs_dir: String,
}

impl Default for RunSection {
    fn default() -> Self {
        RunSection {
            name: "cabc".into(),
            experiment: "custom".into(),
            seed: 42,
            max_epochs: 500,
            runs_dir: "runs".into(),
        }
    }
}

/// The plant: what the simulator, the expert's prediction model and the plots of a run drive on.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SimSection {
    /// The track: `l-track-barc` (the paper's L-shaped BARC track, the default), a track shipped in `tracks/` by
    /// its name (`oval`, `chicane`, `long`), or a file: `*.csv`, an F1TENTH centre line (`x_m, y_m, w_tr_right_m,
    /// w_tr_left_m`), or `*.toml`, a list of pieces (docs/TRACKS.md). A relative path is from the configuration
    /// file's folder (from the working directory under `--set`); a run folder keeps its own copy.
    pub track: String,
    /// The track's lengths and widths are multiplied by this (an F1TENTH circuit is 2.2 m wide; the car's is 1.1).
    pub track_scale: f64,
    /// The constraint's half-width (m, after the scale) instead of the file's narrowest: an F1TENTH circuit's
    /// hairpins are about as tight as the circuit is wide, which no scale changes; with the BARC car's 0.55 m they
    /// drive. Left out: the file's.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub track_half_width: Option<f64>,
    /// Tracks the collecting actors drive instead of `track` (issue 76: training on several circuits): actor i
    /// drives `actor_tracks[i mod n]`, sized as `track`, its expert on it too (so `expert.placement = "in-actor"`);
    /// the evaluation and the early stop drive `track`. Names, or files read from their path on every machine (not
    /// copied into the run folder). Empty (the default): every actor drives `track`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub actor_tracks: Vec<String>,
}

impl Default for SimSection {
    fn default() -> Self {
        SimSection {
            track: Self::L_TRACK_BARC.into(),
            track_scale: 1.0,
            track_half_width: None,
            actor_tracks: Vec::new(),
        }
    }
}

impl SimSection {
    /// The paper's track, the default.
    pub const L_TRACK_BARC: &'static str = "l-track-barc";
    /// The tracks `sim.track` names without a file: the L-track, then those shipped in `tracks/` (built into the
    /// simulator: `cabc_sim::track::load::SHIPPED`).
    pub const NAMES: &'static [&'static str] = &[Self::L_TRACK_BARC, "oval", "chicane", "long"];

    /// Whether `sim.track` names a file (it ends in `.csv` or `.toml`) rather than a track by name.
    pub fn track_is_file(&self) -> bool {
        Self::is_file(&self.track)
    }

    /// Whether a track's name is a file's (it ends in `.csv` or `.toml`).
    pub fn is_file(track: &str) -> bool {
        track.ends_with(".csv") || track.ends_with(".toml")
    }

    /// A relative track file is read from `folder` (the configuration file's).
    pub fn resolve(&mut self, folder: &std::path::Path) {
        let folder = std::fs::canonicalize(folder).unwrap_or_else(|_| folder.to_path_buf());
        for track in std::iter::once(&mut self.track).chain(self.actor_tracks.iter_mut()) {
            let path = std::path::Path::new(track.as_str());
            if Self::is_file(track) && path.is_relative() {
                *track = folder.join(path).display().to_string();
            }
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ExpertSection {
    pub kind: ExpertKind,
    /// PID target speed (m/s), simulator.md 5.
    pub pid_target_speed: f64,
    /// Consecutive expert failures after which a rollout is truncated (PATIENCE).
    pub patience: u32,
    /// Warm starts the MPCC server keeps (least-recently-used eviction). Each holds a QP solver (~0.5 MB); the
    /// streams in use at once are actors x environments, so a few hundred is plenty.
    pub max_streams: usize,
    /// Largest batch a server answers.
    pub max_batch: usize,
    /// Seconds an actor waits for an expert reply before it asks again.
    pub timeout_s: f64,
    /// `server` (expert server processes, over the bus) or `in-actor` (each actor solves its own queries: no round
    /// trip, and `deploy/run-local.sh` starts no server). The answers are the same; only the wall clock differs.
    pub placement: ExpertPlacement,
    /// MPCC-conv solves each QP first without the box rows of v_y, ω and ψ, and again with them only when its
    /// minimiser leaves one of those boxes (issue 75): the same minimiser (the QP without them is a relaxation of
    /// the full one), a KKT system of 682 rows instead of 802 on most steps. False: every row, always (the
    /// reference's QP).
    pub mpcc_lazy_boxes: bool,
    /// MPCC-conv's QP tolerances: Clarabel's duality gap (absolute and relative) and its feasibility. 1e-5 and
    /// 1e-6 (the defaults) are the reference's (HPIPM's tol_comp). Looser is faster and drives a slightly slower,
    /// more cautious line (issue 75, docs/speed/issue-75/candidates.md): 1e-2 and 1e-3 take 0.70 of the step with
    /// a flying lap of 4.75 s against 4.72 and no failures. A method change: judge it over seeds.
    pub mpcc_tol_gap: f64,
    /// See `mpcc_tol_gap`.
    pub mpcc_tol_feas: f64,
}

impl Default for ExpertSection {
    fn default() -> Self {
        ExpertSection {
            kind: ExpertKind::Mpcc,
            pid_target_speed: 1.0,
            patience: 2,
            max_streams: 256,
            max_batch: 1024,
            timeout_s: 10.0,
            placement: ExpertPlacement::Server,
            mpcc_lazy_boxes: false,
            mpcc_tol_gap: 1e-5,
            mpcc_tol_feas: 1e-6,
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ObservationSection {
    pub kind: ObservationKind,
    /// Camera image width and height in pixels (224 in the reference; 64 for CPU runs).
    pub width: u16,
    pub height: u16,
    /// Horizontal field of view in degrees.
    pub fov_deg: f64,
    pub trunk: VisionTrunk,
    /// Sensor noise n_k (the paper's output equation), standard deviation per state dimension [v_long, v_tran,
    /// omega, s, x_tran, e_psi] of what the policy sees; zeros (the default) for none.
    pub state_noise_std: [f64; 6],
    /// Sensor noise on the camera image: standard deviation per channel, in intensity units (0..255); 0 for none.
    pub pixel_noise_std: f64,
    /// ImageNet weights for the ResNet-18 trunk: a safetensors file of torchvision's `resnet18` state dict (the
    /// reference starts from them; they cannot be fetched here). Absent: random initialisation, which the run's
    /// summary states (`trunk_init`).
    pub pretrained: Option<String>,
    /// The velocities beside the image that the camera policy sees (`v_long`, `v_tran`, `omega`; all three by
    /// default, the paper's); the others are zero in what the network sees, in the actor and in training alike.
    /// Issue 58's probe of the copycat shortcut: `[]` (the image alone) or `["v_long"]` (no yaw rate or lateral
    /// velocity to read the last steering from). A full-state policy sees the whole state: only the default there.
    pub velocity_inputs: Vec<Velocity>,
    /// The state's fourth entry: `s` (the arc length, the default) or `curvature-preview` (the track's mean
    /// curvature, 1/m, over the next `preview_m` metres: the same on every track).
    pub track_feature: TrackFeature,
    /// How far ahead the curvature preview looks (m).
    pub preview_m: f64,
}

impl Default for ObservationSection {
    fn default() -> Self {
        ObservationSection {
            kind: ObservationKind::State,
            width: 224,
            height: 224,
            fov_deg: 110.0,
            trunk: VisionTrunk::Resnet18,
            state_noise_std: [0.0; 6],
            pixel_noise_std: 0.0,
            pretrained: None,
            velocity_inputs: Velocity::ALL.to_vec(),
            track_feature: TrackFeature::S,
            preview_m: 1.0,
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AlgorithmSection {
    /// Weight of the safety term in L_CA (0 = the behaviour-cloning baseline); with `lambda_growth`, its cap.
    pub lambda: f64,
    /// lambda's warm-up: lambda_j = min(lambda, lambda_start * lambda_growth^j) ([`RunConfig::lambda`]). The
    /// reference's unused `SafeActor.step_schedule` grows it by 1.007 an epoch up to 10 (`models/safeAC.py:40-41`).
    /// Absent (the default): lambda from epoch 0.
    pub lambda_start: Option<f64>,
    /// lambda's growth per epoch with `lambda_start` (1.007 in the reference's `step_schedule`).
    pub lambda_growth: f64,
    /// Auto-labelling radius rho (eq. (20)).
    pub rho: f64,
    /// Shrink rho as D+ grows (the paper's future work); off by default.
    pub adaptive_rho: bool,
    /// Scale the state by its per-dimension standard deviation before the radius search.
    pub scale_states: bool,
    /// Auto-labelling runs every this many epochs.
    pub autolabel_every: u64,
    /// beta_j = beta_decay^j.
    pub beta_decay: f64,
    /// Critic label for D- (reference 0.1, paper 0).
    pub negative_label: f64,
    /// The critic's negatives: `d-minus` (ours) or all of the current D? (`uncertain`, the reference).
    pub critic_negatives: CriticNegatives,
    /// Auto-labelling runs only when D? holds at least this many points (ours 1, the reference 16).
    pub autolabel_min_uncertain: usize,
    /// Auto-labelling thins D+ to at most this many points first, spread over D+ (the reference's FADS, 32,768);
    /// 0 for all of D+ (ours).
    pub autolabel_max_plus: usize,
    /// A D? point is removed only when the hull of its neighbours has at least this many vertices (the reference's
    /// Qhull check, 8); 0 for no such check (ours).
    pub autolabel_min_vertices: usize,
    /// lambda of the `--baseline` variant of the run: 0 is plain behaviour cloning (ours); the paper's Fig. 6 caption
    /// gives its V-C baseline lambda = 1, rho = 1.
    pub baseline_lambda: f64,
    /// rho of the `--baseline` variant; absent: the run's rho.
    pub baseline_rho: Option<f64>,
}

impl Default for AlgorithmSection {
    fn default() -> Self {
        AlgorithmSection {
            lambda: 10.0,
            lambda_start: None,
            lambda_growth: 1.0,
            rho: 1.0,
            adaptive_rho: false,
            scale_states: false,
            autolabel_every: 10,
            beta_decay: 0.95,
            negative_label: 0.1,
            critic_negatives: CriticNegatives::DMinus,
            autolabel_min_uncertain: 1,
            autolabel_max_plus: 0,
            autolabel_min_vertices: 0,
            baseline_lambda: 0.0,
            baseline_rho: None,
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CollectionSection {
    /// Environment steps per epoch, all actors together (reference `eps_len`).
    pub steps_per_epoch: u64,
    /// Environment steps in epoch 0 (reference `initial_traj_len`).
    pub initial_steps: u64,
    pub spawn: Spawn,
    /// Whether episodes go on across epoch boundaries.
    pub episodes: Episodes,
    /// Maximum laps of an episode (the env truncates after it).
    pub max_laps: u32,
    /// Evaluation: laps a policy must complete from the fixed spawn.
    pub eval_laps: u32,
    /// Early stop when the evaluation completes `eval_laps` this many times.
    pub early_stop_successes: u32,
    /// The early stop judged on random spawns too (ours, issue 59; 0, the paper's: the fixed spawn alone). When the
    /// evaluation from the fixed spawn completes `eval_laps` laps, the evaluator drives this many episodes more,
    /// each of an out-lap and `eval_laps` laps, from random spawns drawn as `cabc robust` draws them
    /// (`cabc_actor::spawns`, its default ranges) under `early_stop_action_noise_std` and
    /// `early_stop_state_noise_std`; the version counts toward `early_stop_successes` only when every one of them
    /// completes its laps. The spawns and the noise come from the run's seed and the version (not `cabc robust`'s
    /// streams); the report's laps and lap times stay the fixed spawn's.
    pub early_stop_spawns: u32,
    /// Gaussian noise on the action [a m/s², delta rad] of the early stop's episodes from random spawns, added before
    /// the plant clips it (as `cabc robust --action-noise`).
    pub early_stop_action_noise_std: [f64; 2],
    /// Gaussian noise on the state [v_long, v_tran, omega, s, x_tran, e_psi] the policy observes in the early stop's
    /// episodes from random spawns, on top of `observation.state_noise_std` (as `cabc robust --state-noise`).
    pub early_stop_state_noise_std: [f64; 6],
    /// Which segment the step that completes a lap or truncates belongs to: `with-step` (ours) or `before-step` (the
    /// reference: the truncating step is dropped).
    pub flush: Flush,
    /// The staged steps of an episode the expert ended: into D? (`uncertain`, ours) or `discard` (the reference).
    pub expert_failure_staged: ExpertFailureStaged,
    /// The action stored for the dynamics model: `clipped` (ours) or `unclipped` (the reference).
    pub stored_action: StoredAction,
    /// Noise injected into the applied action in collection, not in evaluation: Gaussian, standard deviation per
    /// action dimension [acceleration m/s², steering rad], added to the mixture before the plant clips it (DART,
    /// Laskey et al., CoRL 2017). The car then visits the states just off the line it would drive, each labelled
    /// with the expert's correction, so the policy learns the feedback on x_tran and e_psi rather than a map of s
    /// alone. The stored label stays the expert's; the stored action is the one applied. [0, 0] (the reference):
    /// none.
    pub action_noise_std: [f64; 2],
    /// p_hat as a shield in collection (SafeDAgger, EnsembleDAgger and ThriftyDAgger use a learned safety signal
    /// so): once the critic has trained, a step whose applied action u (the mixture's, with its noise) has
    /// p_hat(f_hat(x, u)) below this is driven by the expert's action instead (when the expert answered); the
    /// stored label stays the expert's either way. 0 (the paper): no shield.
    pub shield: f64,
    /// Collection overlapping training (issue 46): from epoch 1 on, the actors collect D_new with pi_j while the
    /// learner trains on what it held before, so that an epoch takes about the longer of the two instead of their
    /// sum. The policy that collects is then one version behind the synchronous order's (IMPALA's and Sample
    /// Factory's actors run so). false (Algorithm 1's order): collection, then training.
    pub overlap: bool,
}

impl Default for CollectionSection {
    fn default() -> Self {
        CollectionSection {
            steps_per_epoch: 1024,
            initial_steps: 1024,
            spawn: Spawn::Random,
            episodes: Episodes::Carry,
            max_laps: 50,
            eval_laps: 50,
            early_stop_successes: 2,
            early_stop_spawns: 0,
            early_stop_action_noise_std: [0.0; 2],
            early_stop_state_noise_std: [0.0; 6],
            flush: Flush::WithStep,
            expert_failure_staged: ExpertFailureStaged::Uncertain,
            stored_action: StoredAction::Clipped,
            action_noise_std: [0.0; 2],
            shield: 0.0,
            overlap: false,
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReplaySection {
    /// Capacity of D+ and of D? each; random eviction on overflow.
    pub capacity: usize,
    /// Memory the replay may hold, in bytes (0: no budget beyond `capacity`). D+ holds the images; its capacity
    /// becomes what fits in this budget once the other stores' (and D-'s) full capacity is set aside, and random
    /// eviction keeps it there. A budget too small for one batch of D+ is refused at start.
    pub max_bytes: u64,
    /// Keep a dynamics-only store for f_hat (ours): unfinished laps, the step after the last lap, and the D? points
    /// auto-labelling removes. false (the reference): unfinished laps are dropped, removed points deleted, and f_hat
    /// trains on D+ and D? alone.
    pub dynamics_only: bool,
}

impl Default for ReplaySection {
    fn default() -> Self {
        ReplaySection {
            capacity: 102_400,
            max_bytes: 0,
            dynamics_only: true,
        }
    }
}

/// Bytes of one replay step besides its image: state, next state, expert and applied action, as f32.
pub const REPLAY_STEP_BYTES: u64 = 4 * (2 * 6 + 2 * 2);

/// An MLP: `layers` hidden Linear+ReLU layers of `width`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MlpSize {
    pub layers: usize,
    pub width: usize,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NetworksSection {
    pub policy: MlpSize,
    pub dynamics: MlpSize,
    pub critic: MlpSize,
}

impl Default for NetworksSection {
    fn default() -> Self {
        NetworksSection {
            policy: MlpSize {
                layers: 3,
                width: 128,
            },
            dynamics: MlpSize {
                layers: 3,
                width: 64,
            },
            critic: MlpSize {
                layers: 4,
                width: 256,
            },
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainingSection {
    pub lr: f64,
    pub weight_decay: f64,
    pub grad_clip: f64,
    /// ExponentialLR gamma, stepped once per fit call (reference 0.1^(1/100)).
    pub lr_gamma: f64,
    /// The policy's own gamma; absent: `lr_gamma` (ours). The reference's vision trainer keeps the policy's
    /// learning rate at 1e-3 (gamma 1).
    pub policy_lr_gamma: Option<f64>,
    /// The learning rates' floor: lr = max(lr * gamma^fits, lr_min), for all three networks; 0 (the reference) for
    /// none, where gamma 0.1^(1/100) per fit leaves 1e-5 by epoch 200 and the policy all but frozen.
    pub lr_min: f64,
    /// Which gradients the policy's clip measures: `policy` (ours) or `policy-critic-dynamics` (the reference).
    pub clip_scope: ClipScope,
    /// Standardise the state for the three networks with D+'s mean and standard deviation, taken once, at the first
    /// policy fit, and checkpointed (robomimic, LeRobot and Diffusion Policy standardise inputs). The reference feeds
    /// the raw state, where s runs over the whole track and the other dimensions stay near 1. The published policy
    /// takes raw states: the standardisation is folded into its first layer.
    pub standardise: bool,
    /// The published policy (collection and evaluation) is an exponential moving average of the trained weights,
    /// updated once an epoch after the policy's fit: ema = policy_ema * ema + (1 - policy_ema) * theta (LeRobot and
    /// Diffusion Policy evaluate such an average). 0 (the reference) publishes the trained weights.
    pub policy_ema: f64,
    /// L_clone also on D?'s states, with the expert's labels (the steps where the expert failed excepted): DAgger's
    /// aggregate, where the reference and Algorithm 1's diagram clone D+ alone. The states where the policy left the
    /// track, and the expert's corrections there, are then in the policy's training set; L_safety stays on D+'s
    /// states unless `safety_states = "clone"`. A camera policy reads D?'s images, which
    /// D? then keeps (within `replay.max_bytes`, [`super::RunConfig::uncertain_images`]). false (the reference): D+ alone.
    pub clone_uncertain: bool,
    /// The states L_safety averages over: `d-plus` (the recorded runs: the batch's D+ rows) or `clone` (eq. (14):
    /// every row L_clone fits, D?'s too with `clone_uncertain`).
    pub safety_states: SafetyStates,
    /// `absolute` (eq. (14)) or `hinged` (only actions predicted less safe than the expert's, [`SafetyTerm`]).
    pub safety_term: SafetyTerm,
    /// L_safety acts only while the critic's last held-out balanced accuracy (p_hat before an epoch's fit, on that
    /// epoch's new D+ and D? rows) is at least this; 0 (the recorded runs): from the critic's first fit on.
    pub safety_gate: f64,
    pub batch_size: usize,
    /// Passes over D+ for the policy in epoch 0 and later.
    pub initial_passes: usize,
    pub passes: usize,
    /// At most this many mini-batches per policy fit (a uniform sample of D+ without replacement) instead of whole
    /// passes: 0 (the paper) for no cap. With images on a CPU a pass over D+ grows by seconds each epoch; the CPU
    /// presets cap it so an epoch's training time stays flat.
    pub policy_max_batches: usize,
    pub schedule: ScheduleKind,
    /// k_f: the dynamics model trains every this many epochs.
    pub dynamics_every: u64,
    /// k_p: the critic trains every this many epochs.
    pub critic_every: u64,
    /// Passes of the dynamics model and critic each time they train (`paper` schedule).
    pub aux_passes: usize,
    /// Their passes in epoch 0 (`paper` schedule); absent: `aux_passes`. The reference's vision trainer makes 50
    /// (10 x the policy's 5).
    pub initial_aux_passes: Option<usize>,
    /// At most this many mini-batches per fit of the dynamics model or the critic (a uniform sample without
    /// replacement of the first pass, then of the next), instead of whole passes: 0 (the paper) for no cap. Both
    /// networks keep their weights from one fit to the next, so a fixed budget of steps holds their cost flat while
    /// D+ u D? grows (10 passes over it cost 45 s at epoch 140 in V-B on a 2-core CPU).
    pub aux_max_batches: usize,
    /// The critic trains only when its negatives (D-, or D? with `critic_negatives = "uncertain"`) are more than
    /// this many (ours and the reference's vision trainer 16; its full-state trainer 0).
    pub critic_min_uncertain: usize,
    /// "auto" (CUDA when present), "cpu" or "cuda:N".
    pub device: String,
    /// "fp32" (default) or "bf16" (CUDA autocast for the forward passes; fp32 on a CPU).
    pub precision: Precision,
}

impl Default for TrainingSection {
    fn default() -> Self {
        TrainingSection {
            lr: 1e-3,
            weight_decay: 1e-4,
            grad_clip: 1.0,
            lr_gamma: 0.1f64.powf(1.0 / 100.0),
            policy_lr_gamma: None,
            lr_min: 0.0,
            clip_scope: ClipScope::Policy,
            standardise: false,
            policy_ema: 0.0,
            clone_uncertain: false,
            safety_states: SafetyStates::DPlus,
            safety_term: SafetyTerm::Absolute,
            safety_gate: 0.0,
            batch_size: 64,
            initial_passes: 5,
            passes: 1,
            policy_max_batches: 0,
            schedule: ScheduleKind::Paper,
            dynamics_every: 5,
            critic_every: 10,
            aux_passes: 10,
            initial_aux_passes: None,
            aux_max_batches: 0,
            critic_min_uncertain: 16,
            device: "auto".into(),
            precision: Precision::Fp32,
        }
    }
}

/// The `[actors]` table. `count` is read as a number or `"auto"` ([`super::actors::ActorCount`]) and resolved when
/// the configuration is read, so that every reader sees a number and a run folder's config.toml holds the count the run
/// ran with (issue 75).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(from = "super::actors::ActorsToml")]
pub struct ActorsSection {
    /// Actor processes (the eval actor comes on top). Written as a number, or `"auto"`: the cores this machine gives
    /// the process that reads the configuration ([`std::thread::available_parallelism`], which follows CPU affinity
    /// and cgroup quotas), at most `auto_max`. Algorithm 1's learner waits while the actors collect (unless
    /// `collection.overlap`), so every core collects; with `collection.overlap` the learner's training thread keeps
    /// one core and `"auto"` takes one fewer. The evaluators run on top (their work is the policy's inference and
    /// the simulator, no MPCC).
    pub count: u32,
    /// The most actors `count = "auto"` takes (an epoch's steps are dealt over the actors, so many actors mean short
    /// episodes).
    pub auto_max: u32,
    /// Environments each actor steps in lockstep.
    pub envs_per_actor: u32,
    /// Evaluator processes (`actor --eval`): evaluator i evaluates every version v with v mod evaluators = i, so
    /// that several keep up with a slow evaluation (a 50-lap camera run) between them.
    pub evaluators: u32,
    /// An evaluation stores the driven line subsampled to at most this many points.
    pub eval_line_points: usize,
}

impl Default for ActorsSection {
    fn default() -> Self {
        ActorsSection {
            count: 2,
            auto_max: 8,
            envs_per_actor: 4,
            evaluators: 1,
            eval_line_points: 2000,
        }
    }
}
