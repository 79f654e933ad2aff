//! Two network namespaces joined by a veth pair (`10.200.0.1/24` in the first, `.2` in the second), for a run
//! whose learner and actors sit on different hosts of a (virtual) network. Needs root and `ip`; both namespaces
//! (and with them the veth pair) are deleted on drop, also when a test fails.

use anyhow::{bail, Context, Result};
use std::process::Command;

/// The first namespace's address (the learner's side).
pub const SERVER_IP: &str = "10.200.0.1";
/// The second namespace's address (the actors' side).
pub const ACTOR_IP: &str = "10.200.0.2";

fn ip(args: &[&str]) -> Result<()> {
    let out = Command::new("ip")
        .args(args)
        .output()
        .context("running ip")?;
    if !out.status.success() {
        bail!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    Ok(())
}

/// A pair of namespaces, deleted on drop.
pub struct NetnsPair {
    /// The learner and expert server's namespace (has [`SERVER_IP`]).
    pub servers: String,
    /// The actors' namespace (has [`ACTOR_IP`]).
    pub actors: String,
    /// The actors' end of the veth pair.
    actors_link: String,
    made: Vec<String>,
}

impl NetnsPair {
    /// Makes the pair; `Err` says why this machine cannot (not root, no `ip`, no namespaces), for a skip.
    pub fn new() -> Result<Self> {
        let tag = std::process::id();
        let mut pair = NetnsPair {
            servers: format!("cabc-{tag}-s"),
            actors: format!("cabc-{tag}-a"),
            actors_link: format!("cv{tag}a"),
            made: Vec::new(),
        };
        for ns in [pair.servers.clone(), pair.actors.clone()] {
            let _ = ip(&["netns", "del", &ns]); // a leftover of a killed run with the same pid
            ip(&["netns", "add", &ns])?;
            pair.made.push(ns.clone());
            ip(&["-n", &ns, "link", "set", "lo", "up"])?;
        }
        // Interface names: at most 15 characters.
        let (vs, va) = (format!("cv{tag}s"), format!("cv{tag}a"));
        ip(&[
            "link",
            "add",
            &vs,
            "netns",
            &pair.servers,
            "type",
            "veth",
            "peer",
            "name",
            &va,
            "netns",
            &pair.actors,
        ])?;
        for (ns, dev, addr) in [
            (&pair.servers, &vs, SERVER_IP),
            (&pair.actors, &va, ACTOR_IP),
        ] {
            ip(&["-n", ns, "addr", "add", &format!("{addr}/24"), "dev", dev])?;
            ip(&["-n", ns, "link", "set", dev, "up"])?;
        }
        Ok(pair)
    }

    /// Cuts the link between the two hosts (the actors' end of the veth pair down), or mends it: no packet passes
    /// while it is down, and the connections over it stay open until their own timeouts (zenoh's lease) end them.
    /// (This kernel has no `netem` qdisc, so the cut is the link's state rather than `tc`'s loss.)
    pub fn set_link(&self, up: bool) -> Result<()> {
        let state = if up { "up" } else { "down" };
        ip(&["-n", &self.actors, "link", "set", &self.actors_link, state])
    }

    /// The wrapper that runs a command in namespace `ns` (for `Cluster::start_in`).
    pub fn exec(ns: &str) -> [&str; 4] {
        ["ip", "netns", "exec", ns]
    }
}

impl Drop for NetnsPair {
    fn drop(&mut self) {
        for ns in &self.made {
            if let Err(e) = ip(&["netns", "del", ns]) {
                eprintln!("cleaning up: {e}");
            }
        }
    }
}
