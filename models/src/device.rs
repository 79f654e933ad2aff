//! Device selection: the config string `training.device` is "auto" (CUDA when present), "cpu" or "cuda:N".

use crate::ModelError;
use tch::Device;

/// Whether libtorch sees a CUDA device (the build script links libtorch_cuda so that this can be true).
pub fn cuda_available() -> bool {
    tch::Cuda::is_available()
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
