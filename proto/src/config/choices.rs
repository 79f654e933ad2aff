//! The run configuration's named choices: the kinds of a run (track, expert, observation, trunk, spawn), and the choices of
//! protocol and arithmetic where ours and the reference implementation differ (docs/PROTOCOL.md, issue 18), each a
//! key whose values name both.

use serde::{Deserialize, Serialize};

/// Which expert relabels the states.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ExpertKind {
    /// MPCC-conv (experiments V-B, V-C).
    Mpcc,
    /// The PID lane follower (experiment V-A).
    Pid,
}

impl ExpertKind {
    pub fn as_str(self) -> &'static str {
        match self {
            ExpertKind::Mpcc => "mpcc",
            ExpertKind::Pid => "pid",
        }
    }
}

/// Where the expert's relabellings are solved (`expert.placement`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ExpertPlacement {
    /// Expert server processes (`expert-server serve`) answer the actors' queries over the bus.
    #[default]
    Server,
    /// Each actor solves its own queries in its process, with the servers' code: the same answers (while the
    /// environments in flight fit in `expert.max_streams`), without a round trip over the bus each step.
    InActor,
}

impl ExpertPlacement {
    pub fn as_str(self) -> &'static str {
        match self {
            ExpertPlacement::Server => "server",
            ExpertPlacement::InActor => "in-actor",
        }
    }
}

/// What the policy observes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ObservationKind {
    /// The full 6-d Frenet state.
    State,
    /// A first-person camera image plus the three velocities.
    Camera,
}

/// The trunk of the vision policy.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum VisionTrunk {
    /// ResNet-18, trained from scratch (the reference uses ImageNet weights, which cannot be had here).
    Resnet18,
    /// A small 4-layer CNN for CPU-only machines.
    SmallCnn,
}

/// One of the velocities beside a camera image ([`crate::messages::velocity_of`]): `observation.velocity_inputs`
/// names those the camera policy sees (issue 58: the copycat shortcut, a policy that reads its last steering off the
/// yaw rate and the lateral velocity).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Velocity {
    VLong,
    VTran,
    Omega,
}

impl Velocity {
    /// In the order of [`crate::messages::velocity_of`].
    pub const ALL: [Velocity; crate::messages::VELOCITY_DIM] =
        [Velocity::VLong, Velocity::VTran, Velocity::Omega];

    pub fn as_str(self) -> &'static str {
        match self {
            Velocity::VLong => "v_long",
            Velocity::VTran => "v_tran",
            Velocity::Omega => "omega",
        }
    }

    /// Its index in [`crate::messages::velocity_of`].
    pub fn index(self) -> usize {
        self as usize
    }
}

/// Where an episode starts (simulator.md §3.2): the run's training spawns, and the simulator's `reset`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Spawn {
    /// Training spawn, drawn in this order: s ~ U(0.1, L−2), x_tran ~ U(−band, band), e_psi ~ U(−π/6, π/6),
    /// v_long ~ U(0.5, 2).
    Random,
    /// The evaluation spawn: s = 0.1, x_tran = 0, e_psi = 0, v_long = 0.5 (`cabc_sim::env::FIXED_SPAWN`).
    Fixed,
}

impl std::str::FromStr for Spawn {
    type Err = String;

    /// "random" or "fixed", as in the configuration.
    fn from_str(s: &str) -> Result<Spawn, String> {
        match s {
            "random" => Ok(Spawn::Random),
            "fixed" => Ok(Spawn::Fixed),
            _ => Err(format!("unknown spawn {s:?}: expected random or fixed")),
        }
    }
}

/// What an epoch boundary does to the actors' episodes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Episodes {
    /// Episodes go on across epoch boundaries (the mixture changes at the boundary; the labels are the expert's
    /// either way), so an episode's length does not depend on how many actors and environments share the epoch's
    /// budget, and a lap started before a boundary lands in D+ whole once it completes.
    Carry,
    /// The reference's collection: every environment starts a new episode at each epoch, and what is staged when
    /// the budget runs out is flushed as incomplete (dynamics only, never labelled).
    Reset,
}

