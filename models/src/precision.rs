//! Mixed precision (`training.precision`): "bf16" runs the forward passes of training under CUDA autocast with
//! bfloat16 (matmuls and convolutions in bf16, the weights, the optimiser and the reductions in fp32; no loss
//! scaling needed, as bf16 has fp32's range). fp32, the default, is the paper's. On the CPU bf16 is not applied.
//!
//! tch 0.24 switches CUDA autocast on and off but always at libtorch's default dtype (fp16), so the dtype is set
//! through libtorch's own `at::autocast::set_autocast_dtype(c10::DeviceType, c10::ScalarType)` (exported by
//! libtorch_cpu; both enums are `int8_t`). Its mangled name is libtorch's ABI: a libtorch without it fails at link
//! time, never at run time.

use cabc_proto::config::Precision;
use tch::Device;

extern "C" {
    #[link_name = "_ZN2at8autocast18set_autocast_dtypeEN3c1010DeviceTypeENS1_10ScalarTypeE"]
    fn at_autocast_set_autocast_dtype(device_type: i8, dtype: i8);
}

/// `c10::DeviceType::CUDA`.
const CUDA: i8 = 1;
/// `c10::ScalarType::BFloat16` (tch's `Kind::BFloat16`).
const BFLOAT16: i8 = 15;

/// Whether `precision` changes anything on `device` (bf16 on CUDA).
pub fn mixed(precision: Precision, device: Device) -> bool {
    precision == Precision::Bf16 && device.is_cuda()
}

/// Runs `f` (a forward pass and its loss) at `precision` on `device`: under bf16 autocast for bf16 on CUDA, as it
/// is otherwise.
pub fn with_precision<T>(precision: Precision, device: Device, f: impl FnOnce() -> T) -> T {
    if !mixed(precision, device) {
        return f();
    }
    // SAFETY: a plain libtorch function of two int8 enums, setting a thread-local dtype; no pointers.
    unsafe { at_autocast_set_autocast_dtype(CUDA, BFLOAT16) };
    tch::autocast(true, f)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;
    use tch::{Kind, Tensor};

    #[test]
    fn on_the_cpu_nothing_changes() {
        assert!(!mixed(Precision::Bf16, Device::Cpu));
        let a = Tensor::ones([4, 4], (Kind::Float, Device::Cpu));
        let y = with_precision(Precision::Bf16, Device::Cpu, || a.matmul(&a));
        assert_eq!(y.kind(), Kind::Float);
    }

    /// On CUDA (skipped without one): a matmul under bf16 comes out in bf16, and outside it in fp32 again.
    #[test]
    fn on_cuda_bf16_autocasts_matmuls() {
        if !tch::Cuda::is_available() {
            // Written past libtest's capture, so that the skip shows in the test run's output.
            let _ = writeln!(
                std::io::stderr(),
                "skipped: no CUDA device (libtorch sees none)"
            );
            return;
        }
        let d = Device::Cuda(0);
        let a = Tensor::ones([64, 64], (Kind::Float, d));
        let y = with_precision(Precision::Bf16, d, || a.matmul(&a));
        assert_eq!(y.kind(), Kind::BFloat16);
        assert_eq!(
            with_precision(Precision::Fp32, d, || a.matmul(&a)).kind(),
            Kind::Float
        );
        assert_eq!(a.matmul(&a).kind(), Kind::Float);
    }
}
