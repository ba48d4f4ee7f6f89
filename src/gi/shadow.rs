//! Layered paraboloid shadow maps: one D32 2D-array image with a layer per VPL plus one for the
//! spotlight, rendered in one layered pass per frame (gl_Layer from the vertex shader, one
//! instance per shadow slot). Only the layers of this frame's new VPLs are cleared and drawn.
//! When the array has more layers than one rendering may span (`maxFramebufferLayers`), the
//! maps are rendered in chunks through the staging image (at most its layers per rendering,
//! which is within the limit) and copied into the array.

use std::sync::Arc;

use ash::vk;

use crate::error::{Error, Result};
use crate::gi::geometry::{SharedCorners, VERTEX_FLOATS};
use crate::gpu::{
    as_bytes, shaders, Attachment, Binding, Buffer, DescriptorSet, DescriptorSets, GpuContext,
    Image, ImageUse, Load, Pipeline, PipelineDesc, PipelineKind, PipelineLayout, Recorder,
};

/// Shadow-map depth format.
pub const SHADOW_FORMAT: vk::Format = vk::Format::D32_SFLOAT;
/// Layers of the staging image: a pass that renders at most this many maps (the spotlight's
/// included) renders them there and copies them into the array, so the rendering spans a few
/// layers instead of all of them (lavapipe's cost grows with a rendering's layers).
pub const STAGING_LAYERS: u32 = 16;

/// One shadow map to render this pass: an origin, the hemisphere's axis and its layer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShadowSlot {
    /// Centre of projection (VPL or light position).
    pub position: glam::Vec3,
    /// Hemisphere axis (VPL normal or light direction).
    pub normal: glam::Vec3,
    /// Array layer written.
    pub layer: u32,
}

impl ShadowSlot {
    /// The std430 layout of the shader's `Slot` (two vec4).
    pub fn to_floats(self) -> [f32; 8] {
        let (p, n) = (self.position, self.normal);
        [p.x, p.y, p.z, self.layer as f32, n.x, n.y, n.z, 0.0]
    }
}

/// The layered shadow-map array and its pipeline.
pub struct ShadowMaps {
    /// Pipeline first so it is dropped before anything it refers to.
    pipeline: Pipeline,
    /// For scenes with alpha masks: the pipeline that discards masked-out texels, used
    /// instead of `pipeline` (see [`ShadowMaps::enable_masks`]).
    masked: Option<MaskedShadow>,
    /// On devices with `shaderClipDistance`, scenes without masks: the indexed mesh and its
    /// pipeline, used instead of `pipeline` (see [`ShadowMaps::enable_indexed`]).
    indexed: Option<IndexedShadow>,
    /// The D32 array: layers `0..vpl_layers` for VPLs, layer `vpl_layers` for the spotlight.
    pub image: Image,
    /// Small passes render here first (layer 0 the spotlight, then the VPLs in order).
    staging: Image,
    /// Width and height of each layer.
    pub size: u32,
    /// Layers available to VPLs.
    pub vpl_layers: u32,
    /// The device's `maxFramebufferLayers`: most layers one rendering may span.
    max_pass_layers: u32,
}

impl ShadowMaps {
    /// Creates `vpl_layers + 1` layers of `size`² texels and the layered pipeline.
    pub fn new(
        ctx: &Arc<GpuContext>,
        layout: &PipelineLayout,
        vpl_layers: u32,
        size: u32,
    ) -> Result<ShadowMaps> {
        let layers = vpl_layers.saturating_add(1);
        // A rendering over more layers than `maxFramebufferLayers` is split (see `staged`);
        // the array itself must fit `maxImageArrayLayers` (the spec guarantees 256 of each).
        let max_pass_layers = ctx.info.max_framebuffer_layers;
        if max_pass_layers < 2 {
            return Err(Error::Unsupported {
                feature: format!(
                    "layered rendering over 2 layers (the device's maxFramebufferLayers is \
                     {max_pass_layers})"
                ),
            });
        }
        if layers > ctx.info.max_image_array_layers {
            return Err(Error::Input(format!(
                "{vpl_layers} VPL shadow maps (+1 for the spotlight) exceed the device's {} array layers",
                ctx.info.max_image_array_layers
            )));
        }
        let image = Image::new(
            ctx,
            "vpl shadow maps",
            SHADOW_FORMAT,
            (size, size),
            layers,
            vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT
                | vk::ImageUsageFlags::SAMPLED
                | vk::ImageUsageFlags::TRANSFER_DST,
        )?;
        let staging = Image::new(
            ctx,
            "shadow map staging",
            SHADOW_FORMAT,
            (size, size),
            STAGING_LAYERS.min(layers).min(max_pass_layers).max(2),
            vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT | vk::ImageUsageFlags::TRANSFER_SRC,
        )?;
        let pipeline = Pipeline::graphics(ctx, layout, &shadow_desc(ctx))?;
        Ok(ShadowMaps {
            pipeline,
            masked: None,
            indexed: None,
            image,
            staging,
            size,
            vpl_layers,
            max_pass_layers,
        })
    }

