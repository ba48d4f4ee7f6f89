//! The library's one error type.

use ash::vk;

/// Everything that can go wrong inside `coherent`.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A Vulkan call failed.
    #[error("Vulkan call {call} failed: {result}")]
    Vulkan {
        /// The failing call.
        call: &'static str,
        /// The result it returned.
        result: vk::Result,
    },
    /// The Vulkan loader could not be opened.
    #[error("cannot load the Vulkan loader: {0}")]
    Loader(String),
    /// GPU memory allocation failed.
    #[error("GPU memory allocation failed: {0}")]
    Alloc(String),
    /// A shader could not be used.
    #[error("shader error: {0}")]
    Shader(String),
    /// A scene could not be loaded or built.
    #[error("{0}")]
    Scene(String),
    /// The chosen device lacks something we need.
    #[error("the Vulkan device lacks a required feature: {feature}")]
    Unsupported {
        /// What is missing.
        feature: String,
    },
    /// Bad input from the caller (flags, sizes, names).
    #[error("{0}")]
    Input(String),
    /// File I/O failed.
    #[error("I/O error: {0}")]
    Io(#[from] std::io::Error),
}

/// Result alias of the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Maps a `vk::Result` to [`Error::Vulkan`] naming the call.
pub(crate) trait VkContext<T> {
    fn vk(self, call: &'static str) -> Result<T>;
}

impl<T> VkContext<T> for std::result::Result<T, vk::Result> {
    fn vk(self, call: &'static str) -> Result<T> {
        self.map_err(|result| Error::Vulkan { call, result })
    }
}
