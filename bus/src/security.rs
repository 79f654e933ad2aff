//! `[bus.security]` as zenoh 1.10 configuration: TLS (mutual, or server-only with user/password) for every
//! process, and the learner router's access control.
//!
//! Every process is known on the bus by its component (`learner`, `actor/<id>`, `eval/<id>`,
//! `expert-server/<id>`, `observer`): its certificate's common name (files `<certs>/<component>.pem|.key`, made by
//! `deploy/make-certs.sh`) or its user name (password in `<certs>/<component>.password`).
//!
//! The access control lives on the learner, the router of a run. zenoh checks it per remote transport: what a
//! client sends is its *ingress*, what the router forwards to it its *egress*; the learner's own session is local
//! and never checked, so it alone may put `policy` and `control`. Everything else is denied unless a rule below
//! includes the key (zenoh-1.10.2 `src/net/routing/interceptor/{access_control,authorization}.rs`).

use crate::{BusError, Role};
use cabc_proto::config::{SecurityMode, SecuritySection};
use cabc_proto::keys::Keys;
use serde_json::{json, Value};
use std::path::Path;

/// The component name of a role and id: `actor/actor-0`, `eval/eval`, `expert-server/0`.
pub fn component(role: &str, id: &str) -> String {
    format!("{role}/{id}")
}

/// The components the learner knows, with the keys each one may put (besides its liveliness token).
fn principals(keys: &Keys, who: &SecuritySection) -> Vec<(String, Vec<String>)> {
    let own = |c: String, data: Option<String>| {
        let mut puts: Vec<String> = data.into_iter().collect();
        puts.push(keys.metrics(&c));
        (c, puts)
    };
    let actors = who
        .actors
        .iter()
        .map(|id| own(component("actor", id), Some(keys.traj(id))));
    let evaluators = who
        .evaluators
        .iter()
        .map(|id| own(component("eval", id), Some(keys.eval(id))));
    let experts = who
        .expert_servers
        .iter()
        .map(|id| own(component("expert-server", id), None));
    actors.chain(evaluators).chain(experts).collect()
}

fn rule(id: &str, messages: &[&str], flow: &str, key_exprs: &[String]) -> Value {
    json!({"id": id, "messages": messages, "flows": [flow], "permission": "allow", "key_exprs": key_exprs})
}

