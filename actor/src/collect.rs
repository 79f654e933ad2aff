//! Collection: K environments stepped in lockstep under the expert/policy mixture of Algorithm 1, zenoh-free.
//!
//! The driver (the actor binary, or a test in-process) calls [`Collector::begin_epoch`], then [`Collector::collect`],
//! which repeats [`Collector::queries`] → send them to the expert → [`Collector::observations`] → run the policy →
//! receive the answers → [`Collector::step`] for two halves of the environments in alternation (one half's round trip
//! overlaps the other half's work), publishing the segments each step completes, until the epoch's budget is spent;
//! then [`Collector::end_epoch`].
//! With `collection.episodes = "carry"` (the default) an episode goes on across epoch boundaries: what is staged at
//! the end of an epoch stays staged, and its lap or failure is cut in a later epoch (with that epoch's version).
//! With `"reset"` every epoch starts new episodes and flushes what is staged as incomplete, as the reference does.
//! The applied action is `beta * expert + (1 - beta) * policy` when the expert solved its problem, else the
//! policy's action (as the reference does); the stored label is always the expert's action.

use crate::dart::ActionNoise;
use crate::eyes::Eyes;
use crate::segment::{Segmenter, SeqCounter, StepEnd};
use crate::sensor::Sensor;
use crate::shield::{Shield, ShieldConfig};
use cabc_proto::config::{Episodes, ObservationKind, RunConfig, Spawn, StoredAction};
use cabc_proto::messages::{
    EndReason, ExpertAnswer, ExpertQuery, Image, Segment, ShieldNets, Step, StreamId,
};
use cabc_proto::ports::{CollectionTimes, ExpertClient, Next, Pending, PortError};
use cabc_sim::env::{Env, EnvBatch, EnvConfig, EnvObservation, Truncation};
use cabc_sim::track::{Track, TrackError};
use cabc_sim::vehicle::{clip_action, Input, VehicleParams};
use std::collections::VecDeque;
use std::ops::Range;
use std::time::Instant;

/// What the policy sees for a batch of environments.
pub struct Observations<'a> {
    /// Full states [v_long, v_tran, omega, s, x_tran, e_psi].
    pub states: &'a [[f32; 6]],
    /// Camera images, one per state, when the run observes images (else empty).
    pub images: &'a [Image],
}

/// Maps the simulator's truncation to the protocol's end reason.
pub fn end_reason(t: Truncation) -> EndReason {
    t.into()
}

/// The env constants of a run: the simulator's, with `max_laps` laps at most and the run's observed track feature.
fn env_config(config: &RunConfig, max_laps: u32) -> EnvConfig {
    EnvConfig {
        max_laps,
        track_feature: config.observation.track_feature,
        preview_m: config.observation.preview_m,
        ..EnvConfig::default()
    }
}

/// The environment of a run: its track (`sim.track`), the reference vehicle and env constants, `max_laps` laps at
/// most.
pub fn make_env(config: &RunConfig, max_laps: u32) -> Result<Env, TrackError> {
    Ok(Env::new(
        Track::of(&config.sim)?,
        VehicleParams::default(),
        env_config(config, max_laps),
    ))
}

/// Mixed into the run seed for the sensors' random streams.
pub(crate) const SENSOR_SEED: u64 = 0x5e_4503;

fn f32s<const N: usize>(x: &[f64; N]) -> [f32; N] {
    x.map(|v| v as f32)
}

/// One actor's K environments.
pub struct Collector {
    actor: String,
    envs: EnvBatch,
    segmenters: Vec<Segmenter>,
    stream_start: Vec<bool>,
    seq: SeqCounter,
    spawn: Spawn,
    episodes: Episodes,
    /// Whether the environments have started their first episodes.
    started: bool,
    eyes: Option<Eyes>,
    /// The noise n_k on what the policy sees (none by default).
    sensor: Sensor,
    states: Vec<[f32; 6]>,
    /// The images of the last [`Collector::observations`], moved into the steps by [`Collector::step`].
    images: Vec<Image>,
    /// Reused per step: the observations before it, the applied actions and the actions stored for f_hat.
    before: Vec<EnvObservation>,
    applied: Vec<Input>,
    stored: Vec<Input>,
    stored_action: StoredAction,
    /// The noise injected into the applied action (`collection.action_noise_std`), from its own random stream.
    action_noise: ActionNoise,
    /// Steps taken in the current epoch.
    taken: u64,
    /// Steps taken since the collector began, told to `tally` after each batch ([`Collector::with_tally`]).
    taken_total: u64,
    tally: Option<Box<dyn FnMut(u64) + Send>>,
    /// `collection.shield`: its settings, the current version's networks, and the steps it gave the expert this epoch.
    shield_config: ShieldConfig,
    shield: Option<Shield>,
    shielded: u64,
    /// Where this epoch's wall clock went ([`Collector::times`]).
    times: CollectionTimes,
}

