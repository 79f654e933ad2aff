//! Fuzzing the weights parser in the normal test run (issue 13, item 4): mutations of valid safetensors bytes (the
//! 8-byte header length, the JSON header, the data; truncated, extended) and crafted headers (huge or negative
//! shapes, wrong dtypes, offsets past the end, foreign or oversized architecture names) through
//! `Policy::from_bytes`, `PolicyCheck::check` and `PolicyCheck::policy`. Every case must return a value or a
//! `ModelError`, never panic, in bounded time. The counts go to stderr, past the harness's capture.

use cabc_models::{Network, Policy, PolicyArch, PolicyCheck};
use cabc_proto::config::MlpSize;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use std::io::Write;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::time::{Duration, Instant};
use tch::Device;

fn arch() -> PolicyArch {
    PolicyArch::State {
        mlp: MlpSize {
            layers: 2,
            width: 8,
        },
    }
}

/// safetensors bytes from a header (JSON text) and data.
fn safetensors(header: &str, data: &[u8]) -> Vec<u8> {
    let mut out = (header.len() as u64).to_le_bytes().to_vec();
    out.extend_from_slice(header.as_bytes());
    out.extend_from_slice(data);
    out
}

/// Headers a hostile sender might write.
fn crafted(rng: &mut StdRng, name: &str) -> Vec<u8> {
    let meta = format!(r#""__metadata__":{{"architecture":"{name}"}}"#);
    let dims = [
        "[8,6]".to_string(),
        "[-8,-6]".into(),
        "[4611686018427387904,4]".into(),
        "[9223372036854775807,9223372036854775807]".into(),
        "[0]".into(),
        "[]".into(),
        format!("[{}]", rng.gen::<i64>()),
        "\"eight\"".into(),
    ];
    let dtypes = ["F32", "F16", "I64", "BOOL", "", "f32"];
    let offsets = [
        "[0,192]".to_string(),
        "[192,0]".into(),
        "[0,18446744073709551615]".into(),
        "[18446744073709551615,18446744073709551615]".into(),
        format!("[{},{}]", rng.gen::<u64>() % 400, rng.gen::<u64>() % 400),
        "[0]".into(),
        "null".into(),
    ];
    let tensor = |rng: &mut StdRng| {
        format!(
            r#""mlp.0.weight":{{"dtype":"{}","shape":{},"data_offsets":{}}}"#,
            dtypes[rng.gen_range(0..dtypes.len())],
            dims[rng.gen_range(0..dims.len())],
            offsets[rng.gen_range(0..offsets.len())]
        )
    };
    let header = match rng.gen_range(0..4) {
        0 => format!("{{{meta},{}}}", tensor(rng)),
        1 => format!("{{{},{meta},{}}}", tensor(rng), tensor(rng)),
        2 => format!("{{{}}}", tensor(rng)),
        _ => format!("[{meta}]"),
    };
    let data: Vec<u8> = (0..rng.gen_range(0..400))
        .map(|_| rng.gen::<u8>())
        .collect();
    let mut bytes = safetensors(&header, &data);
    if rng.gen_range(0..8) == 0 {
        // A header length past the end, or near u64::MAX.
        let n = [u64::MAX, u64::MAX - 7, bytes.len() as u64, 1 << 40][rng.gen_range(0..4)];
        bytes[..8].copy_from_slice(&n.to_le_bytes());
    }
    bytes
}

/// One mutation of valid weights.
fn mutate(good: &[u8], rng: &mut StdRng) -> Vec<u8> {
    let mut b = good.to_vec();
    let header_end = 8 + u64::from_le_bytes(good[..8].try_into().unwrap()) as usize;
    for _ in 0..1 + rng.gen_range(0..3) {
        let len = b.len();
        match rng.gen_range(0..7) {
            // The header length.
            0 if len >= 8 => {
                let i = rng.gen_range(0..8);
                b[i] = rng.gen::<u8>();
            }
            // A byte of the JSON header (names, shapes, offsets, dtype, metadata).
            1 | 2 if header_end <= len => {
                let i = 8 + rng.gen_range(0..header_end - 8);
                b[i] = if rng.gen_range(0..2) == 0 {
                    rng.gen::<u8>()
                } else {
                    b"0123456789-[]{}\",:.eE"[rng.gen_range(0..21)]
                };
            }
            // A byte of the data (NaN and garbage are numbers to the parser).
            3 if len > 0 => {
                let i = rng.gen_range(0..len);
                b[i] = rng.gen::<u8>();
            }
            4 => b.truncate(rng.gen_range(0..len + 1)),
            5 => (0..1 + rng.gen_range(0..64)).for_each(|_| b.push(rng.gen::<u8>())),
            _ if len > 9 => {
                let a = 8 + rng.gen_range(0..len - 8);
                let e = (a + 1 + rng.gen_range(0..16)).min(len);
                b.drain(a..e);
            }
            _ => b.push(rng.gen::<u8>()),
        }
    }
    b
}

fn report(target: &str, cases: usize, panics: usize, accepted: usize, took: Duration) {
    let _ = writeln!(
        std::io::stderr(),
        "fuzz {target}: {cases} cases, {panics} panics ({accepted} accepted), {:.2} s",
        took.as_secs_f64()
    );
}

/// Runs the three entry points on `bytes`: whether any panicked, whether the check accepted them.
fn run_all(check: &PolicyCheck, name: &str, bytes: &[u8]) -> (bool, bool) {
    let result = catch_unwind(AssertUnwindSafe(|| {
        let _ = Policy::from_bytes(bytes, Device::Cpu);
        let checked = check.check(name, bytes).is_ok();
        let built = check.policy(name, bytes, Device::Cpu).is_ok();
        assert_eq!(checked, built, "check and build disagree");
        checked
    }));
    match result {
        Ok(accepted) => (false, accepted),
        Err(_) => (true, false),
    }
}

const MUTATIONS: usize = 30_000;
const CRAFTED: usize = 20_000;

#[test]
fn mutated_weights_never_panic() {
    let check = PolicyCheck::new(arch());
    let name = arch().to_string();
    let good = Policy::new(arch(), Device::Cpu, 5).to_bytes();
    assert_eq!(run_all(&check, &name, &good), (false, true));
    let mut rng = StdRng::seed_from_u64(0x00c0_ffee_0013_5afe);
    let started = Instant::now();
    let (mut panics, mut accepted) = (0, 0);
    for _ in 0..MUTATIONS {
        let bytes = mutate(&good, &mut rng);
        let (panicked, ok) = run_all(&check, &name, &bytes);
        panics += panicked as usize;
        accepted += ok as usize;
    }
    report(
        "weights (Policy::from_bytes, PolicyCheck) mutations",
        MUTATIONS,
        panics,
        accepted,
        started.elapsed(),
    );
    assert_eq!(panics, 0);
    assert!(started.elapsed() < Duration::from_secs(20));
}

#[test]
fn crafted_headers_never_panic_or_allocate_their_declared_size() {
    let check = PolicyCheck::new(arch());
    let name = arch().to_string();
    let names = [
        name.clone(),
        "policy-state-mlp-5x8".to_string(),
        "policy-state-mlp-4x4096".into(),
        "policy-state-mlp-3x18446744073709551615".into(),
        "policy-camera-resnet18-mlp-2x8".into(),
        "policy-camera-small-cnn-mlp-0x1".into(),
        "critic-mlp-2x8".into(),
        String::new(),
    ];
    let mut rng = StdRng::seed_from_u64(0x0bad_cafe_0013);
    let started = Instant::now();
    let (mut panics, mut accepted) = (0, 0);
    for i in 0..CRAFTED {
        let bytes = crafted(&mut rng, &names[i % names.len()]);
        let (panicked, ok) = run_all(&check, &name, &bytes);
        panics += panicked as usize;
        accepted += ok as usize;
    }
    report(
        "weights (Policy::from_bytes, PolicyCheck) crafted headers",
        CRAFTED,
        panics,
        accepted,
        started.elapsed(),
    );
    assert_eq!(panics, 0);
    assert_eq!(accepted, 0);
    assert!(started.elapsed() < Duration::from_secs(20));
}