    /// Draws every later pass with the masked pipeline: `masks` holds the vec4 per vertex of
    /// `vertices` and the packed images (see `TriangleMasks::gpu_data`); `slots` is the slot
    /// buffer the passes read; `push_size` the graphics push block's size.
    pub fn enable_masks(
        &mut self,
        ctx: &Arc<GpuContext>,
        push_size: u32,
        vertices: &Buffer,
        slots: &Buffer,
        masks: &(Vec<f32>, Vec<u32>),
    ) -> Result<()> {
        self.masked = Some(MaskedShadow::new(ctx, push_size, vertices, slots, masks)?);
        Ok(())
    }

    /// Draws later passes indexed over the renderer's vertex buffer (`vertex_floats`, its
    /// contents, [`VERTEX_FLOATS`] per vertex, position first), the position read as a vertex
    /// attribute: corners at the same position share an index, so the vertex stage (lavapipe's
    /// bottleneck in this pass) runs about once per vertex instead of three times per
    /// triangle. Needs `shaderClipDistance` (the indexed shader clips in fixed function);
    /// without it, or with masks enabled, this does nothing and the passes pull the vertices
    /// as before.
    pub fn enable_indexed(
        &mut self,
        ctx: &Arc<GpuContext>,
        layout: &PipelineLayout,
        vertex_floats: &[f32],
    ) -> Result<()> {
        if !ctx.info.optional.shader_clip_distance || self.masked.is_some() {
            return Ok(());
        }
        let pipeline = Pipeline::graphics(
            ctx,
            layout,
            &PipelineDesc {
                name: "gi shadow indexed",
                vert: shaders::GI_SHADOW_INDEXED_VERT,
                vertex_stride: (VERTEX_FLOATS * 4) as u32,
                attributes: &[(0, vk::Format::R32G32B32_SFLOAT, 0)],
                ..shadow_desc(ctx)
            },
        )?;
        let indices = SharedCorners::new(ctx, "gi shadow indices", vertex_floats)?;
        self.indexed = Some(IndexedShadow { pipeline, indices });
        Ok(())
    }

    /// Rewrites the indexed pass's indices after the vertices from `first_vertex` on changed
    /// (`vertex_floats` is the whole buffer's new contents, as in [`ShadowMaps::enable_indexed`];
    /// the same vertex count): only those vertices are hashed again. Nothing to do when the
    /// pass is not indexed. Call between frames, after vertices moved.
    pub fn reindex(&mut self, vertex_floats: &[f32], first_vertex: usize) -> Result<()> {
        match &mut self.indexed {
            Some(ix) => ix.indices.rewrite(vertex_floats, first_vertex),
            None => Ok(()),
        }
    }

    /// Renders later passes with the exact variant, which clips at the base plane in the
    /// vertex shader and pulls all three corners of each triangle (what devices without
    /// `shaderClipDistance` always run): drops the indexed mesh and rebuilds the pipelines.
    /// Slower; for comparing the two variants.
    pub fn use_exact_clipping(
        &mut self,
        ctx: &Arc<GpuContext>,
        layout: &PipelineLayout,
    ) -> Result<()> {
        self.indexed = None;
        self.pipeline = Pipeline::graphics(
            ctx,
            layout,
            &PipelineDesc {
                vert: shaders::GI_SHADOW_EXACT_VERT,
                ..shadow_desc(ctx)
            },
        )?;
        if let Some(m) = &mut self.masked {
            m.pipeline = Pipeline::graphics(
                ctx,
                &m.layout,
                &PipelineDesc {
                    vert: shaders::GI_SHADOW_MASKED_EXACT_VERT,
                    ..MaskedShadow::desc(ctx)
                },
            )?;
        }
        Ok(())
    }