impl Collector {
    /// `index` makes each actor's random streams distinct (actor k uses streams k*K .. k*K+K-1 of the run seed).
    /// An error when the run's track (`sim.track`) cannot be built.
    pub fn new(actor: &str, index: u64, config: &RunConfig) -> Result<Self, TrackError> {
        let k = config.actors.envs_per_actor as usize;
        let envs = EnvBatch::with_streams(
            Track::of(&config.sim)?,
            VehicleParams::default(),
            env_config(config, config.collection.max_laps),
            config.run.seed,
            index * k as u64..(index + 1) * k as u64,
        );
        let c = &config.collection;
        let segmenters = (0..k)
            .map(|i| {
                Segmenter::new(actor, i as u32, config.expert.patience)
                    .with_rules(c.flush, c.expert_failure_staged)
            })
            .collect();
        let eyes = (config.observation.kind == ObservationKind::Camera)
            .then(|| Eyes::new(config))
            .transpose()?;
        Ok(Collector {
            actor: actor.to_string(),
            envs,
            segmenters,
            stream_start: vec![true; k],
            seq: SeqCounter::default(),
            spawn: config.collection.spawn,
            episodes: config.collection.episodes,
            started: false,
            eyes,
            // Its own stream, after the environments' (actor k's envs use streams k*K .. k*K+K-1).
            sensor: Sensor::new(
                &config.observation,
                Env::rng(config.run.seed ^ SENSOR_SEED, index),
            ),
            states: Vec::with_capacity(k),
            images: Vec::with_capacity(k),
            before: Vec::with_capacity(k),
            applied: Vec::with_capacity(k),
            stored: Vec::with_capacity(k),
            stored_action: config.collection.stored_action,
            action_noise: ActionNoise::new(
                config.collection.action_noise_std,
                config.run.seed,
                index,
                k,
            ),
            taken: 0,
            taken_total: 0,
            tally: None,
            shield_config: ShieldConfig::of(config),
            shield: None,
            shielded: 0,
            times: CollectionTimes::default(),
        })
    }

    /// The shield of the version about to be collected ([`crate::shield`]): none when the run has none or `nets` is
    /// None; networks that do not load (another size, malformed) are refused, logged, and the version collected
    /// without a shield.
    pub fn arm_shield(&mut self, nets: Option<&ShieldNets>) {
        self.shield = self.shield_config.shield(nets).unwrap_or_else(|e| {
            tracing::error!("refusing the shield's networks: {e}");
            None
        });
    }

    /// Steps of this epoch the shield gave the expert.
    pub fn shielded(&self) -> u64 {
        self.shielded
    }

    /// Where this epoch's collection spent its wall clock: observing, the policy, the expert, the steps and the
    /// segments' store (the evaluation is not the collector's: 0).
    pub fn times(&self) -> CollectionTimes {
        self.times
    }

    /// Sets the incarnation every segment carries (the `actor` binary: the time it started; in-process actors: the
    /// policy version they start with, 0 for a fresh run), so that the learner tells a restarted actor's segments
    /// from duplicates.
    pub fn with_incarnation(mut self, incarnation: u64) -> Self {
        self.set_incarnation(incarnation);
        self
    }

    /// Tells `tally` the steps taken since the collector began after each batch of steps, before any segment of the
    /// batch is published (the actor's journal: what a process killed took and never published).
    pub fn with_tally(mut self, tally: impl FnMut(u64) + Send + 'static) -> Self {
        self.tally = Some(Box::new(tally));
        self
    }

    /// [`Collector::with_incarnation`] in place, before the first step.
    pub fn set_incarnation(&mut self, incarnation: u64) {
        self.seq.incarnation = incarnation;
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
        self.seq.next
    }

    /// Steps taken in this epoch.
    pub fn taken(&self) -> u64 {
        self.taken
    }

