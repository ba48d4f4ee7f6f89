//! Deferred shading for GI: the G-buffer (world position, normal, albedo; the albedo read
//! from the base color texture per pixel in a textured scene) rendered from the camera, the interleaved VPL gather and its geometry-aware blur at half resolution (compute),
//! and the resolve pass (geometry-aware upsample, direct spotlight, tone mapping into RGBA8).

use std::sync::Arc;

use ash::vk;

use crate::error::Result;
use crate::gi::geometry::{SharedCorners, VERTEX_FLOATS};
use crate::gpu::{
    as_bytes, shaders, Attachment, Binding, Buffer, ComputePipeline, DescriptorSet, DescriptorSets,
    GpuContext, Image, ImageUse, Load, Pipeline, PipelineDesc, PipelineKind, PipelineLayout,
    Recorder,
};

/// G-buffer position and normal format (also the indirect accumulation format).
pub const FLOAT_FORMAT: vk::Format = vk::Format::R32G32B32A32_SFLOAT;
/// Albedo and output format.
pub const UNORM_FORMAT: vk::Format = vk::Format::R8G8B8A8_UNORM;
const DEPTH_FORMAT: vk::Format = vk::Format::D32_SFLOAT;

/// The G-buffer, the indirect-light accumulation image and the tone-mapped output.
pub struct GBuffer {
    gbuffer_pipeline: Pipeline,
    /// For scenes with alpha masks: the G-buffer pipeline that discards masked-out texels,
    /// used instead (see [`GBuffer::enable_masks`]).
    masked_pipeline: Option<Pipeline>,
    /// Scenes with base color textures: the pipeline that reads the albedo from them, its
    /// layout, set and data, used instead of the others (see [`GBuffer::enable_textures`]).
    textured: Option<TexturedGBuffer>,
    /// Scenes without masks or textures: the indexed pipeline and its indices (see
    /// [`GBuffer::enable_indexed`]).
    indexed: Option<IndexedGBuffer>,
    /// World position (w = 1 where a surface was hit).
    pub position: Image,
    /// World normal, facing the camera.
    pub normal: Image,
    /// Diffuse albedo.
    pub albedo: Image,
    /// Depth for the G-buffer pass.
    pub depth: Image,
    /// Half resolution: interleaved indirect irradiance (gather output, blur input).
    pub indirect: Image,
    /// Half resolution: each sample's G-buffer position (written by the gather).
    pub half_position: Image,
    /// Half resolution: each sample's G-buffer normal (written by the gather).
    pub half_normal: Image,
    /// Half resolution: blurred irradiance from all VPLs (blur output, resolve input).
    pub blurred: Image,
    /// Tone-mapped RGBA8 result.
    pub output: Image,
    /// Width and height.
    pub size: (u32, u32),
    /// Width and height of the half-resolution images (rounded up).
    pub half_size: (u32, u32),
}

impl GBuffer {
    /// Creates the images and the G-buffer pipeline (sharing the graphics `layout`).
    pub fn new(
        ctx: &Arc<GpuContext>,
        layout: &PipelineLayout,
        width: u32,
        height: u32,
    ) -> Result<GBuffer> {
        let extent = (width, height);
        let attach = vk::ImageUsageFlags::COLOR_ATTACHMENT | vk::ImageUsageFlags::STORAGE;
        let position = Image::new(ctx, "gbuffer position", FLOAT_FORMAT, extent, 1, attach)?;
        let normal = Image::new(ctx, "gbuffer normal", FLOAT_FORMAT, extent, 1, attach)?;
        let albedo = Image::new(ctx, "gbuffer albedo", UNORM_FORMAT, extent, 1, attach)?;
        let depth = Image::new(
            ctx,
            "gbuffer depth",
            DEPTH_FORMAT,
            extent,
            1,
            vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT,
        )?;
        let half_size = (width.div_ceil(2), height.div_ceil(2));
        let storage = vk::ImageUsageFlags::STORAGE;
        let indirect = Image::new(ctx, "indirect", FLOAT_FORMAT, half_size, 1, storage)?;
        let half_position = Image::new(ctx, "half position", FLOAT_FORMAT, half_size, 1, storage)?;
        let half_normal = Image::new(ctx, "half normal", FLOAT_FORMAT, half_size, 1, storage)?;
        let blurred = Image::new(ctx, "blurred indirect", FLOAT_FORMAT, half_size, 1, storage)?;
        let output = Image::new(
            ctx,
            "gi output",
            UNORM_FORMAT,
            extent,
            1,
            vk::ImageUsageFlags::STORAGE | vk::ImageUsageFlags::TRANSFER_SRC,
        )?;
        let gbuffer_pipeline = Pipeline::graphics(ctx, layout, &gbuffer_desc())?;
        Ok(GBuffer {
            gbuffer_pipeline,
            masked_pipeline: None,
            textured: None,
            indexed: None,
            position,
            normal,
            albedo,
            depth,
            indirect,
            half_position,
            half_normal,
            blurred,
            output,
            size: extent,
            half_size,
        })
    }