/// When the dynamics model and the critic train.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ScheduleKind {
    /// Algorithm 1: dynamics every k_f epochs, critic every k_p epochs.
    Paper,
    /// The reference's full-state trainer: all three every epoch.
    EveryEpoch,
}

/// The arithmetic of training (`training.precision`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    /// fp32 throughout (the paper's).
    #[default]
    Fp32,
    /// Forward passes under CUDA autocast in bfloat16; weights and optimiser in fp32. CUDA only (fp32 on a CPU).
    Bf16,
}

/// Where a segment is cut relative to the step that ends it (`collection.flush`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Flush {
    /// Ours: the step belongs to the segment its transition ends. The lap-completing step is part of its lap (D+) and
    /// the truncating step part of the failure (D?), so an off-track spawn puts its one state into D?.
    WithStep,
    /// The reference's `add_frame`: the staged steps are flushed before the current step is staged. The
    /// lap-completing step opens the next lap's segment, and the truncating step is dropped with the reset, so an
    /// off-track spawn stores nothing.
    BeforeStep,
}

/// What happens to an episode's staged steps when the expert fails `expert.patience` times in a row, or fails on a
/// step that truncates (`collection.expert_failure_staged`). The failing steps go to D? either way.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ExpertFailureStaged {
    /// Ours: they are a failed segment, into D?.
    Uncertain,
    /// The reference: they are discarded with the reset (`clear_buffer`).
    Discard,
}

/// Which action a step stores for the dynamics model (`collection.stored_action`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum StoredAction {
    /// Ours: the action the plant received, clipped to the action box.
    Clipped,
    /// The reference: the blended action before the environment clips it (`closed_loop_action`).
    Unclipped,
}

/// The critic's negatives (`algorithm.critic_negatives`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CriticNegatives {
    /// Ours: D-, what the last auto-labelling left in D? (eq. (19)), held until the next labelling.
    DMinus,
    /// The reference's full-state trainer: all of D? as it is now, failures not yet labelled too.
    Uncertain,
}

/// Over which states L_safety, eq. (14)'s second term, takes its mean (`training.safety_states`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SafetyStates {
    /// The recorded runs (issues 18 and 30): the batch's D+ rows alone, so that with `training.clone_uncertain`
    /// the states near a failure (D?'s) give L_safety no gradient.
    DPlus,
    /// Eq. (14) as written: the expectation over the states L_clone sees (D+, and D?'s expert-labelled rows with
    /// `training.clone_uncertain`), the states near a failure included.
    Clone,
}

/// What L_safety penalises (`training.safety_term`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SafetyTerm {
    /// Eq. (14): -lambda log p_hat(f_hat(x, pi(y))), every action pushed towards higher predicted safety.
    Absolute,
    /// Relative to the expert (issue 45): lambda max(0, log p_hat(f_hat(x, pi_beta(x))) - log p_hat(f_hat(x,
    /// pi(y)))), only an action predicted less safe than the expert's own is penalised, so that L_safety does not
    /// pull against L_clone where the expert's action is as safe as the critic can tell.
    Hinged,
}

/// Which gradients the policy's gradient-norm clip measures (`training.clip_scope`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ClipScope {
    /// Ours: the policy's own gradients.
    Policy,
    /// The reference (`base_model.py`): `clip_grad_norm_(self.parameters())` of a module that holds the critic and
    /// the dynamics model as submodules, whose gradients are never zeroed during the policy's fit. The policy's
    /// clip factor then also counts their last fit's gradient and what L_safety accumulates into them.
    PolicyCriticDynamics,
}

/// What the fourth entry of the observed state is (`observation.track_feature`): the arc length `s` (the paper's and
/// the default), or the track's mean curvature over the next `observation.preview_m` metres, which means the same on
/// every track (issue 76: a policy that drives circuits it never saw).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TrackFeature {
    #[default]
    S,
    CurvaturePreview,
}