    /// Whether the passes draw the indexed mesh (see [`ShadowMaps::enable_indexed`]).
    pub fn indexed(&self) -> bool {
        self.indexed.is_some()
    }

    /// Whether the passes discard masked-out texels.
    pub fn masked(&self) -> bool {
        self.masked.is_some()
    }

    /// The masked passes' layout and set (vertices, slots, mask per vertex, mask images), when
    /// masks are enabled: the G-buffer's masked pipeline draws with them too.
    pub fn masked_set(&self) -> Option<(&PipelineLayout, DescriptorSet)> {
        self.masked.as_ref().map(|m| (&m.layout, m.sets.get(0)))
    }

    /// The masked passes' buffers of mask data (a vec4 per vertex, the packed mask images),
    /// when masks are enabled: the textured G-buffer's masked pipeline reads them too.
    pub fn mask_buffers(&self) -> Option<[&Buffer; 2]> {
        self.masked.as_ref().map(|m| [&m.buffers[0], &m.buffers[1]])
    }

    /// The spotlight's layer.
    pub fn spot_layer(&self) -> u32 {
        self.vpl_layers
    }

    /// Whether a pass of `vpl_maps` VPL maps (plus the spotlight's) renders into the staging
    /// image: when they fit it, or when the whole array is more layers than one rendering may
    /// span (then in chunks of [`ShadowMaps::staged_layer`]'s batch). Staged, the spotlight's
    /// slot must name layer 0 and the VPLs' slots the layers [`ShadowMaps::staged_layer`]
    /// gives, in the order of the pass's layers.
    pub fn staged(&self, vpl_maps: usize) -> bool {
        vpl_maps < self.staging.layers as usize || self.vpl_layers + 1 > self.max_pass_layers
    }

    /// The staging layer of the `i`-th VPL map of a staged pass: chunks of the staging
    /// image's layers after the spotlight's (layer 0), so 1, 2, .., then 1, 2, .. again.
    pub fn staged_layer(&self, i: usize) -> u32 {
        (i as u32 % (self.staging.layers - 1)) + 1
    }

    /// Records one layered pass (or its chunks, see [`ShadowMaps::staged`]) that clears and
    /// renders the spotlight's layer and the layers of `vpl_slots` (slots `first_slot + 1 ..` of the bound slot buffer; slot `first_slot` is the
    /// spotlight). `push` is the graphics push block whose params.x/y this sets. Leaves the array
    /// sampled by compute for the gather passes. Returns the number of VPL shadow maps drawn,
    /// counted from the triangles the recorder saw.
    pub fn record(
        &mut self,
        rec: &mut Recorder,
        pass: &ShadowPass,
        push: &mut [f32; 24],
        first_slot: u32,
        vpl_layers: &[u32],
    ) -> Result<u32> {
        if let Some(&bad) = vpl_layers.iter().find(|&&l| l >= self.vpl_layers) {
            return Err(Error::Input(format!(
                "VPL layer {bad} is outside 0..{}",
                self.vpl_layers
            )));
        }
        let maps = if self.staged(vpl_layers.len()) {
            self.record_staged(rec, pass, push, first_slot, vpl_layers)?
        } else {
            self.begin(rec, vpl_layers)?;
            let maps = self.draw(rec, pass, push, first_slot, vpl_layers.len() as u32, true);
            rec.end_rendering();
            maps
        };
        rec.transition(&self.image, ImageUse::SampledByCompute);
        Ok(maps)
    }

