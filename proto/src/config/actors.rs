//! `actors.count` as written, a number or `"auto"`, and its resolution to the cores of the machine that reads the
//! configuration (issue 75): the `[actors]` table is read through [`ActorsToml`] into [`ActorsSection`].

use super::ActorsSection;
use serde::Deserialize;

impl ActorsSection {
    /// What `count = "auto"` resolves to on a machine with `cores` cores: the cores, less one for the learner's
    /// training thread when collection overlaps training, between 1 and `auto_max`.
    pub fn auto_count(cores: usize, auto_max: u32, overlap: bool) -> u32 {
        let free = cores.saturating_sub(usize::from(overlap));
        u32::try_from(free)
            .unwrap_or(u32::MAX)
            .clamp(1, auto_max.max(1))
    }

    /// The cores this process may run on (1 when the machine does not say).
    pub fn machine_cores() -> usize {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    }
}

/// `actors.count` as written: a number of actors, or `"auto"`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ActorCount {
    Fixed(u32),
    Auto,
}

impl<'de> Deserialize<'de> for ActorCount {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl serde::de::Visitor<'_> for Visitor {
            type Value = ActorCount;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a number of actors or \"auto\"")
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<ActorCount, E> {
                u32::try_from(v)
                    .map(ActorCount::Fixed)
                    .map_err(|_| E::invalid_value(serde::de::Unexpected::Signed(v), &self))
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<ActorCount, E> {
                u32::try_from(v)
                    .map(ActorCount::Fixed)
                    .map_err(|_| E::invalid_value(serde::de::Unexpected::Unsigned(v), &self))
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<ActorCount, E> {
                match v {
                    "auto" => Ok(ActorCount::Auto),
                    _ => Err(E::invalid_value(serde::de::Unexpected::Str(v), &self)),
                }
            }
        }
        d.deserialize_any(Visitor)
    }
}

/// The `[actors]` table as read: `count` may still be `"auto"`, resolved here as if collection did not overlap
/// training (that key is in another table: [`super::RunConfig::from_toml`] resolves it again when it does).
#[derive(Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(super) struct ActorsToml {
    count: ActorCount,
    auto_max: u32,
    envs_per_actor: u32,
    evaluators: u32,
    eval_line_points: usize,
}

impl Default for ActorsToml {
    fn default() -> Self {
        let d = ActorsSection::default();
        ActorsToml {
            count: ActorCount::Fixed(d.count),
            auto_max: d.auto_max,
            envs_per_actor: d.envs_per_actor,
            evaluators: d.evaluators,
            eval_line_points: d.eval_line_points,
        }
    }
}

impl From<ActorsToml> for ActorsSection {
    fn from(t: ActorsToml) -> Self {
        let count = match t.count {
            ActorCount::Fixed(n) => n,
            ActorCount::Auto => {
                ActorsSection::auto_count(ActorsSection::machine_cores(), t.auto_max, false)
            }
        };
        ActorsSection {
            count,
            auto_max: t.auto_max,
            envs_per_actor: t.envs_per_actor,
            evaluators: t.evaluators,
            eval_line_points: t.eval_line_points,
        }
    }
}
