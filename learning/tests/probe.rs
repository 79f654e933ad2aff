//! `cabc probe` (issue 58): a label that is a readout of the velocities is predicted by the velocities alone and not
//! by the image; a label drawn in the image is predicted by the camera policy and not by the velocities.

use cabc_learning::probe::{probe_rows, ProbeOptions, ProbeReport, Rows};
use cabc_proto::config::RunConfig;
use cabc_proto::messages::image_bytes;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const SIDE: u16 = 16;
const N: usize = 1_000;

fn config() -> RunConfig {
    RunConfig::load("v-a-cpu")
        .unwrap()
        .with_overrides(&[
            format!("observation.width={SIDE}"),
            format!("observation.height={SIDE}"),
        ])
        .unwrap()
}

fn options() -> ProbeOptions {
    ProbeOptions {
        steps: 300,
        block: 20,
        ..ProbeOptions::default()
    }
}

/// `N` rows: velocities and a grey level per row, the steering label from `label(velocity, grey)`.
fn rows(label: impl Fn([f32; 3], f32) -> f32) -> Rows {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let px = image_bytes(SIDE.into(), SIDE.into());
    let mut rows = Rows {
        images: Some((SIDE, SIDE, Vec::with_capacity(N * px))),
        ..Rows::default()
    };
    for _ in 0..N {
        let v = [
            rng.gen_range(0.8..1.2),
            rng.gen_range(-0.2..0.2),
            rng.gen_range(-1.0..1.0),
        ];
        let grey: f32 = rng.gen_range(0.0..1.0);
        rows.states.push([v[0], v[1], v[2], 0.0, 0.0, 0.0]);
        rows.labels.push([0.0, label(v, grey)]);
        if let Some((_, _, bytes)) = &mut rows.images {
            bytes.extend(std::iter::repeat_n((grey * 255.0) as u8, px));
        }
    }
    rows
}

fn share(report: &ProbeReport, predictor: &str) -> f64 {
    report
        .predictors
        .iter()
        .find(|r| r.predictor == predictor)
        .unwrap_or_else(|| panic!("no {predictor} in {}", report.table()))
        .share_of_constant
}

#[test]
fn a_copycat_label_is_read_off_the_velocities() {
    let report = probe_rows(&config(), &rows(|v, _| 0.3 * v[2]), N, &options()).unwrap();
    let table = report.table();
    eprintln!("{table}");
    assert_eq!(report.train_rows + report.held_out_rows, N);
    assert_eq!(report.held_out_rows, N / 5);
    assert!((share(&report, "constant") - 1.0).abs() < 1e-9, "{table}");
    assert!(share(&report, "velocities") < 0.2, "{table}");
    assert!(share(&report, "camera") < 0.5, "{table}");
    assert!(share(&report, "image") > 0.7, "{table}");
}

#[test]
fn a_label_in_the_image_is_not_in_the_velocities() {
    let report = probe_rows(
        &config(),
        &rows(|_, grey| 0.4 * (grey - 0.5)),
        N,
        &options(),
    )
    .unwrap();
    let table = report.table();
    eprintln!("{table}");
    assert!(share(&report, "velocities") > 0.7, "{table}");
    assert!(share(&report, "image") < 0.5, "{table}");
    assert!(share(&report, "camera") < 0.5, "{table}");
}

#[test]
fn too_few_rows_or_bad_options_are_refused() {
    let few = Rows {
        states: vec![[0.0; 6]; 10],
        labels: vec![[0.0; 2]; 10],
        images: None,
    };
    let e = probe_rows(&config(), &few, 10, &options())
        .unwrap_err()
        .to_string();
    assert!(e.contains("at least 100"), "{e}");
    let bad = ProbeOptions {
        steps: 0,
        ..options()
    };
    assert!(probe_rows(&config(), &rows(|_, _| 0.0), N, &bad).is_err());
}
