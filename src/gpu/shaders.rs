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
/// Forward-pass vertex shader for scenes with materials (texture coordinates, vertex colors).
pub const SCENE_MAT_VERT: &[u8] = spirv!("scene_mat.vert");
/// Forward-pass fragment shader for scenes with materials (opaque).
pub const SCENE_MAT_FRAG: &[u8] = spirv!("scene_mat.frag");
/// Forward-pass fragment shader for alpha-masked materials.
pub const SCENE_MAT_MASKED_FRAG: &[u8] = spirv!("scene_mat_masked.frag");
/// Forward-pass fragment shader for blended materials (its alpha is the material's).
pub const SCENE_MAT_BLEND_FRAG: &[u8] = spirv!("scene_mat_blend.frag");
/// ID-pass fragment shader for alpha-masked materials.
pub const ID_MASKED_FRAG: &[u8] = spirv!("id_masked.frag");
/// The box oracle's vertex shader: one bounding box per instance, from a storage buffer.
pub const BOX_VISIBLE_VERT: &[u8] = spirv!("box_visible.vert");
/// The box oracle's fragment shader: marks the object of a box fragment that passed depth.
pub const BOX_VISIBLE_FRAG: &[u8] = spirv!("box_visible.frag");
/// coherent-ash's query-box vertex shader, compiled from shaders/query_box.vert (the crate ships
/// its own copy of these words; a test fails when they differ).
pub const QUERY_BOX_VERT: &[u8] = spirv!("query_box.vert");

/// GI G-buffer vertex shader (pulls world-space vertices from a storage buffer).
pub const GI_GBUFFER_VERT: &[u8] = spirv!("gi_gbuffer.vert");
/// GI G-buffer vertex shader of the indexed pass (position, normal, albedo as attributes).
pub const GI_GBUFFER_INDEXED_VERT: &[u8] = spirv!("gi_gbuffer_indexed.vert");
/// GI G-buffer fragment shader.
pub const GI_GBUFFER_FRAG: &[u8] = spirv!("gi_gbuffer.frag");
/// GI G-buffer vertex shader of scenes with alpha masks (adds the mask's coordinates).
pub const GI_GBUFFER_MASKED_VERT: &[u8] = spirv!("gi_gbuffer_masked.vert");
/// GI G-buffer fragment shader of scenes with alpha masks (discards masked-out texels).
pub const GI_GBUFFER_MASKED_FRAG: &[u8] = spirv!("gi_gbuffer_masked.frag");
/// GI G-buffer vertex shader of scenes with base color textures (adds the texture's data).
pub const GI_GBUFFER_TEXTURED_VERT: &[u8] = spirv!("gi_gbuffer_textured.vert");
/// GI G-buffer fragment shader of scenes with base color textures (the albedo per pixel).
pub const GI_GBUFFER_TEXTURED_FRAG: &[u8] = spirv!("gi_gbuffer_textured.frag");
/// [`GI_GBUFFER_TEXTURED_VERT`] of scenes with alpha masks too (adds the mask's data).
pub const GI_GBUFFER_TEXTURED_MASKED_VERT: &[u8] = spirv!("gi_gbuffer_textured_masked.vert");
/// [`GI_GBUFFER_TEXTURED_FRAG`] of scenes with alpha masks too (discards masked-out texels).
pub const GI_GBUFFER_TEXTURED_MASKED_FRAG: &[u8] = spirv!("gi_gbuffer_textured_masked.frag");
/// GI layered paraboloid shadow-map vertex shader (clips at the base plane with
/// `gl_ClipDistance`; needs `shaderClipDistance`).
pub const GI_SHADOW_VERT: &[u8] = spirv!("gi_shadow.vert");
/// GI shadow-map vertex shader of the indexed pass: the position is a vertex attribute (needs
/// `shaderClipDistance`, like [`GI_SHADOW_VERT`]).
pub const GI_SHADOW_INDEXED_VERT: &[u8] = spirv!("gi_shadow_indexed.vert");
/// GI shadow-map vertex shader that clips in the shader (devices without `shaderClipDistance`).
pub const GI_SHADOW_EXACT_VERT: &[u8] = spirv!("gi_shadow_exact.vert");
/// GI shadow-map vertex shader of scenes with alpha masks (adds the mask's coordinates).
pub const GI_SHADOW_MASKED_VERT: &[u8] = spirv!("gi_shadow_masked.vert");
/// [`GI_SHADOW_MASKED_VERT`] clipping in the shader (devices without `shaderClipDistance`).
pub const GI_SHADOW_MASKED_EXACT_VERT: &[u8] = spirv!("gi_shadow_masked_exact.vert");
/// GI shadow-map fragment shader of scenes with alpha masks (discards masked-out texels).
pub const GI_SHADOW_MASKED_FRAG: &[u8] = spirv!("gi_shadow_masked.frag");
/// GI interleaved VPL gather (compute).
pub const GI_GATHER_COMP: &[u8] = spirv!("gi_gather.comp");
/// GI resolve: blur, direct light, tone mapping (compute).
pub const GI_RESOLVE_COMP: &[u8] = spirv!("gi_resolve.comp");
/// GI blur of the gathered light (compute).
pub const GI_BLUR_COMP: &[u8] = spirv!("gi_blur.comp");
/// GI imperfect shadow maps: point splats (vertex).
pub const GI_ISM_SPLAT_VERT: &[u8] = spirv!("gi_ism_splat.vert");
/// GI imperfect shadow maps: pull-push hole filling (compute).
pub const GI_ISM_PULL_PUSH_COMP: &[u8] = spirv!("gi_ism_pull_push.comp");

/// Hi-Z: one level of the depth pyramid (farthest depth of 2x2 blocks) (compute).
pub const HIZ_REDUCE_COMP: &[u8] = spirv!("hiz_reduce.comp");
/// Hi-Z: frustum and pyramid test of every object, writing indirect draws (compute).
pub const HIZ_CULL_COMP: &[u8] = spirv!("hiz_cull.comp");
/// Predicated mode: the depth test of split nodes' parts, writing their predicates (compute).
pub const PART_TEST_COMP: &[u8] = spirv!("part_test.comp");
/// Predicated mode: the draws of the parts that passed their test, gathered for one indirect
/// draw with a count (compute).
pub const PART_DRAWS_COMP: &[u8] = spirv!("part_draws.comp");

/// Creates a shader module from SPIR-V bytes.
pub fn module(ctx: &GpuContext, name: &str, bytes: &[u8]) -> Result<vk::ShaderModule> {
    let words = ash::util::read_spv(&mut Cursor::new(bytes))
        .map_err(|e| Error::Shader(format!("{name}: {e}")))?;
    let info = vk::ShaderModuleCreateInfo::default().code(&words);
    // SAFETY: valid SPIR-V produced by shaderc at build time.
    unsafe { ctx.device.create_shader_module(&info, None) }.vk("vkCreateShaderModule")
}
