//! Why a [`SimSpec`](super::SimSpec) was refused.

/// A topology file that could not be read, or a spec that fails its
/// checks. The message names the item (and, for a file, its line) and
/// the fix.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SpecError {
    /// The file could not be read.
    #[error("{context}: {source}")]
    Read {
        /// Which file.
        context: String,
        /// The error.
        #[source]
        source: std::io::Error,
    },
    /// The text is not a valid spec, or the spec fails its checks.
    #[error("{context}: {message}")]
    Invalid {
        /// Which spec or file, and where in it.
        context: String,
        /// What is wrong and how to fix it.
        message: String,
    },
}

impl SpecError {
    /// What is wrong, without the context.
    pub fn message(&self) -> String {
        match self {
            SpecError::Read { source, .. } => source.to_string(),
            SpecError::Invalid { message, .. } => message.clone(),
        }
    }
}

/// A spec error as the host's I/O error, the same words: the simulated
/// machines start as a host connects, and fail as a connection does.
impl From<SpecError> for osap_host::HostError {
    fn from(e: SpecError) -> Self {
        match e {
            SpecError::Read { context, source } => osap_host::HostError::Io { context, source },
            SpecError::Invalid { context, message } => osap_host::HostError::Io {
                context,
                source: std::io::Error::new(std::io::ErrorKind::InvalidData, message),
            },
        }
    }
}
