//! Mixed precision (`training.precision`): "bf16" runs the forward passes of training under CUDA autocast with
//! bfloat16 (matmuls and convolutions in bf16, the weights, the optimiser and the reductions in fp32; no loss
//! scaling needed, as bf16 has fp32's range). fp32, the default, is the paper's. On the CPU bf16 is not applied.
//!
//! tch 0.24's `tch::autocast` switches autocast at libtorch's default dtype (fp16), through `at::autocast::is_enabled`
//! and `set_enabled`, which libtorch 2.11 deprecates with a warning printed at every call: thousands of lines a
//! second on the GPU (seen in the first CUDA run, docs/gpu/). So the scope is libtorch's own, called by its exported
//! names: `set_autocast_dtype(c10::DeviceType, c10::ScalarType)`, `is_autocast_enabled(c10::DeviceType)`,
//! `set_autocast_enabled(c10::DeviceType, bool)`, `increment_nesting()`, `decrement_nesting()` and `clear_cache()`
//! (both enums are `int8_t`), the sequence `tch::autocast` runs. Their mangled names are libtorch's ABI: a libtorch
//! without them fails at link time, never at run time.

use cabc_proto::config::Precision;
use tch::Device;

extern "C" {
    #[link_name = "_ZN2at8autocast18set_autocast_dtypeEN3c1010DeviceTypeENS1_10ScalarTypeE"]
    fn at_autocast_set_autocast_dtype(device_type: i8, dtype: i8);
    #[link_name = "_ZN2at8autocast19is_autocast_enabledEN3c1010DeviceTypeE"]
    fn at_autocast_is_autocast_enabled(device_type: i8) -> bool;
    #[link_name = "_ZN2at8autocast20set_autocast_enabledEN3c1010DeviceTypeEb"]
    fn at_autocast_set_autocast_enabled(device_type: i8, enabled: bool);
    #[link_name = "_ZN2at8autocast17increment_nestingEv"]
    fn at_autocast_increment_nesting() -> std::ffi::c_int;
    #[link_name = "_ZN2at8autocast17decrement_nestingEv"]
    fn at_autocast_decrement_nesting() -> std::ffi::c_int;
    #[link_name = "_ZN2at8autocast11clear_cacheEv"]
    fn at_autocast_clear_cache();
}

/// `c10::DeviceType::CUDA`.
const CUDA: i8 = 1;
/// `c10::ScalarType::BFloat16` (tch's `Kind::BFloat16`).
const BFLOAT16: i8 = 15;

/// Whether `precision` changes anything on `device` (bf16 on CUDA).
pub fn mixed(precision: Precision, device: Device) -> bool {
    precision == Precision::Bf16 && device.is_cuda()
}

/// The precision `precision` trains at on `device`: bf16 on CUDA alone, fp32 elsewhere.
pub fn effective(precision: Precision, device: Device) -> Precision {
    if mixed(precision, device) {
        Precision::Bf16
    } else {
        Precision::Fp32
    }
}

/// Runs `f` (a forward pass and its loss) at `precision` on `device`: under bf16 autocast for bf16 on CUDA, as it
/// is otherwise.
pub fn with_precision<T>(precision: Precision, device: Device, f: impl FnOnce() -> T) -> T {
    if !mixed(precision, device) {
        return f();
    }
    let _scope = Bf16Scope::enter();
    f()
}

/// CUDA autocast in bf16 from `enter` until dropped (also on a panic), as `tch::autocast(true, ..)` without its
/// deprecated calls: the previous state comes back, and the cast cache is cleared when the outermost scope ends.
struct Bf16Scope {
    was_enabled: bool,
}

impl Bf16Scope {
    fn enter() -> Self {
        // SAFETY (here and in `drop`): plain libtorch functions of int8 enums and bools that set or read thread-local
        // state; no pointers.
        unsafe {
            at_autocast_set_autocast_dtype(CUDA, BFLOAT16);
            let was_enabled = at_autocast_is_autocast_enabled(CUDA);
            at_autocast_set_autocast_enabled(CUDA, true);
            at_autocast_increment_nesting();
            Bf16Scope { was_enabled }
        }
    }
}

impl Drop for Bf16Scope {
    fn drop(&mut self) {
        // SAFETY: see `enter`.
        unsafe {
            if at_autocast_decrement_nesting() == 0 {
                at_autocast_clear_cache();
            }
            at_autocast_set_autocast_enabled(CUDA, self.was_enabled);
        }
    }
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

    /// The scope's bookkeeping is libtorch's thread-local state, which exists on any build: on inside, nested
    /// scopes too, and off again after the outermost one, also when its closure panics.
    #[test]
    fn the_scope_switches_cuda_autocast_on_and_back_off() {
        let on = || unsafe { at_autocast_is_autocast_enabled(CUDA) };
        assert!(!on());
        {
            let _outer = Bf16Scope::enter();
            assert!(on());
            {
                let _inner = Bf16Scope::enter();
                assert!(on());
            }
            assert!(on(), "the inner scope leaves the outer one's state");
        }
        assert!(!on());
        let panicked = std::panic::catch_unwind(|| {
            let _scope = Bf16Scope::enter();
            panic!("in the forward pass");
        });
        assert!(panicked.is_err());
        assert!(!on(), "a panic inside the scope still ends it");
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