/// zenoh's `access_control` object for the learner's router: default deny; actors, evaluators (and a learner that
/// is a client) may follow the learner (subscribe to / query `policy`), they and the expert servers hear the stop
/// (`control`); only the learner reads `traj/*` and `eval/*`, and puts the receipts `ack/<id>` that actor `<id>` alone
/// hears; actors ask `expert/*` and alone hear its replies, expert
/// servers answer it; each process puts only its own keys (`traj/<id>` or `eval/<id>`, `metrics/<component>`)
/// and declares only its own `alive/<component>`; the observer reads metrics and liveliness; the `learner` rules
/// serve a learner that is itself a client of a standalone zenohd carrying this object.
pub fn access_control(keys: &Keys, who: &SecuritySection) -> Value {
    let k = |s: String| vec![s];
    let (policy, control) = (keys.policy(), keys.control());
    let expert = keys.expert("*");
    let mut rules = vec![
        rule(
            "sub-policy",
            &["declare_subscriber"],
            "ingress",
            &k(policy.clone()),
        ),
        rule("recv-policy", &["put"], "egress", &k(policy.clone())),
        rule(
            "sub-control",
            &["declare_subscriber"],
            "ingress",
            &k(control.clone()),
        ),
        rule("recv-control", &["put"], "egress", &k(control.clone())),
        rule("query-policy", &["query"], "ingress", &k(policy.clone())),
        rule(
            "recv-policy-reply",
            &["reply"],
            "egress",
            &k(policy.clone()),
        ),
        rule("query-expert", &["query"], "ingress", &k(expert.clone())),
        rule(
            "recv-expert-reply",
            &["reply"],
            "egress",
            &k(expert.clone()),
        ),
        rule(
            "serve-expert",
            &["declare_queryable", "reply"],
            "ingress",
            &k(expert.clone()),
        ),
        rule("recv-expert-query", &["query"], "egress", &k(expert)),
    ];
    let processes = principals(keys, who);
    for (c, puts) in &processes {
        rules.push(rule(&format!("put-{c}"), &["put"], "ingress", puts));
        rules.push(rule(
            &format!("alive-{c}"),
            &["liveliness_token"],
            "ingress",
            &k(keys.alive(c)),
        ));
    }
    // Each actor hears the learner's receipts of its own segments, and no other actor's (`crate::outbox`).
    for id in &who.actors {
        let (c, ack) = (component("actor", id), k(keys.ack(id)));
        rules.push(rule(
            &format!("sub-ack-{c}"),
            &["declare_subscriber"],
            "ingress",
            &ack,
        ));
        rules.push(rule(&format!("recv-ack-{c}"), &["put"], "egress", &ack));
    }
    let (metrics, alive) = (k(keys.metrics("**")), k(keys.alive_all()));
    let liveliness = ["liveliness_query", "declare_liveliness_subscriber"];
    if who.observer {
        rules.extend([
            rule("observe-sub", &["declare_subscriber"], "ingress", &metrics),
            rule("observe-recv", &["put"], "egress", &metrics),
            rule("observe-alive", &liveliness, "ingress", &alive),
            rule(
                "observe-alive-recv",
                &["liveliness_token"],
                "egress",
                &alive,
            ),
        ]);
    }
    let data = vec![keys.traj_all(), keys.eval_all()];
    rules.extend([
        rule(
            "learner-put",
            &["put"],
            "ingress",
            &[
                policy.clone(),
                control,
                keys.metrics("learner"),
                keys.ack_all(),
            ],
        ),
        rule(
            "learner-alive",
            &["liveliness_token"],
            "ingress",
            &k(keys.alive("learner")),
        ),
        rule(
            "learner-serve-policy",
            &["declare_queryable", "reply"],
            "ingress",
            &k(policy.clone()),
        ),
        rule(
            "learner-recv-policy-query",
            &["query"],
            "egress",
            &k(policy),
        ),
        // The learner puts the receipts from a publisher declared per actor (`receipts::Acknowledger`): a router that
        // is not the learner (zenohd, §2) tells it who subscribes to `ack/*`, which the publisher routes by.
        rule(
            "learner-ack-subscribers",
            &["declare_subscriber"],
            "egress",
            &k(keys.ack_all()),
        ),
        rule("learner-sub", &["declare_subscriber"], "ingress", &data),
        rule("learner-recv", &["put"], "egress", &data),
        rule(
            "learner-alive-sub",
            &[liveliness[1], liveliness[0]],
            "ingress",
            &alive,
        ),
        rule(
            "learner-alive-recv",
            &["liveliness_token"],
            "egress",
            &alive,
        ),
    ]);

    let names = match who.mode {
        SecurityMode::Password => "usernames",
        _ => "cert_common_names",
    };
    let subject = |id: &str, members: Vec<String>| json!({"id": id, names: members});
    let actor_names: Vec<String> = who.actors.iter().map(|id| component("actor", id)).collect();
    let expert_names: Vec<String> = who
        .expert_servers
        .iter()
        .map(|id| component("expert-server", id))
        .collect();
    let eval_names: Vec<String> = who
        .evaluators
        .iter()
        .map(|id| component("eval", id))
        .collect();
    let mut subjects = Vec::new();
    let mut policies = Vec::new();
    // Least privilege for reads: the policy goes to actors, evaluators and the learner alone; the stop (`control`)
    // to them and the expert servers; the observer reads metrics and liveliness only.
    let (mut policy_readers, mut control_readers) = (vec!["learner"], vec!["learner"]);
    // zenoh refuses a subject without names, so the group subjects exist only when the group does.
    if !actor_names.is_empty() {
        subjects.push(subject("actors", actor_names));
        policies.push(json!({"id": "actors", "subjects": ["actors"], "rules": ["query-expert", "recv-expert-reply"]}));
        policy_readers.push("actors");
        control_readers.push("actors");
    }
    if !eval_names.is_empty() {
        subjects.push(subject("evaluators", eval_names));
        policy_readers.push("evaluators");
        control_readers.push("evaluators");
    }
    if !expert_names.is_empty() {
        subjects.push(subject("expert-servers", expert_names));
        policies.push(
            json!({"id": "expert-servers", "subjects": ["expert-servers"],
            "rules": ["serve-expert", "recv-expert-query"]}),
        );
        control_readers.push("expert-servers");
    }
    policies.push(json!({"id": "follow-policy", "subjects": policy_readers,
        "rules": ["sub-policy", "recv-policy", "query-policy", "recv-policy-reply"]}));
    policies.push(json!({"id": "follow-control", "subjects": control_readers,
        "rules": ["sub-control", "recv-control"]}));
    for (c, _) in &processes {
        subjects.push(subject(c, vec![c.clone()]));
        let mut own = vec![format!("put-{c}"), format!("alive-{c}")];
        if c.starts_with("actor/") {
            own.extend([format!("sub-ack-{c}"), format!("recv-ack-{c}")]);
        }
        policies.push(json!({"subjects": [c], "rules": own}));
    }
    if who.observer {
        subjects.push(subject("observer", vec!["observer".into()]));
        policies.push(json!({"subjects": ["observer"],
            "rules": ["observe-sub", "observe-recv", "observe-alive", "observe-alive-recv"]}));
    }
    subjects.push(subject("learner", vec!["learner".into()]));
    policies.push(
        json!({"subjects": ["learner"], "rules": ["learner-put", "learner-alive",
        "learner-serve-policy", "learner-recv-policy-query", "learner-sub", "learner-recv", "learner-ack-subscribers",
        "learner-alive-sub", "learner-alive-recv"]}),
    );
    json!({
        "enabled": true,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    })
}

