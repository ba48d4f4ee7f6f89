//! The forward renderer's pipelines: shaded scene geometry (render state) and the object-ID
//! pass of the exact-visibility oracle. They share one layout: set 0 binds the per-object
//! storage buffer; push constants hold view_proj and the sun direction. The query boxes are
//! drawn with coherent-ash's box pipeline on this layout (it reads view_proj from the same
//! push block).

use std::sync::Arc;

use ash::vk;

use crate::error::Result;
use crate::gpu::targets::{COLOR_FORMAT, DEPTH_FORMAT, ID_FORMAT};
use crate::gpu::{shaders, GpuContext, Pipeline, PipelineDesc, PipelineKind, PipelineLayout};

/// Push-constant block: view_proj (64 bytes) and sun direction (16 bytes).
pub const PUSH_SIZE: u32 = 80;

/// Vertex attributes of the scene vertex buffer: position and normal.
const SCENE_ATTRIBUTES: [(u32, vk::Format, u32); 2] = [
    (0, vk::Format::R32G32B32_SFLOAT, 0),
    (1, vk::Format::R32G32B32_SFLOAT, 12),
];

/// Vertex attributes of a scene with materials: position, normal, texture coordinates and a
/// vertex color, interleaved ([`crate::render::upload`] writes them).
const MATERIAL_ATTRIBUTES: [(u32, vk::Format, u32); 4] = [
    (0, vk::Format::R32G32B32_SFLOAT, 0),
    (1, vk::Format::R32G32B32_SFLOAT, 12),
    (2, vk::Format::R32G32_SFLOAT, 24),
    (3, vk::Format::R8G8B8A8_UNORM, 32),
];

/// Bytes of one interleaved vertex of a scene with materials.
pub const MATERIAL_VERTEX_STRIDE: u32 = 36;

/// The three pipelines and their layout.
pub struct ScenePipelines {
    // Pipelines are declared before the layout so they are dropped first.
    /// Shaded geometry.
    pub render: Pipeline,
    /// Object IDs (oracle pre-pass).
    pub id: Pipeline,
    /// Shaded alpha-masked geometry (scenes with materials only).
    pub render_masked: Option<Pipeline>,
    /// Object IDs of alpha-masked geometry (scenes with materials only).
    pub id_masked: Option<Pipeline>,
    /// Variants without back-face culling for `doubleSided` materials (see
    /// [`ScenePipelines::add_two_sided`]).
    pub two_sided: Option<TwoSidedPipelines>,
    /// Blended geometry, one-sided and two-sided (see [`ScenePipelines::add_blended`]).
    pub blended: Option<[Pipeline; 2]>,
    /// Whether these are the material pipelines (set 0 binding 1 is the base color texture,
    /// vertices are interleaved with texture coordinates and colors).
    pub materials: bool,
    /// The shared layout.
    pub layout: PipelineLayout,
}

impl ScenePipelines {
    /// Creates the layout and the three pipelines.
    pub fn new(ctx: &Arc<GpuContext>) -> Result<ScenePipelines> {
        let layout = PipelineLayout::new(ctx, &[vk::DescriptorType::STORAGE_BUFFER], PUSH_SIZE)?;
        Ok(ScenePipelines {
            render: Pipeline::graphics(ctx, &layout, &scene_desc("render", shaded()))?,
            id: Pipeline::graphics(ctx, &layout, &scene_desc("id", ids()))?,
            render_masked: None,
            id_masked: None,
            two_sided: None,
            blended: None,
            materials: false,
            layout,
        })
    }

    /// The pipelines for a scene: [`ScenePipelines::new`] unless `materials`, then the
    /// material pipelines (opaque and masked render, ID and masked ID)
    /// with set 0 = (objects, base color texture).
    pub fn for_scene(ctx: &Arc<GpuContext>, materials: bool) -> Result<ScenePipelines> {
        if !materials {
            return ScenePipelines::new(ctx);
        }
        let layout = PipelineLayout::new(
            ctx,
            &[
                vk::DescriptorType::STORAGE_BUFFER,
                vk::DescriptorType::COMBINED_IMAGE_SAMPLER,
            ],
            PUSH_SIZE,
        )?;
        let mat = |name, frag, out: SceneOutput| PipelineDesc {
            vert: shaders::SCENE_MAT_VERT,
            vertex_stride: MATERIAL_VERTEX_STRIDE,
            attributes: &MATERIAL_ATTRIBUTES,
            frag: Some(frag),
            ..scene_desc(name, out)
        };
        Ok(ScenePipelines {
            render: Pipeline::graphics(
                ctx,
                &layout,
                &mat("render", shaders::SCENE_MAT_FRAG, shaded()),
            )?,
            id: Pipeline::graphics(ctx, &layout, &mat("id", shaders::ID_FRAG, ids()))?,
            render_masked: Some(Pipeline::graphics(
                ctx,
                &layout,
                &mat("render masked", shaders::SCENE_MAT_MASKED_FRAG, shaded()),
            )?),
            id_masked: Some(Pipeline::graphics(
                ctx,
                &layout,
                &mat("id masked", shaders::ID_MASKED_FRAG, ids()),
            )?),
            two_sided: None,
            blended: None,
            materials: true,
            layout,
        })
    }
}

