//! Collection: K environments stepped in lockstep under the expert/policy mixture of Algorithm 1, zenoh-free.
//!
//! The driver (the actor binary, or a test in-process) repeats:
//! [`Collector::queries`] → ask the expert → [`Collector::observations`] → run the policy → [`Collector::step`],
//! publishing the segments each step completes, until the epoch's budget is spent; then [`Collector::end_epoch`].
//! The applied action is `beta * expert + (1 - beta) * policy` when the expert solved its problem, else the
//! policy's action (as the reference does); the stored label is always the expert's action.

use crate::eyes::Eyes;
use crate::segment::{Segmenter, SeqCounter, StepEnd};
use cabc_proto::config::{ObservationKind, RunConfig, SpawnKind};
use cabc_proto::messages::{EndReason, ExpertAnswer, ExpertQuery, Image, Segment, Step, StreamId};
use cabc_sim::env::{Env, EnvConfig, Observation, Spawn, Truncation};
use cabc_sim::track::Track;
use cabc_sim::vehicle::{clip_action, VehicleParams};
use rand_chacha::ChaCha8Rng;
use std::sync::Arc;

/// What the policy sees for a batch of environments.
pub struct PolicyInput<'a> {
    /// Full states [v_long, v_tran, omega, s, x_tran, e_psi].
    pub states: &'a [[f32; 6]],
    /// Camera images, one per state, when the run observes images (else empty).
    pub images: &'a [Image],
}

/// Maps the simulator's truncation to the protocol's end reason.
pub fn end_reason(t: Truncation) -> EndReason {
    match t {
        Truncation::OutOfTrack => EndReason::OutOfTrack,
        Truncation::LeftBand => EndReason::LeftBand,
        Truncation::Stall => EndReason::Stall,
        Truncation::Spin => EndReason::Spin,
        Truncation::MaxLaps => EndReason::MaxLaps,
    }
}

/// The environment of a run: the BARC track, the reference vehicle and env constants, `max_laps` laps at most.
pub fn make_env(max_laps: u32) -> Env {
    let env_config = EnvConfig {
        max_laps,
        ..EnvConfig::default()
    };
    Env::new(
        Arc::new(Track::l_track_barc()),
        VehicleParams::default(),
        env_config,
    )
}

fn f32s<const N: usize>(x: &[f64; N]) -> [f32; N] {
    x.map(|v| v as f32)
}

/// One actor's K environments.
pub struct Collector {
    actor: String,
    envs: Vec<Env>,
    rngs: Vec<ChaCha8Rng>,
    segmenters: Vec<Segmenter>,
    stream_start: Vec<bool>,
    seq: SeqCounter,
    spawn: Spawn,
    eyes: Option<Eyes>,
    states: Vec<[f32; 6]>,
    images: Vec<Image>,
    /// Steps taken in the current epoch.
    taken: u64,
}

impl Collector {
    /// `index` makes each actor's random streams distinct (actor k uses streams k*K .. k*K+K-1 of the run seed).
    pub fn new(actor: &str, index: u64, config: &RunConfig) -> Self {
        let k = config.actors.envs_per_actor as usize;
        let envs: Vec<Env> = (0..k)
            .map(|_| make_env(config.collection.max_laps))
            .collect();
        let rngs = (0..k)
            .map(|i| Env::rng(config.run.seed, index * k as u64 + i as u64))
            .collect();
        let segmenters = (0..k)
            .map(|i| Segmenter::new(actor, i as u32, config.expert.patience))
            .collect();
        let eyes = (config.observation.kind == ObservationKind::Camera)
            .then(|| Eyes::new(&config.observation));
        let spawn = match config.collection.spawn {
            SpawnKind::Random => Spawn::Random,
            SpawnKind::Fixed => Spawn::Fixed,
        };
        Collector {
            actor: actor.to_string(),
            envs,
            rngs,
            segmenters,
            stream_start: vec![true; k],
            seq: SeqCounter::default(),
            spawn,
            eyes,
            states: Vec::with_capacity(k),
            images: Vec::with_capacity(k),
            taken: 0,
        }
    }

    /// The actor's name (the `actor` of its segments).
    pub fn actor(&self) -> &str {
        &self.actor
    }