    /// Renders the maps through the staging image, in chunks of its layers after the
    /// spotlight's: each chunk is one rendering over at most the staging image's layers (the
    /// spotlight's map at layer 0 in the first, the chunk's VPL maps at 1, 2, ..), then a copy
    /// of those layers into the array. Returns the VPL maps drawn.
    fn record_staged(
        &self,
        rec: &mut Recorder,
        pass: &ShadowPass,
        push: &mut [f32; 24],
        first_slot: u32,
        vpl_layers: &[u32],
    ) -> Result<u32> {
        let batch = (self.staging.layers - 1) as usize;
        let mut maps = 0;
        let mut pairs = Vec::with_capacity(batch + 1);
        for c in 0..vpl_layers.len().div_ceil(batch).max(1) {
            let chunk = &vpl_layers[c * batch..((c + 1) * batch).min(vpl_layers.len())];
            rec.discard(&self.staging, ImageUse::DepthAttachment);
            let depth = Attachment {
                image: &self.staging,
                load: Load::ClearDepth(1.0),
                store: true,
            };
            rec.begin_rendering(&[], Some(depth), chunk.len() as u32 + 1)?;
            // Slot `first`: the spotlight's (drawn in the first chunk only); then the chunk's.
            let first = first_slot + (c * batch) as u32;
            maps += self.draw(rec, pass, push, first, chunk.len() as u32, c == 0);
            rec.end_rendering();
            rec.transition(&self.staging, ImageUse::TransferSrc);
            rec.transition(&self.image, ImageUse::TransferDst);
            pairs.clear();
            if c == 0 {
                pairs.push((0, self.spot_layer()));
            }
            pairs.extend(chunk.iter().enumerate().map(|(i, &l)| (i as u32 + 1, l)));
            rec.copy_layers(&self.staging, &self.image, &pairs)?;
        }
        Ok(maps)
    }

    /// Draws the spotlight's map from slot `first_slot` (when `spot`) and `vpl_maps` VPL maps
    /// from the slots after it (one instance per slot, gl_Layer from the slot). Returns the
    /// VPL maps drawn, counted from the triangles the recorder saw.
    fn draw(
        &self,
        rec: &mut Recorder,
        pass: &ShadowPass,
        push: &mut [f32; 24],
        first_slot: u32,
        vpl_maps: u32,
        spot: bool,
    ) -> u32 {
        if pass.vertex_count == 0 {
            // An empty scene casts no shadow: the cleared layers are its maps.
            return 0;
        }
        let (layout, indexed) = match (&self.masked, &self.indexed) {
            (Some(m), _) => {
                rec.bind_pipeline(&m.pipeline);
                rec.bind_graphics_set(&m.layout, m.sets.get(0));
                (&m.layout, false)
            }
            (None, Some(ix)) => {
                rec.bind_pipeline(&ix.pipeline);
                rec.bind_graphics_set(pass.layout, pass.set);
                rec.bind_buffers(pass.vertices, 0, Some(ix.indices.buffer()));
                (pass.layout, true)
            }
            (None, None) => {
                rec.bind_pipeline(&self.pipeline);
                rec.bind_graphics_set(pass.layout, pass.set);
                (pass.layout, false)
            }
        };
        // The indexed pass has one index per vertex of the renderer's buffer, in order.
        let draw = |rec: &mut Recorder, instances: u32| match indexed {
            true => rec.draw_indexed(pass.vertex_count, instances, 0, 0, 0),
            false => rec.draw(pass.vertex_count, instances),
        };
        push[21] = pass.far;
        if spot {
            push[20] = first_slot as f32;
            rec.push_constants(layout, &as_bytes(&push[..]));
            draw(rec, 1);
        }
        let before = rec.counts.triangles;
        if vpl_maps > 0 {
            push[20] = (first_slot + 1) as f32;
            rec.push_constants(layout, &as_bytes(&push[..]));
            draw(rec, vpl_maps);
        }
        ((rec.counts.triangles - before) / (pass.vertex_count as u64 / 3).max(1)) as u32
    }

    /// Starts the layered rendering over every layer and clears the layers drawn now (the
    /// others keep their maps from earlier frames).
    fn begin(&self, rec: &mut Recorder, vpl_layers: &[u32]) -> Result<()> {
        rec.transition(&self.image, ImageUse::DepthAttachment);
        let depth = Attachment {
            image: &self.image,
            load: Load::Keep,
            store: true,
        };
        rec.begin_rendering(&[], Some(depth), self.vpl_layers + 1)?;
        let spot = std::iter::once(self.spot_layer());
        rec.clear_depth_layers(vpl_layers.iter().copied().chain(spot), 1.0);
        Ok(())
    }
}

/// What a shadow pass draws with: the graphics layout and set (world-space vertices and the
/// slot buffer), the vertex count and the far distance of the paraboloid depth.
pub struct ShadowPass<'a> {
    /// The graphics pipeline layout.
    pub layout: &'a PipelineLayout,
    /// Its descriptor set.
    pub set: DescriptorSet,
    /// The renderer's vertex buffer (bound as vertex input by the indexed pass; the others pull
    /// it through the set).
    pub vertices: &'a Buffer,
    /// World-space vertices to draw.
    pub vertex_count: u32,
    /// Depth normalization distance.
    pub far: f32,
}