    /// Draws later G-buffer passes with the pipeline that discards masked-out texels; its
    /// `layout` is the masked shadow pass's (vertices, slots, mask per vertex, mask images),
    /// whose set the caller then passes to [`GBuffer::record_gbuffer`].
    pub fn enable_masks(&mut self, ctx: &Arc<GpuContext>, layout: &PipelineLayout) -> Result<()> {
        let desc = PipelineDesc {
            name: "gi gbuffer masked",
            vert: shaders::GI_GBUFFER_MASKED_VERT,
            frag: Some(shaders::GI_GBUFFER_MASKED_FRAG),
            ..gbuffer_desc()
        };
        self.masked_pipeline = Some(Pipeline::graphics(ctx, layout, &desc)?);
        Ok(())
    }

    /// Draws later G-buffer passes with the pipeline that reads each pixel's albedo from the
    /// base color textures: `textures` holds two vec4 per vertex of `vertices` and the packed
    /// images ([`TriangleTextures::gpu_data`](crate::gi::textures::TriangleTextures::gpu_data));
    /// with `masks` (the masked shadow pass's buffers of mask data,
    /// [`ShadowMaps::mask_buffers`](crate::gi::shadow::ShadowMaps::mask_buffers)), the variant
    /// that also discards masked-out texels. Its own layout (storage buffers: vertices, slots, mask vertices,
    /// mask images, texture vertices, texture images) and set; [`GBuffer::record_gbuffer`]
    /// then ignores the set it is given.
    pub fn enable_textures(
        &mut self,
        ctx: &Arc<GpuContext>,
        push_size: u32,
        (vertices, slots): (&Buffer, &Buffer),
        masks: Option<[&Buffer; 2]>,
        (texture_vertices, words): &(Vec<f32>, Vec<u32>),
    ) -> Result<()> {
        self.textured = Some(TexturedGBuffer::new(
            ctx,
            push_size,
            (vertices, slots),
            masks,
            (texture_vertices, words),
        )?);
        Ok(())
    }

    /// Draws later passes indexed, reading the renderer's vertex buffer (`vertex_floats`, its
    /// contents, [`VERTEX_FLOATS`] per vertex) as vertex attributes: corners with identical
    /// position, normal and albedo share an index, so the vertex stage runs about once per
    /// vertex instead of once per corner. Nothing changes for scenes with masks (their
    /// pipeline pulls per-corner mask data by vertex index).
    pub fn enable_indexed(
        &mut self,
        ctx: &Arc<GpuContext>,
        layout: &PipelineLayout,
        vertex_floats: &[f32],
    ) -> Result<()> {
        if self.masked_pipeline.is_some() || self.textured.is_some() {
            return Ok(());
        }
        let desc = PipelineDesc {
            name: "gi gbuffer indexed",
            vert: shaders::GI_GBUFFER_INDEXED_VERT,
            vertex_stride: (VERTEX_FLOATS * 4) as u32,
            attributes: &[
                (0, vk::Format::R32G32B32_SFLOAT, 0),
                (1, vk::Format::R32G32B32_SFLOAT, 16),
                (2, vk::Format::R32G32B32_SFLOAT, 32),
            ],
            ..gbuffer_desc()
        };
        self.indexed = Some(IndexedGBuffer {
            pipeline: Pipeline::graphics(ctx, layout, &desc)?,
            indices: SharedCorners::new(ctx, "gi gbuffer indices", vertex_floats)?,
        });
        Ok(())
    }

    /// Whether the pass draws indexed (see [`GBuffer::enable_indexed`]).
    pub fn indexed(&self) -> bool {
        self.indexed.is_some()
    }