/// The material pipelines without back-face culling, for `doubleSided` materials: opaque and
/// masked render, ID and masked ID.
pub struct TwoSidedPipelines {
    pub render: Pipeline,
    pub render_masked: Pipeline,
    pub id: Pipeline,
    pub id_masked: Pipeline,
}

impl ScenePipelines {
    /// Adds the [`TwoSidedPipelines`] to material pipelines (a scene with a `doubleSided`
    /// material); nothing for the plain ones, which have no materials.
    pub fn add_two_sided(&mut self, ctx: &Arc<GpuContext>) -> Result<()> {
        if !self.materials || self.two_sided.is_some() {
            return Ok(());
        }
        let layout = &self.layout;
        let mat = |name, frag, out: SceneOutput| -> Result<Pipeline> {
            let desc = PipelineDesc {
                vert: shaders::SCENE_MAT_VERT,
                vertex_stride: MATERIAL_VERTEX_STRIDE,
                attributes: &MATERIAL_ATTRIBUTES,
                frag: Some(frag),
                cull: vk::CullModeFlags::NONE,
                ..scene_desc(name, out)
            };
            Pipeline::graphics(ctx, layout, &desc)
        };
        self.two_sided = Some(TwoSidedPipelines {
            render: mat("render two-sided", shaders::SCENE_MAT_FRAG, shaded())?,
            render_masked: mat(
                "render masked two-sided",
                shaders::SCENE_MAT_MASKED_FRAG,
                shaded(),
            )?,
            id: mat("id two-sided", shaders::ID_FRAG, ids())?,
            id_masked: mat("id masked two-sided", shaders::ID_MASKED_FRAG, ids())?,
        });
        Ok(())
    }

    /// Adds the blended pipelines to material pipelines (a scene with a blended material):
    /// depth-tested, no depth writes, color blended by the material's alpha; nothing for the
    /// plain ones.
    pub fn add_blended(&mut self, ctx: &Arc<GpuContext>) -> Result<()> {
        if !self.materials || self.blended.is_some() {
            return Ok(());
        }
        let layout = &self.layout;
        let make = |name, cull| -> Result<Pipeline> {
            let desc = PipelineDesc {
                vert: shaders::SCENE_MAT_VERT,
                vertex_stride: MATERIAL_VERTEX_STRIDE,
                attributes: &MATERIAL_ATTRIBUTES,
                frag: Some(shaders::SCENE_MAT_BLEND_FRAG),
                cull,
                depth_write: false,
                blend: true,
                ..scene_desc(name, shaded())
            };
            Pipeline::graphics(ctx, layout, &desc)
        };
        self.blended = Some([
            make("render blended", vk::CullModeFlags::BACK)?,
            make("render blended two-sided", vk::CullModeFlags::NONE)?,
        ]);
        Ok(())
    }

    /// The pipeline a blended object is drawn with: blended, two-sided or not; the render
    /// pipeline in a scene without the blended ones (no materials).
    pub fn blended_pipeline(&self, two_sided: bool) -> &Pipeline {
        match &self.blended {
            Some([one_sided, both]) => {
                if two_sided {
                    both
                } else {
                    one_sided
                }
            }
            None => &self.render,
        }
    }

    /// The material pipeline for an object: masked or not, two-sided or not (when the
    /// two-sided variants exist), the render or the ID pass.
    pub fn material_pipeline(&self, masked: bool, two_sided: bool, ids: bool) -> &Pipeline {
        if let Some(t) = self.two_sided.as_ref().filter(|_| two_sided) {
            return match (masked, ids) {
                (false, false) => &t.render,
                (true, false) => &t.render_masked,
                (false, true) => &t.id,
                (true, true) => &t.id_masked,
            };
        }
        let masked_pipeline = match ids {
            false => self.render_masked.as_ref(),
            true => self.id_masked.as_ref(),
        };
        let opaque = if ids { &self.id } else { &self.render };
        masked_pipeline.filter(|_| masked).unwrap_or(opaque)
    }
}

/// Fragment shader, color format and kind of a pass over scene geometry.
struct SceneOutput {
    frag: &'static [u8],
    formats: &'static [vk::Format],
    kind: PipelineKind,
}

fn shaded() -> SceneOutput {
    SceneOutput {
        frag: shaders::SCENE_FRAG,
        formats: &[COLOR_FORMAT],
        kind: PipelineKind::Render,
    }
}

fn ids() -> SceneOutput {
    SceneOutput {
        frag: shaders::ID_FRAG,
        formats: &[ID_FORMAT],
        kind: PipelineKind::Other,
    }
}

fn scene_desc(name: &'static str, out: SceneOutput) -> PipelineDesc<'static> {
    PipelineDesc {
        name,
        vert: shaders::SCENE_VERT,
        frag: Some(out.frag),
        vertex_stride: 24,
        attributes: &SCENE_ATTRIBUTES,
        color_formats: out.formats,
        color_write: true,
        depth_format: DEPTH_FORMAT,
        depth_compare: vk::CompareOp::LESS,
        depth_write: true,
        cull: vk::CullModeFlags::BACK,
        kind: out.kind,
        depth_bias: (0.0, 0.0),
        blend: false,
    }
}