/// The masked shadow pipeline and what it reads: set 0 = (vertices, slots, mask per vertex,
/// packed mask images), the same push block as the opaque pass. Four storage buffers, the
/// minimum every device allows per stage (`maxPerStageDescriptorStorageBuffers` >= 4).
struct MaskedShadow {
    // Sets and the pipeline before the layout, buffers last.
    sets: DescriptorSets,
    pipeline: Pipeline,
    layout: PipelineLayout,
    /// Owned here; the set points at them (and the textured G-buffer's, through
    /// [`ShadowMaps::mask_buffers`]).
    buffers: [Buffer; 2],
}

impl MaskedShadow {
    /// The masked pipeline: the fast vertex variant where the device has `shaderClipDistance`.
    fn desc(ctx: &GpuContext) -> PipelineDesc<'static> {
        PipelineDesc {
            name: "gi shadow masked",
            vert: clip_variant(
                ctx,
                shaders::GI_SHADOW_MASKED_VERT,
                shaders::GI_SHADOW_MASKED_EXACT_VERT,
            ),
            frag: Some(shaders::GI_SHADOW_MASKED_FRAG),
            ..shadow_desc(ctx)
        }
    }

    fn new(
        ctx: &Arc<GpuContext>,
        push_size: u32,
        vertices: &Buffer,
        slots: &Buffer,
        (mask_vertices, words): &(Vec<f32>, Vec<u32>),
    ) -> Result<MaskedShadow> {
        let storage = vk::DescriptorType::STORAGE_BUFFER;
        let layout = PipelineLayout::new(ctx, &[storage; 4], push_size)?;
        let buffers = [
            Buffer::storage_with(ctx, "gi shadow mask vertices", &as_bytes(mask_vertices))?,
            Buffer::storage_with(ctx, "gi shadow mask images", &as_bytes(words))?,
        ];
        let pipeline = Pipeline::graphics(ctx, &layout, &MaskedShadow::desc(ctx))?;
        let bindings = [
            Binding::StorageBuffer(vertices),
            Binding::StorageBuffer(slots),
            Binding::StorageBuffer(&buffers[0]),
            Binding::StorageBuffer(&buffers[1]),
        ];
        let sets = DescriptorSets::new(ctx, &[(&layout, &bindings)])?;
        Ok(MaskedShadow {
            sets,
            pipeline,
            layout,
            buffers,
        })
    }
}

/// The indexed shadow pass: indices into the renderer's vertex buffer, each corner pointing at
/// the first vertex with the same position; the position is read as a vertex attribute. The
/// vertex stage then runs once per shared vertex (within the driver's vertex cache), where the
/// pulled variant runs three times per triangle and reads all three corners.
struct IndexedShadow {
    pipeline: Pipeline,
    /// Corners at one position share an index.
    indices: SharedCorners<3>,
}

/// The vertex shader that clips at the base plane with `gl_ClipDistance` (`fast`) where the
/// device has `shaderClipDistance`, else the one that clips in the shader (`exact`).
fn clip_variant(ctx: &GpuContext, fast: &'static [u8], exact: &'static [u8]) -> &'static [u8] {
    match ctx.info.optional.shader_clip_distance {
        true => fast,
        false => exact,
    }
}

/// The opaque shadow pipeline: depth only, no culling, no bias. Its vertex shader clips at
/// the hemisphere's base plane with `gl_ClipDistance` where the device has
/// `shaderClipDistance`, else in the shader (see include/gi_shadow_vertex.glsl).
fn shadow_desc(ctx: &GpuContext) -> PipelineDesc<'static> {
    PipelineDesc {
        name: "gi shadow",
        vert: clip_variant(ctx, shaders::GI_SHADOW_VERT, shaders::GI_SHADOW_EXACT_VERT),
        frag: None,
        vertex_stride: 0,
        attributes: &[],
        color_formats: &[],
        color_write: false,
        depth_format: SHADOW_FORMAT,
        depth_compare: vk::CompareOp::LESS,
        depth_write: true,
        // The paraboloid map can flip winding; both sides occlude.
        cull: vk::CullModeFlags::NONE,
        kind: PipelineKind::Other,
        // The bias is applied at lookup time (distance-proportional, see gi_gather.comp).
        depth_bias: (0.0, 0.0),
        blend: false,
    }
}