    /// Rewrites the indexed pass's indices after the vertices from `first_vertex` on changed
    /// (`vertex_floats` is the whole buffer's new contents, as in [`GBuffer::enable_indexed`];
    /// the same vertex count): only those vertices are hashed again. Nothing to do when the
    /// pass is not indexed. Call between frames, after vertices moved.
    pub fn reindex(&mut self, vertex_floats: &[f32], first_vertex: usize) -> Result<()> {
        match &mut self.indexed {
            Some(ix) => ix.indices.rewrite(vertex_floats, first_vertex),
            None => Ok(()),
        }
    }

    /// Records the G-buffer pass (all `vertex_count` world-space vertices of `vertices`, pulled
    /// in the shader or, when indexed, read as attributes) and leaves its images for the compute
    /// passes: the G-buffer read-only, the indirect and output images read-write (their old
    /// contents discarded).
    pub fn record_gbuffer(
        &self,
        rec: &mut Recorder,
        layout: &PipelineLayout,
        set: DescriptorSet,
        push: &[f32; 24],
        (vertices, vertex_count): (&Buffer, u32),
    ) -> Result<()> {
        let targets = [&self.position, &self.normal, &self.albedo];
        for image in targets {
            rec.discard(image, ImageUse::ColorAttachment);
        }
        rec.discard(&self.depth, ImageUse::DepthAttachment);
        for image in self.half_images() {
            rec.discard(image, ImageUse::ComputeReadWrite);
        }
        rec.discard(&self.output, ImageUse::ComputeReadWrite);
        let color = targets.map(|image| Attachment {
            image,
            load: Load::ClearColor([0.0; 4]),
            store: true,
        });
        let depth = Attachment {
            image: &self.depth,
            load: Load::ClearDepth(1.0),
            store: false,
        };
        rec.begin_rendering(&color, Some(depth), 1)?;
        // Nothing to draw binds no vertex buffers (left bound for a later pipeline without
        // vertex input, they draw a best-practices warning).
        let indexed = self.indexed.as_ref().filter(|_| {
            self.masked_pipeline.is_none() && self.textured.is_none() && vertex_count > 0
        });
        let (layout, set) = match &self.textured {
            Some(t) => (&t.layout, t.sets.get(0)),
            None => (layout, set),
        };
        match (indexed, &self.textured) {
            (Some(ix), _) => {
                rec.bind_pipeline(&ix.pipeline);
                rec.bind_buffers(vertices, 0, Some(ix.indices.buffer()));
            }
            (None, Some(t)) => {
                rec.bind_pipeline(&t.pipeline);
            }
            (None, None) => {
                rec.bind_pipeline(
                    self.masked_pipeline
                        .as_ref()
                        .unwrap_or(&self.gbuffer_pipeline),
                );
            }
        }
        rec.bind_graphics_set(layout, set);
        rec.push_constants(layout, &crate::gpu::as_bytes(&push[..]));
        match (vertex_count, indexed) {
            (0, _) => {}
            (_, Some(_)) => rec.draw_indexed(vertex_count, 1, 0, 0, 0),
            (_, None) => rec.draw(vertex_count, 1),
        }
        rec.end_rendering();
        for image in targets {
            rec.transition(image, ImageUse::ComputeRead);
        }
        Ok(())
    }

    /// The half-resolution images the gather and the blur write.
    fn half_images(&self) -> [&Image; 4] {
        [
            &self.indirect,
            &self.half_position,
            &self.half_normal,
            &self.blurred,
        ]
    }

    /// Barrier between two compute passes that read and write the half-resolution images.
    pub fn record_compute_barrier(&self, rec: &mut Recorder) {
        for image in self.half_images() {
            rec.transition(image, ImageUse::ComputeReadWrite);
        }
    }

    /// Dispatches `pipeline` over the full-resolution image in 8x8 groups.
    pub fn record_dispatch(&self, rec: &mut Recorder, pipeline: &ComputePipeline) -> Result<()> {
        rec.bind_compute_pipeline(pipeline);
        rec.dispatch(
            "gi full-resolution pass",
            self.size.0.div_ceil(8),
            self.size.1.div_ceil(8),
            1,
        )
    }