    /// Steps staged in all environments (taken, not yet in a segment).
    pub fn staged(&self) -> u64 {
        self.segmenters.iter().map(|s| s.staged() as u64).sum()
    }

    /// Starts an epoch. The first epoch starts every environment's episode; later ones go on with them, unless
    /// episodes are reset at each epoch (the reference).
    pub fn begin_epoch(&mut self) {
        self.taken = 0;
        self.shielded = 0;
        self.times = CollectionTimes::default();
        if !self.started || self.episodes == Episodes::Reset {
            for i in 0..self.envs.len() {
                self.reset(i);
            }
            self.started = true;
        }
    }

    fn reset(&mut self, i: usize) {
        self.envs
            .reset_one(i, self.spawn)
            .expect("i indexes the batch");
        self.stream_start[i] = true;
    }

    /// The halves of the environments that alternate in [`Collector::collect`] (one half of one environment).
    pub fn halves(&self) -> Vec<Range<usize>> {
        let k = self.envs.len();
        if k < 2 {
            std::iter::once(0..k).collect()
        } else {
            vec![0..k / 2, k / 2..k]
        }
    }

    /// The expert queries of the next step of environments `envs`.
    pub fn queries(&self, envs: Range<usize>) -> Vec<ExpertQuery> {
        let first = envs.start;
        self.envs.envs()[envs]
            .iter()
            .enumerate()
            .map(|(i, env)| (first + i, env))
            .map(|(i, env)| ExpertQuery {
                stream: StreamId {
                    actor: self.actor.clone(),
                    env: i as u32,
                    episode: self.segmenters[i].episode(),
                },
                start: self.stream_start[i],
                vehicle: env.vehicle_state(),
                frenet: env.observation().state,
            })
            .collect()
    }

