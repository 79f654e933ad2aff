//! The errors of this crate.

/// Why a network could not be built, loaded or run.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// Weights of one architecture offered to a network of another.
    #[error("architecture mismatch: the network is `{expected}`, the weights are `{found}`")]
    ArchitectureMismatch { expected: String, found: String },
    #[error("unknown architecture name `{0}`")]
    UnknownArchitecture(String),
    #[error("malformed safetensors bytes: {0}")]
    MalformedWeights(String),
    #[error("the weights lack tensor `{0}`")]
    MissingTensor(String),
    #[error("the weights hold tensor `{0}`, which the network does not have")]
    UnexpectedTensor(String),
    #[error("tensor `{name}`: the network has shape {expected:?}, the weights {found:?}")]
    ShapeMismatch {
        name: String,
        expected: Vec<i64>,
        found: Vec<i64>,
    },
    #[error("device `{0}`: {1}")]
    Device(String, &'static str),
    #[error("observation does not fit the policy: {0}")]
    Observation(String),
    #[error("{path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error(transparent)]
    Torch(#[from] tch::TchError),
}