    /// Dispatches `pipeline` over the half-resolution images in 8x8 groups.
    pub fn record_half_dispatch(
        &self,
        rec: &mut Recorder,
        pipeline: &ComputePipeline,
    ) -> Result<()> {
        rec.bind_compute_pipeline(pipeline);
        rec.dispatch(
            "gi half-resolution pass",
            self.half_size.0.div_ceil(8),
            self.half_size.1.div_ceil(8),
            1,
        )
    }
}

/// The indexed G-buffer pass: indices into the renderer's vertex buffer, each corner pointing
/// at the first vertex with the same [`VERTEX_FLOATS`] floats.
struct IndexedGBuffer {
    pipeline: Pipeline,
    /// Identical vertices share an index.
    indices: SharedCorners<VERTEX_FLOATS>,
}

/// The textured G-buffer pass: its pipeline (masked or not), layout, set and the buffers the
/// set points at besides the renderer's vertices and slots and the shadow pass's mask data.
struct TexturedGBuffer {
    // Sets and the pipeline before the layout, buffers last.
    sets: DescriptorSets,
    pipeline: Pipeline,
    layout: PipelineLayout,
    #[allow(dead_code)] // owned here; the set points at them
    buffers: Vec<Buffer>,
}

impl TexturedGBuffer {
    fn new(
        ctx: &Arc<GpuContext>,
        push_size: u32,
        (vertices, slots): (&Buffer, &Buffer),
        masks: Option<[&Buffer; 2]>,
        (texture_vertices, words): (&Vec<f32>, &Vec<u32>),
    ) -> Result<TexturedGBuffer> {
        let storage = vk::DescriptorType::STORAGE_BUFFER;
        let layout = PipelineLayout::new(ctx, &[storage; 6], push_size)?;
        let upload = |name, bytes: &[u8]| Buffer::storage_with(ctx, name, bytes);
        let mut buffers = vec![
            upload("gi gbuffer texture vertices", &as_bytes(texture_vertices))?,
            upload("gi gbuffer texture images", &as_bytes(words))?,
        ];
        if masks.is_none() {
            // The pipeline without masks reads neither mask binding: a word stands in.
            buffers.push(upload("gi gbuffer no masks", &as_bytes(&[0u32][..]))?);
        }
        let desc = match masks {
            Some(_) => PipelineDesc {
                name: "gi gbuffer textured masked",
                vert: shaders::GI_GBUFFER_TEXTURED_MASKED_VERT,
                frag: Some(shaders::GI_GBUFFER_TEXTURED_MASKED_FRAG),
                ..gbuffer_desc()
            },
            None => PipelineDesc {
                name: "gi gbuffer textured",
                vert: shaders::GI_GBUFFER_TEXTURED_VERT,
                frag: Some(shaders::GI_GBUFFER_TEXTURED_FRAG),
                ..gbuffer_desc()
            },
        };
        let pipeline = Pipeline::graphics(ctx, &layout, &desc)?;
        let [mask_vertices, mask_words] = masks.unwrap_or_else(|| [&buffers[2], &buffers[2]]);
        let bindings = [
            Binding::StorageBuffer(vertices),
            Binding::StorageBuffer(slots),
            Binding::StorageBuffer(mask_vertices),
            Binding::StorageBuffer(mask_words),
            Binding::StorageBuffer(&buffers[0]),
            Binding::StorageBuffer(&buffers[1]),
        ];
        let sets = DescriptorSets::new(ctx, &[(&layout, &bindings)])?;
        Ok(TexturedGBuffer {
            sets,
            pipeline,
            layout,
            buffers,
        })
    }
}

/// The G-buffer pipeline: three color targets and depth, no culling.
fn gbuffer_desc() -> PipelineDesc<'static> {
    PipelineDesc {
        name: "gi gbuffer",
        vert: shaders::GI_GBUFFER_VERT,
        frag: Some(shaders::GI_GBUFFER_FRAG),
        vertex_stride: 0,
        attributes: &[],
        color_formats: &[FLOAT_FORMAT, FLOAT_FORMAT, UNORM_FORMAT],
        color_write: true,
        depth_format: DEPTH_FORMAT,
        depth_compare: vk::CompareOp::LESS,
        depth_write: true,
        cull: vk::CullModeFlags::NONE,
        kind: PipelineKind::Other,
        depth_bias: (0.0, 0.0),
        blend: false,
    }
}
