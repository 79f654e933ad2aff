//! The generated access control against the router file verified with zenoh 1.10.2 (`learner-router.json5`
//! here, from the research of issue 13: 24 checks of mTLS + ACL passed against it), compared after both went
//! through zenoh's own typed configuration.

use super::*;
use cabc_proto::config::BusSection;

fn section(mode: SecurityMode, certs: &str) -> SecuritySection {
    SecuritySection {
        mode,
        certs: certs.into(),
        actors: vec!["actor-0".into(), "actor-1".into()],
        ..SecuritySection::default()
    }
}

fn through_zenoh(acl: &Value) -> Value {
    let mut config = zenoh::Config::default();
    config
        .insert_json5("access_control", &acl.to_string())
        .unwrap();
    serde_json::from_str(&config.get_json("access_control").unwrap()).unwrap()
}

#[test]
fn the_access_control_is_the_verified_router_file() {
    let reference = zenoh::Config::from_json5(include_str!("learner-router.json5")).unwrap();
    let reference: Value =
        serde_json::from_str(&reference.get_json("access_control").unwrap()).unwrap();
    let ours = access_control(
        &Keys::new("r").unwrap(),
        &section(SecurityMode::Mtls, "certs"),
    );
    let generated = through_zenoh(&ours);
    for list in ["rules", "subjects", "policies"] {
        let (a, b) = (
            generated[list].as_array().unwrap(),
            reference[list].as_array().unwrap(),
        );
        for (i, (a, b)) in a.iter().zip(b).enumerate() {
            assert_eq!(a, b, "{list}[{i}]");
        }
        assert_eq!(a.len(), b.len(), "{list}");
    }
    assert_eq!(generated, reference);
    // Size: 23 + 2 n + 2 a rules, 5 + n subjects and 6 + n policies for n = 4 processes of which a = 2 actors.
    assert_eq!(ours["rules"].as_array().unwrap().len(), 35);
    assert_eq!(ours["subjects"].as_array().unwrap().len(), 9);
    assert_eq!(ours["policies"].as_array().unwrap().len(), 10);
}

#[test]
fn password_mode_names_users_and_empty_groups_are_left_out() {
    let mut who = section(SecurityMode::Password, "certs");
    who.expert_servers.clear();
    who.observer = false;
    let acl = through_zenoh(&access_control(&Keys::new("r").unwrap(), &who));
    let subjects = acl["subjects"].as_array().unwrap();
    assert!(subjects
        .iter()
        .all(|s| s["id"] != "expert-servers" && s["id"] != "observer"));
    let a0 = subjects
        .iter()
        .find(|s| s["id"] == "actor/actor-0")
        .unwrap();
    assert_eq!(a0["usernames"], json!(["actor/actor-0"]));
    assert!(a0["cert_common_names"].is_null());
}

fn get(config: &zenoh::Config, key: &str) -> String {
    config
        .get_json(key)
        .unwrap_or_else(|e| panic!("{key}: {e}"))
}

fn bus(mode: SecurityMode, certs: &str) -> BusSection {
    BusSection {
        listen: vec!["tls/0.0.0.0:7447".into()],
        connect: vec!["tls/10.0.0.5:7447".into()],
        security: section(mode, certs),
        ..BusSection::default()
    }
}

#[test]
fn mtls_gives_each_process_its_certificate_and_the_learner_the_acl() {
    let keys = Keys::new("r").unwrap();
    let b = bus(SecurityMode::Mtls, "/c");
    let learner = crate::zenoh_config(&b, Role::Listen, &keys, "learner").unwrap();
    assert_eq!(get(&learner, "transport/link/protocols"), r#"["tls"]"#);
    assert_eq!(
        get(&learner, "transport/link/tls/listen_certificate"),
        r#""/c/learner.pem""#
    );
    assert_eq!(get(&learner, "transport/link/tls/enable_mtls"), "true");
    assert_eq!(get(&learner, "access_control/enabled"), "true");
    assert_eq!(
        get(&learner, "access_control/default_permission"),
        r#""deny""#
    );
    let actor = crate::zenoh_config(&b, Role::Connect, &keys, "actor/actor-1").unwrap();
    assert_eq!(
        get(&actor, "transport/link/tls/connect_certificate"),
        r#""/c/actor/actor-1.pem""#
    );
    assert_eq!(
        get(&actor, "transport/link/tls/root_ca_certificate"),
        r#""/c/ca.pem""#
    );
    assert_eq!(get(&actor, "access_control/enabled"), "false");
}

#[test]
fn a_plain_endpoint_is_refused_when_secure() {
    let mut b = bus(SecurityMode::Mtls, "/c");
    b.connect = vec!["tcp/10.0.0.5:7447".into()];
    let keys = Keys::new("r").unwrap();
    let err = crate::zenoh_config(&b, Role::Connect, &keys, "actor/actor-0")
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("tcp/10.0.0.5:7447") && err.contains("tls/"),
        "{err}"
    );
}

#[test]
fn password_mode_reads_the_process_password_and_gives_the_learner_the_dictionary() {
    let dir = std::env::temp_dir().join(format!("cabc-pw-{}", std::process::id()));
    std::fs::create_dir_all(dir.join("actor")).unwrap();
    std::fs::write(dir.join("actor/actor-0.password"), "s3cret\n").unwrap();
    std::fs::write(dir.join("learner.password"), "l\n").unwrap();
    let b = bus(SecurityMode::Password, &dir.display().to_string());
    let keys = Keys::new("r").unwrap();
    let actor = crate::zenoh_config(&b, Role::Connect, &keys, "actor/actor-0").unwrap();
    assert_eq!(get(&actor, "transport/link/tls/enable_mtls"), "false");
    assert_eq!(
        get(&actor, "transport/auth/usrpwd/user"),
        r#""actor/actor-0""#
    );
    let learner = crate::zenoh_config(&b, Role::Listen, &keys, "learner").unwrap();
    let dictionary = get(&learner, "transport/auth/usrpwd/dictionary_file");
    assert!(dictionary.ends_with("passwords\""), "{dictionary}");
    let err = crate::zenoh_config(&b, Role::Connect, &keys, "actor/actor-9")
        .unwrap_err()
        .to_string();
    assert!(err.contains("actor-9.password"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}