    /// Observations of environments `envs` (images rendered when the run observes images), with the sensor's noise.
    pub fn observations(&mut self, envs: Range<usize>) -> Observations<'_> {
        self.states.clear();
        self.images.clear();
        for env in &self.envs.envs()[envs] {
            self.states
                .push(self.sensor.state(f32s(&env.observation().state)));
            if let Some(eyes) = &mut self.eyes {
                self.images.push(self.sensor.image(eyes.see(env)));
            }
        }
        Observations {
            states: &self.states,
            images: &self.images,
        }
    }

    /// Steps `answers.len()` environments from `first` on. `policy` holds the policy's actions for them (call
    /// [`Self::observations`] of the same environments first when images are needed: its images move into the steps,
    /// so each is stored once). Completed segments are appended to `out`.
    pub fn step(
        &mut self,
        first: usize,
        answers: &[ExpertAnswer],
        policy: &[[f32; 2]],
        beta: f64,
        version: u64,
        out: &mut Vec<Segment>,
    ) {
        let first = first.min(self.envs.len());
        let active = answers.len().min(policy.len()).min(self.envs.len() - first);
        let answers = &answers[..active];
        // Whether the expert solved each environment's problem: once per step, for the mixture, the shield and the
        // stored label.
        let solved: Vec<bool> = answers.iter().map(expert_ok).collect();
        self.mix(first, answers, &solved, policy, beta);
        self.shield_overrules(answers, &solved);
        let before = self.taken;
        self.advance(first, answers, &solved, version, out);
        self.taken_total += self.taken - before;
        if let Some(tally) = &mut self.tally {
            tally(self.taken_total);
        }
    }

    /// pi_collect's actions for environments `first..first + answers.len()`: the mixture of the expert's and the
    /// policy's (the policy's alone where the expert failed) with the action noise, clipped to the box where applied
    /// and stored as `collection.stored_action` says; and the observations they act on.
    fn mix(
        &mut self,
        first: usize,
        answers: &[ExpertAnswer],
        solved: &[bool],
        policy: &[[f32; 2]],
        beta: f64,
    ) {
        self.before.clear();
        self.applied.clear();
        self.stored.clear();
        for (j, env) in self.envs.envs()[first..first + answers.len()]
            .iter()
            .enumerate()
        {
            self.before.push(env.observation());
            let mixed = self.action_noise.add(
                first + j,
                mixed_action(&answers[j], solved[j], &policy[j], beta),
            );
            self.applied.push(clip_action(&mixed));
            self.stored.push(match self.stored_action {
                StoredAction::Clipped => clip_action(&mixed),
                StoredAction::Unclipped => mixed,
            });
        }
    }

    /// `collection.shield`: where it overrules the mixture's action and the expert solved its problem, the expert's
    /// action is applied and stored instead (counted in [`Collector::shielded`]).
    fn shield_overrules(&mut self, answers: &[ExpertAnswer], solved: &[bool]) {
        let Some(shield) = &self.shield else {
            return;
        };
        let states: Vec<[f32; 6]> = self.before.iter().map(|o| f32s(&o.state)).collect();
        for (j, overrule) in shield
            .overrules(&states, &self.applied)
            .into_iter()
            .enumerate()
        {
            if overrule && solved[j] {
                self.applied[j] = clip_action(&answers[j].action);
                self.stored[j] = match self.stored_action {
                    StoredAction::Clipped => self.applied[j],
                    StoredAction::Unclipped => answers[j].action,
                };
                self.shielded += 1;
            }
        }
    }

    /// The plant's step with the applied actions; each step (its image, the expert's label where it solved, the
    /// stored action) goes to its environment's segmenter, which appends the segments it completes to `out`. An
    /// environment whose episode ended starts the next.
    fn advance(
        &mut self,
        first: usize,
        answers: &[ExpertAnswer],
        solved: &[bool],
        version: u64,
        out: &mut Vec<Segment>,
    ) {
        let results = self
            .envs
            .step_from(first, &self.applied)
            .expect("at most one action per env");
        let mut images = self.images.drain(..);
        let mut ended = Vec::new();
        for (j, result) in results.iter().enumerate() {
            let (i, answer) = (first + j, &answers[j]);
            let expert_ok = solved[j];
            self.stream_start[i] = false;
            let end = match (result.truncation, result.lap_completed) {
                (Some(t), _) => StepEnd::Truncated(end_reason(t)),
                (None, true) => StepEnd::Lap,
                (None, false) => StepEnd::Continue,
            };
            let step = Step {
                state: f32s(&self.before[j].state),
                pose: f32s(&self.before[j].pose),
                image: images.next(),
                expert_action: if expert_ok {
                    f32s(&answer.action)
                } else {
                    [0.0; 2]
                },
                applied_action: f32s(&self.stored[j]),
                next_state: f32s(&result.obs.state),
                expert_ok,
            };
            self.taken += 1;
            if self.segmenters[i]
                .push(step, end, version, &mut self.seq, out)
                .is_some()
            {
                ended.push(i);
            }
        }
        drop(images);
        for i in ended {
            self.reset(i);
        }
    }

    /// Steps until `budget` steps are taken in this epoch, with the environments in two halves that alternate: a
    /// half's next relabelling is sent as soon as it has stepped, and travels (and is solved) while the other half
    /// observes, runs the policy, steps and publishes, so the expert's round trip overlaps with the actor's work.
    /// Every environment still steps with its own answer and the policy's action for its own observation, the
    /// sensor draws in the order of a whole-batch step, and the budget goes to the environments in the same order,
    /// so with a batch-invariant policy the data is what whole-batch steps give (`actor/tests/collect.rs`,
    /// `tests/tests/halves.rs`).
    ///
    /// `policy` maps observations to actions; `between` runs before the first step and after each half-step with the
    /// segments cut so far (to publish them), and returns a newer version or a stop to end the epoch early. A stop
    /// while waiting on the expert ends it too.
    pub fn collect<E: From<PortError>>(
        &mut self,
        budget: u64,
        beta: f64,
        version: u64,
        expert: &mut dyn ExpertClient,
        policy: impl FnMut(&Observations) -> Result<Vec<[f32; 2]>, E>,
        between: impl FnMut(&mut Vec<Segment>) -> Result<Option<Next>, E>,
    ) -> Result<Option<Next>, E> {
        let mut queue = VecDeque::new();
        let ended = self.pipeline(&mut queue, budget, beta, version, expert, policy, between);
        for (_, _, pending) in queue {
            expert.cancel(pending);
        }
        match ended {
            Ok(next) => Ok(next),
            Err(Halt::Stopped(reason)) => Ok(Some(Next::Stop(reason))),
            Err(Halt::Failed(e)) => Err(e),
        }
    }

    /// [`Collector::collect`]'s loop; what is still in `queue` when it returns is the caller's to cancel.
    #[allow(clippy::too_many_arguments)]
    fn pipeline<E: From<PortError>>(
        &mut self,
        queue: &mut VecDeque<(usize, Range<usize>, Pending)>,
        budget: u64,
        beta: f64,
        version: u64,
        expert: &mut dyn ExpertClient,
        mut policy: impl FnMut(&Observations) -> Result<Vec<[f32; 2]>, E>,
        mut between: impl FnMut(&mut Vec<Segment>) -> Result<Option<Next>, E>,
    ) -> Result<Option<Next>, Halt<E>> {
        let mut out = Vec::new();
        if let Some(next) = between(&mut out).map_err(Halt::Failed)? {
            return Ok(Some(next));
        }
        let halves = self.halves();
        let mut reserved = 0u64;
        let mut clock = Instant::now();
        for (h, half) in halves.iter().enumerate() {
            if let Some((envs, pending)) = self.send(half, budget, &mut reserved, expert)? {
                queue.push_back((h, envs, pending));
            }
        }
        lap(&mut clock, &mut self.times.expert_s);
        while let Some((h, envs, pending)) = queue.pop_front() {
            let observations = self.observations(envs.clone());
            let observed = Instant::now();
            let actions = policy(&observations).map_err(Halt::Failed)?;
            self.times.observe_s += (observed - clock).as_secs_f64();
            clock = observed;
            lap(&mut clock, &mut self.times.policy_s);
            let answers = expert.receive(pending)?;
            lap(&mut clock, &mut self.times.expert_s);
            reserved -= envs.len() as u64;
            self.step(envs.start, &answers, &actions, beta, version, &mut out);
            lap(&mut clock, &mut self.times.step_s);
            if let Some((envs, pending)) = self.send(&halves[h], budget, &mut reserved, expert)? {
                queue.push_back((h, envs, pending));
            }
            lap(&mut clock, &mut self.times.expert_s);
            if let Some(next) = between(&mut out).map_err(Halt::Failed)? {
                return Ok(Some(next));
            }
            lap(&mut clock, &mut self.times.store_s);
        }
        Ok(None)
    }

    /// Sends the relabelling of the next step of `half`: of as many of its environments as the budget has left,
    /// counting the steps already `reserved` by relabellings on their way. None when the budget is spent.
    fn send(
        &self,
        half: &Range<usize>,
        budget: u64,
        reserved: &mut u64,
        expert: &mut dyn ExpertClient,
    ) -> Result<Option<(Range<usize>, Pending)>, PortError> {
        let left = budget.saturating_sub(self.taken + *reserved);
        let n = (half.len() as u64).min(left) as usize;
        if n == 0 {
            return Ok(None);
        }
        let envs = half.start..half.start + n;
        let pending = expert.send(self.queries(envs.clone()))?;
        *reserved += n as u64;
        Ok(Some((envs, pending)))
    }

    /// The budget is spent. Episodes reset at each epoch: every environment's staged steps are flushed as
    /// incomplete. Episodes carried: they stay staged for the next epoch.
    pub fn end_epoch(&mut self, version: u64, out: &mut Vec<Segment>) {
        if self.episodes == Episodes::Reset {
            for s in &mut self.segmenters {
                s.finish(version, &mut self.seq, out);
            }
        }
    }
}