    pub fn len(&self) -> usize {
        self.envs.len()
    }

    pub fn is_empty(&self) -> bool {
        self.envs.is_empty()
    }

    /// Segments published so far (the next `seq`).
    pub fn segments_cut(&self) -> u64 {
        self.seq.0
    }

    /// Steps taken in this epoch.
    pub fn taken(&self) -> u64 {
        self.taken
    }

    /// Starts an epoch: every environment starts a new episode (the reference resets at each epoch).
    pub fn begin_epoch(&mut self) {
        self.taken = 0;
        for i in 0..self.envs.len() {
            self.reset(i);
        }
    }

    fn reset(&mut self, i: usize) {
        self.envs[i].reset(self.spawn, &mut self.rngs[i]);
        self.stream_start[i] = true;
    }

    /// How many environments step next, given what is left of the budget.
    pub fn active(&self, budget: u64) -> usize {
        (budget.saturating_sub(self.taken)).min(self.envs.len() as u64) as usize
    }

    /// The expert queries of the next step (for the first `active` environments).
    pub fn queries(&self, active: usize) -> Vec<ExpertQuery> {
        (0..active)
            .map(|i| {
                let env = &self.envs[i];
                ExpertQuery {
                    stream: StreamId {
                        actor: self.actor.clone(),
                        env: i as u32,
                        episode: self.segmenters[i].episode(),
                    },
                    start: self.stream_start[i],
                    vehicle: env.vehicle_state(),
                    frenet: env.observation().state,
                }
            })
            .collect()
    }

    /// Observations of the first `active` environments (images rendered when the run observes images).
    pub fn observations(&mut self, active: usize) -> PolicyInput<'_> {
        self.states.clear();
        self.images.clear();
        for env in &self.envs[..active] {
            self.states.push(f32s(&env.observation().state));
            if let Some(eyes) = &mut self.eyes {
                self.images.push(eyes.see(env));
            }
        }
        PolicyInput {
            states: &self.states,
            images: &self.images,
        }
    }

    /// Steps the first `answers.len()` environments. `policy` holds the policy's actions for them (call
    /// [`Self::observations`] first when images are needed: its images are stored with the steps). Completed
    /// segments are appended to `out`.
    pub fn step(
        &mut self,
        answers: &[ExpertAnswer],
        policy: &[[f32; 2]],
        beta: f64,
        version: u64,
        out: &mut Vec<Segment>,
    ) {
        let active = answers.len().min(policy.len()).min(self.envs.len());
        for i in 0..active {
            let before: Observation = self.envs[i].observation();
            let image = self.images.get(i).cloned();
            let answer = &answers[i];
            let expert_ok = answer.success && answer.action.iter().all(|v| v.is_finite());
            let agent = [policy[i][0] as f64, policy[i][1] as f64];
            let mixed = if expert_ok {
                [
                    beta * answer.action[0] + (1.0 - beta) * agent[0],
                    beta * answer.action[1] + (1.0 - beta) * agent[1],
                ]
            } else {
                agent
            };
            let applied = clip_action(&mixed);
            let result = self.envs[i].step(&applied);
            self.stream_start[i] = false;
            let end = match (result.truncation, result.lap_completed) {
                (Some(t), _) => StepEnd::Truncated(end_reason(t)),
                (None, true) => StepEnd::Lap,
                (None, false) => StepEnd::Continue,
            };
            let step = Step {
                state: f32s(&before.state),
                pose: f32s(&before.pose),
                image,
                expert_action: if expert_ok {
                    f32s(&answer.action)
                } else {
                    [0.0; 2]
                },
                applied_action: f32s(&applied),
                next_state: f32s(&result.obs.state),
                expert_ok,
            };
            self.taken += 1;
            if self.segmenters[i]
                .push(step, end, version, &mut self.seq, out)
                .is_some()
            {
                self.reset(i);
            }
        }
    }

    /// The budget is spent: flush every environment's staged steps as incomplete.
    pub fn end_epoch(&mut self, version: u64, out: &mut Vec<Segment>) {
        for s in &mut self.segmenters {
            s.finish(version, &mut self.seq, out);
        }
    }
}
