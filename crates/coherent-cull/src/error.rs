//! The culling core's error type. It holds no Vulkan type: a backend's own error travels boxed in
//! [`Error::Backend`] and can be taken back out with [`Error::into_backend`].

/// Everything that can go wrong in a culler or a hierarchy update.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Bad input from the caller (names, sizes, object ids, parameters).
    #[error("{0}")]
    Input(String),
    /// The backend cannot do what the culler asks (a latency mode it does not support, for
    /// example).
    #[error("the occlusion backend lacks {feature}")]
    Unsupported {
        /// What is missing.
        feature: String,
    },
    /// The backend failed; its own error, boxed.
    #[error("{0}")]
    Backend(Box<dyn std::error::Error + Send + Sync + 'static>),
}

impl Error {
    /// Wraps a backend's own error.
    pub fn backend(e: impl std::error::Error + Send + Sync + 'static) -> Error {
        Error::Backend(Box::new(e))
    }
    /// The backend's error of type `E` this holds, or the error itself back.
    pub fn into_backend<E: std::error::Error + 'static>(self) -> std::result::Result<E, Error> {
        match self {
            Error::Backend(b) => match b.downcast::<E>() {
                Ok(e) => Ok(*e),
                Err(b) => Err(Error::Backend(b)),
            },
            other => Err(other),
        }
    }
}

/// Result alias of the culling core.
pub type Result<T, E = Error> = std::result::Result<T, E>;
