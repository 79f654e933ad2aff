//! The track keys: `sim.track` and its size, `sim.actor_tracks`, `observation.track_feature`.

use crate::config::*;

#[test]
fn the_track_key_defaults_to_the_l_track_and_refuses_an_unknown_track() {
    // Every preset and a recorded config.toml (written before the key existed) drive the L-track.
    for (name, _) in PRESETS {
        assert_eq!(
            RunConfig::load(name).unwrap().sim.track,
            SimSection::L_TRACK_BARC,
            "{name}"
        );
    }
    let recorded = include_str!("../../../../docs/reproducibility/smoke-6-epochs.toml");
    assert!(!recorded.contains("[sim]"));
    let c = RunConfig::from_toml(recorded, "smoke-6-epochs.toml").unwrap();
    assert_eq!(c.sim, SimSection::default());
    let explicit = RunConfig::from_toml("[sim]\ntrack = \"l-track-barc\"\n", "t.toml").unwrap();
    assert_eq!(explicit, RunConfig::default());
    assert_eq!(explicit.show("sim.track").as_deref(), Some("l-track-barc"));
    let err = RunConfig::from_toml("[sim]\ntrack = \"monza\"\n", "t.toml")
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("t.toml") && err.contains("monza") && err.contains("l-track-barc"),
        "{err}"
    );
    let err = RunConfig::default()
        .with_overrides(&["sim.track_scale=0".into()])
        .unwrap_err()
        .to_string();
    assert!(err.contains("sim.track_scale"), "{err}");
    // A shipped track by name; a file relative to the configuration's folder.
    let oval = RunConfig::default()
        .with_overrides(&["sim.track=oval".into()])
        .unwrap();
    assert_eq!(oval.sim.track, "oval");
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("run.toml"),
        "[sim]\ntrack = \"mine.csv\"\ntrack_scale = 0.5\n",
    )
    .unwrap();
    let c = RunConfig::load(&dir.path().join("run.toml").display().to_string()).unwrap();
    let folder = std::fs::canonicalize(dir.path()).unwrap();
    assert_eq!(c.sim.track, folder.join("mine.csv").display().to_string());
    assert_eq!(c.sim.track_scale, 0.5);
}

#[test]
fn the_curvature_preview_is_a_key_of_the_observation() {
    let c = RunConfig::default();
    assert_eq!(c.observation.track_feature, TrackFeature::S);
    let p = c
        .clone()
        .with_overrides(&["observation.track_feature=curvature-preview".into()])
        .unwrap();
    assert_eq!(p.observation.track_feature, TrackFeature::CurvaturePreview);
    assert!(p
        .to_toml()
        .contains("track_feature = \"curvature-preview\""));
    let e = c
        .clone()
        .with_overrides(&["observation.preview_m=0".into()])
        .unwrap_err()
        .to_string();
    assert!(e.contains("observation.preview_m"), "{e}");
    let e = c
        .with_overrides(&["observation.track_feature=tangent".into()])
        .unwrap_err()
        .to_string();
    assert!(e.contains("curvature-preview"), "{e}");
}

#[test]
fn each_actor_drives_its_own_track_under_actor_tracks() {
    let c = RunConfig::default()
        .with_overrides(&[
            r#"sim.actor_tracks=["oval", "long"]"#.into(),
            "expert.placement=in-actor".into(),
            "sim.track=chicane".into(),
        ])
        .unwrap();
    assert_eq!(c.for_actor(0).sim.track, "oval");
    assert_eq!(c.for_actor(1).sim.track, "long");
    assert_eq!(c.for_actor(2).sim.track, "oval");
    assert_eq!(c.sim.track, "chicane");
    assert_eq!(RunConfig::default().for_actor(1), RunConfig::default());
    // An expert server answers on one track; an unknown name is refused.
    let e = RunConfig::default()
        .with_overrides(&[r#"sim.actor_tracks=["oval"]"#.into()])
        .unwrap_err()
        .to_string();
    assert!(e.contains("in-actor"), "{e}");
    let e = RunConfig::default()
        .with_overrides(&[
            r#"sim.actor_tracks=["monza"]"#.into(),
            "expert.placement=in-actor".into(),
        ])
        .unwrap_err()
        .to_string();
    assert!(e.contains("monza"), "{e}");
}
