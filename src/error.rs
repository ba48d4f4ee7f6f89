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
    /// The device was lost (a driver crash, reset or hang); the context cannot be used again.
    #[error("the Vulkan device was lost during {call} (driver crash, reset or hang); recreate the context")]
    DeviceLost {
        /// The call that reported it.
        call: &'static str,
    },
    /// Device memory ran out (the driver said so, the allocator found no room, or the
    /// context's memory budget would be exceeded).
    #[error("out of device memory: {what}")]
    OutOfDeviceMemory {
        /// What was being allocated or called, and the sizes where known.
        what: String,
    },
    /// Host memory ran out inside the driver.
    #[error("out of host memory: {what}")]
    OutOfHostMemory {
        /// The call that reported it.
        what: String,
    },
    /// Something exceeds a device limit and the work cannot be split to fit.
    #[error("{what}: {value} exceeds the device's {limit} of {max}")]
    Limit {
        /// What was being created or recorded.
        what: String,
        /// The Vulkan limit's name, e.g. `maxImageDimension2D`.
        limit: &'static str,
        /// The value asked for.
        value: u64,
        /// The device's limit.
        max: u64,
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
    /// A culler refused its input or its backend (an error of the culling core that is not
    /// one of this crate's own errors coming back through the backend).
    #[error("{0}")]
    Cull(coherent_cull::Error),
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
        self.map_err(|result| Error::from_vk(call, result))
    }
}

impl Error {
    /// The error for `result` returned by `call`: device loss and running out of device or host
    /// memory get their own variants, everything else is [`Error::Vulkan`].
    pub fn from_vk(call: &'static str, result: vk::Result) -> Error {
        match result {
            vk::Result::ERROR_DEVICE_LOST => Error::DeviceLost { call },
            vk::Result::ERROR_OUT_OF_DEVICE_MEMORY => Error::OutOfDeviceMemory {
                what: format!("{call} returned {result}"),
            },
            vk::Result::ERROR_OUT_OF_HOST_MEMORY => Error::OutOfHostMemory {
                what: format!("{call} returned {result}"),
            },
            _ => Error::Vulkan { call, result },
        }
    }

    /// The error for a failed gpu-allocator allocation of `what`.
    pub(crate) fn from_alloc(what: &str, e: gpu_allocator::AllocationError) -> Error {
        match e {
            gpu_allocator::AllocationError::OutOfMemory => Error::OutOfDeviceMemory {
                what: format!("{what}: the allocator found no memory"),
            },
            e => Error::Alloc(format!("{what}: {e}")),
        }
    }
}

/// A culling error: a backend error of this crate travelling back through a culler comes out
/// as itself, everything else as [`Error::Cull`] (input errors as [`Error::Input`]).
impl From<coherent_cull::Error> for Error {
    fn from(e: coherent_cull::Error) -> Error {
        match e.into_backend::<Error>() {
            Ok(own) => own,
            Err(coherent_cull::Error::Input(msg)) => Error::Input(msg),
            Err(other) => Error::Cull(other),
        }
    }
}

/// This crate's errors leave through [`coherent_cull::OcclusionBackend`] boxed, and come back
/// whole through `From<coherent_cull::Error>`.
impl From<Error> for coherent_cull::Error {
    fn from(e: Error) -> coherent_cull::Error {
        match e {
            Error::Cull(inner) => inner,
            Error::Input(msg) => coherent_cull::Error::Input(msg),
            other => coherent_cull::Error::backend(other),
        }
    }
}
