//! One error type for the whole tool, mapped to the documented exit codes.
use std::path::PathBuf;

/// Exit codes that farm scripts rely on (see README).
pub mod exit {
    pub const OK: i32 = 0;
    pub const INVALID_INPUT: i32 = 2;
    pub const RUNTIME: i32 = 3;
    pub const NO_GPU: i32 = 4;
    pub const INTERRUPTED: i32 = 130;
}

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A config problem, already formatted as `file:line:col: key: message`.
    #[error("{0}")]
    Config(String),
    /// Any other bad input (a corrupt checkpoint, a file that is not ours, bad CLI values).
    #[error("{0}")]
    InvalidInput(String),
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{0}")]
    Runtime(String),
    #[error("{0}")]
    NoGpu(String),
    #[error("interrupted: {0}")]
    Interrupted(String),
}

impl Error {
    pub fn exit_code(&self) -> i32 {
        match self {
            Error::Config(_) | Error::InvalidInput(_) => exit::INVALID_INPUT,
            Error::Io { .. } | Error::Runtime(_) => exit::RUNTIME,
            Error::NoGpu(_) => exit::NO_GPU,
            Error::Interrupted(_) => exit::INTERRUPTED,
        }
    }

    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }
}

pub type Result<T, E = Error> = std::result::Result<T, E>;
