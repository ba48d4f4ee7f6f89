//! SPIR-V compiled by build.rs from shaders/, embedded in the binary.

use std::io::Cursor;

use ash::vk;

use super::GpuContext;
use crate::error::{Error, Result, VkContext};

macro_rules! spirv {
    ($name:literal) => {
        include_bytes!(concat!(env!("OUT_DIR"), "/", $name, ".spv"))
    };
}

/// Forward-pass vertex shader.
pub const SCENE_VERT: &[u8] = spirv!("scene.vert");
/// Forward-pass fragment shader.
pub const SCENE_FRAG: &[u8] = spirv!("scene.frag");
/// Oracle ID fragment shader.
pub const ID_FRAG: &[u8] = spirv!("id.frag");
/// Query box vertex shader.
pub const BOX_VERT: &[u8] = spirv!("box.vert");

/// Creates a shader module from SPIR-V bytes.
pub fn module(ctx: &GpuContext, name: &str, bytes: &[u8]) -> Result<vk::ShaderModule> {
    let words = ash::util::read_spv(&mut Cursor::new(bytes))
        .map_err(|e| Error::Shader(format!("{name}: {e}")))?;
    let info = vk::ShaderModuleCreateInfo::default().code(&words);
    // SAFETY: valid SPIR-V produced by shaderc at build time.
    unsafe { ctx.device.create_shader_module(&info, None) }.vk("vkCreateShaderModule")
}