/// The zenoh settings (`insert_json5` key, JSON value) that `[bus.security]` adds to a process's configuration;
/// none in mode "none". The learner (`Role::Listen`) gets the access control too. Reads only the password file
/// of mode "password".
pub fn settings(
    sec: &SecuritySection,
    keys: &Keys,
    role: Role,
    component: &str,
) -> Result<Vec<(&'static str, String)>, BusError> {
    if !sec.enabled() {
        return Ok(Vec::new());
    }
    let certs = Path::new(&sec.certs);
    let file = |name: String| json!(certs.join(name).display().to_string()).to_string();
    let mtls = sec.mode == SecurityMode::Mtls;
    let mut out = vec![
        // Accept and open TLS links only, whatever endpoint is given on a command line.
        ("transport/link/protocols", r#"["tls"]"#.to_string()),
        (
            "transport/link/tls/root_ca_certificate",
            file("ca.pem".into()),
        ),
        ("transport/link/tls/enable_mtls", mtls.to_string()),
        // The host an actor dials must be a SAN of the learner's certificate (make-certs.sh --host).
        ("transport/link/tls/verify_name_on_connect", "true".into()),
        ("transport/link/tls/close_link_on_expiration", "true".into()),
    ];
    if role == Role::Listen {
        out.push((
            "transport/link/tls/listen_certificate",
            file(format!("{component}.pem")),
        ));
        out.push((
            "transport/link/tls/listen_private_key",
            file(format!("{component}.key")),
        ));
    }
    if mtls {
        out.push((
            "transport/link/tls/connect_certificate",
            file(format!("{component}.pem")),
        ));
        out.push((
            "transport/link/tls/connect_private_key",
            file(format!("{component}.key")),
        ));
    } else {
        // A client presents its user and password; a router checks them against the dictionary and needs its
        // own only to dial another router, which a secured run never does (`crate::settings`).
        let path = certs.join(format!("{component}.password"));
        match std::fs::read_to_string(&path) {
            Ok(password) => {
                out.push(("transport/auth/usrpwd/user", json!(component).to_string()));
                out.push((
                    "transport/auth/usrpwd/password",
                    json!(password.trim()).to_string(),
                ));
            }
            Err(_) if role == Role::Listen => {}
            Err(e) => {
                return Err(BusError::Config {
                    key: "bus.security.certs",
                    value: path.display().to_string(),
                    why: format!(
                        "reading this process's password: {e} (deploy/make-certs.sh --passwords makes it)"
                    ),
                })
            }
        }
        if role == Role::Listen {
            out.push((
                "transport/auth/usrpwd/dictionary_file",
                file("passwords".into()),
            ));
        }
    }
    if role == Role::Listen {
        out.push(("access_control", access_control(keys, sec).to_string()));
    }
    Ok(out)
}

#[cfg(test)]
mod tests;