/// Adds the seconds since `clock` to `phase` and restarts `clock`.
fn lap(clock: &mut Instant, phase: &mut f64) {
    let now = Instant::now();
    *phase += (now - *clock).as_secs_f64();
    *clock = now;
}

/// Why [`Collector::collect`]'s loop ended early: a stop while talking to the expert, or the caller's error.
enum Halt<E> {
    Stopped(String),
    Failed(E),
}

impl<E: From<PortError>> From<PortError> for Halt<E> {
    fn from(e: PortError) -> Self {
        match e {
            PortError::Stopped(reason) => Halt::Stopped(reason),
            e => Halt::Failed(e.into()),
        }
    }
}

fn expert_ok(answer: &ExpertAnswer) -> bool {
    answer.success && answer.action.iter().all(|v| v.is_finite())
}

/// The beta mixture of the expert's and the policy's actions when the expert `solved` its problem, else the policy's
/// action; not clipped (the plant receives it clipped to the action box, [`clip_action`]).
fn mixed_action(answer: &ExpertAnswer, solved: bool, policy: &[f32; 2], beta: f64) -> Input {
    let agent = [policy[0] as f64, policy[1] as f64];
    if solved {
        [
            beta * answer.action[0] + (1.0 - beta) * agent[0],
            beta * answer.action[1] + (1.0 - beta) * agent[1],
        ]
    } else {
        agent
    }
}
