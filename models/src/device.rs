//! Device selection: the config string `training.device` is "auto" (CUDA when present), "cpu" or "cuda:N".

use crate::ModelError;
use tch::Device;

/// Whether libtorch sees a CUDA device (the build script links libtorch_cuda so that this can be true).
pub fn cuda_available() -> bool {
    tch::Cuda::is_available()
}

/// A device as `training.device` names it: "cpu" or "cuda:N" (what a run's summary says it trained on).
pub fn device_name(device: Device) -> String {
    match device {
        Device::Cpu => "cpu".into(),
        Device::Cuda(i) => format!("cuda:{i}"),
        other => format!("{other:?}").to_lowercase(),
    }
}

/// Parses "auto" | "cpu" | "cuda" | "cuda:N".
pub fn parse_device(spec: &str) -> Result<Device, ModelError> {
    let spec = spec.trim();
    match spec {
        "auto" => Ok(Device::cuda_if_available()),
        "cpu" => Ok(Device::Cpu),
        _ => {
            let index = match spec.strip_prefix("cuda") {
                Some("") => 0,
                Some(rest) => rest
                    .strip_prefix(':')
                    .and_then(|n| n.parse::<usize>().ok())
                    .ok_or_else(|| {
                        ModelError::Device(spec.into(), "expected auto, cpu or cuda:N")
                    })?,
                None => {
                    return Err(ModelError::Device(
                        spec.into(),
                        "expected auto, cpu or cuda:N",
                    ))
                }
            };
            if !cuda_available() {
                return Err(ModelError::Device(spec.into(), "CUDA is not available"));
            }
            if index as i64 >= tch::Cuda::device_count() {
                return Err(ModelError::Device(
                    spec.into(),
                    "no CUDA device with that index",
                ));
            }
            Ok(Device::Cuda(index))
        }
    }
}

/// Flushes subnormal floats to zero in this thread's CPU arithmetic (x86-64's MXCSR flush-to-zero and
/// denormals-are-zero, what PyTorch's `torch.set_flush_denormal(True)` sets). Late in a run the networks' small
/// weights and gradients reach subnormal values, which the CPU handles in microcode: on a V-B checkpoint at epoch 136
/// (`learning/examples/fit_timing.rs`) one pass of the critic took 45.5 s with them and 4.9 s without, the policy's
/// 19.9 s and 2.3 s. Values below 1.2e-38 become 0; GPUs' fast paths flush them too. Set per thread; a no-op on
/// other architectures.
pub fn flush_denormals() {
    #[cfg(target_arch = "x86_64")]
    #[allow(deprecated)]
    // SAFETY: sets two mode bits of this thread's SSE control register; no memory is touched.
    unsafe {
        use std::arch::x86_64::{_mm_getcsr, _mm_setcsr};
        const FTZ_DAZ: u32 = 0x8040;
        _mm_setcsr(_mm_getcsr() | FTZ_DAZ);
    }
}

/// One libtorch thread for this process's CPU work, with subnormals flushed ([`flush_denormals`]): an actor's.
pub fn one_cpu_thread() {
    tch::set_num_threads(1);
    flush_denormals();
}

/// Whether this thread flushes subnormal floats ([`flush_denormals`]).
pub fn flushes_denormals() -> bool {
    #[cfg(target_arch = "x86_64")]
    #[allow(deprecated)]
    // SAFETY: reads this thread's SSE control register.
    unsafe {
        std::arch::x86_64::_mm_getcsr() & 0x8040 == 0x8040
    }
    #[cfg(not(target_arch = "x86_64"))]
    false
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_device_strings() {
        assert_eq!(parse_device("cpu").unwrap(), Device::Cpu);
        assert!(parse_device("gpu").is_err());
        assert!(parse_device("cuda:x").is_err());
        let auto = parse_device("auto").unwrap();
        assert_eq!(auto.is_cuda(), cuda_available());
        if !cuda_available() {
            assert!(matches!(
                parse_device("cuda:0"),
                Err(ModelError::Device(..))
            ));
        }
    }
}

#[cfg(test)]
mod denormal_tests {
    use super::*;

    /// After `flush_denormals` a subnormal operand counts as 0, in Rust's arithmetic and in libtorch's kernels on
    /// this thread (a thread of its own: the bit is per thread).
    #[test]
    #[cfg(target_arch = "x86_64")]
    fn subnormals_are_flushed_on_this_thread() {
        std::thread::spawn(|| {
            let tiny = std::hint::black_box(f32::MIN_POSITIVE / 4.0);
            assert!(!flushes_denormals());
            assert!(
                std::hint::black_box(tiny) * 2.0 > 0.0,
                "subnormals kept by default"
            );
            flush_denormals();
            assert!(flushes_denormals());
            assert_eq!(std::hint::black_box(tiny) * 2.0, 0.0);
            tch::set_num_threads(1);
            let t = tch::Tensor::from_slice(&[tiny; 4]) * 2.0;
            assert_eq!(Vec::<f32>::try_from(&t).unwrap(), vec![0.0; 4]);
        })
        .join()
        .unwrap();
    }
}
