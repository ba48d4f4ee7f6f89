//! Layered paraboloid shadow maps: one D32 2D-array image with a layer per VPL plus one for the
//! spotlight, rendered in one layered pass per frame (gl_Layer from the vertex shader, one
//! instance per shadow slot). Only the layers of this frame's new VPLs are cleared and drawn.

use std::sync::Arc;

use ash::vk;

use crate::error::{Error, Result};
use crate::gpu::commands::image_barrier;
use crate::gpu::memory::Image;
use crate::gpu::pipelines::{Pipeline, PipelineDesc, PipelineKind, PipelineLayout};
use crate::gpu::{GpuContext, Recorder};

/// Shadow-map depth format.
pub const SHADOW_FORMAT: vk::Format = vk::Format::D32_SFLOAT;

const SHADOW_VERT: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/gi_shadow.vert.spv"));

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
    /// The D32 array: layers `0..vpl_layers` for VPLs, layer `vpl_layers` for the spotlight.
    pub image: Image,
    /// Width and height of each layer.
    pub size: u32,
    /// Layers available to VPLs.
    pub vpl_layers: u32,
    /// Whether the image has left the UNDEFINED layout.
    initialized: bool,
}

impl ShadowMaps {
    /// Creates `vpl_layers + 1` layers of `size`² texels and the layered pipeline.
    pub fn new(
        ctx: &Arc<GpuContext>,
        layout: &PipelineLayout,
        vpl_layers: u32,
        size: u32,
    ) -> Result<ShadowMaps> {
        let layers = vpl_layers + 1;
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
            vk::Extent2D {
                width: size,
                height: size,
            },
            layers,
            vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT | vk::ImageUsageFlags::SAMPLED,
        )?;
        let pipeline = Pipeline::graphics(
            ctx,
            layout,
            &PipelineDesc {
                name: "gi shadow",
                vert: SHADOW_VERT,
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
            },
        )?;
        Ok(ShadowMaps {
            pipeline,
            image,
            size,
            vpl_layers,
            initialized: false,
        })
    }

    /// The spotlight's layer.
    pub fn spot_layer(&self) -> u32 {
        self.vpl_layers
    }

    /// Records one layered pass that clears and renders the spotlight's layer and the layers of
    /// `vpl_slots` (slots `first_slot + 1 ..` of the bound slot buffer; slot `first_slot` is the
    /// spotlight). `push` is the graphics push block whose params.x/y this sets. Leaves the array
    /// in SHADER_READ_ONLY_OPTIMAL for the gather passes. Returns the number of VPL shadow maps
    /// drawn, counted from the triangles the recorder saw.
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &mut self,
        rec: &mut Recorder,
        layout: &PipelineLayout,
        set: vk::DescriptorSet,
        push: &mut [f32; 24],
        first_slot: u32,
        vpl_layers: &[u32],
        vertex_count: u32,
        far: f32,
    ) -> Result<u32> {
        let layer_count = self.vpl_layers + 1;
        // Lavapipe crashes instead of reporting a render whose layerCount exceeds an attachment's
        // layers, so check it here.
        if layer_count > self.image.layers {
            return Err(Error::Input(format!(
                "layered shadow pass over {layer_count} layers, but the attachment has {}",
                self.image.layers
            )));
        }
        if let Some(&bad) = vpl_layers.iter().find(|&&l| l >= self.vpl_layers) {
            return Err(Error::Input(format!(
                "VPL layer {bad} is outside 0..{}",
                self.vpl_layers
            )));
        }
        let depth_stages = vk::PipelineStageFlags2::EARLY_FRAGMENT_TESTS
            | vk::PipelineStageFlags2::LATE_FRAGMENT_TESTS;
        let attachment = (
            vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL,
            depth_stages,
            vk::AccessFlags2::DEPTH_STENCIL_ATTACHMENT_WRITE
                | vk::AccessFlags2::DEPTH_STENCIL_ATTACHMENT_READ,
        );
        let sampled = (
            vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL,
            vk::PipelineStageFlags2::COMPUTE_SHADER,
            vk::AccessFlags2::SHADER_SAMPLED_READ,
        );
        let from = if self.initialized {
            sampled
        } else {
            (
                vk::ImageLayout::UNDEFINED,
                vk::PipelineStageFlags2::NONE,
                vk::AccessFlags2::NONE,
            )
        };
        rec.barrier(
            &[image_barrier(
                self.image.handle,
                self.image.full_range(),
                from,
                attachment,
            )],
            &[],
        );
        self.initialized = true;
        let extent = vk::Extent2D {
            width: self.size,
            height: self.size,
        };
        let depth_att = vk::RenderingAttachmentInfo::default()
            .image_view(self.image.view)
            .image_layout(vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL)
            .load_op(vk::AttachmentLoadOp::LOAD)
            .store_op(vk::AttachmentStoreOp::STORE);
        let info = vk::RenderingInfo::default()
            .render_area(vk::Rect2D {
                offset: vk::Offset2D::default(),
                extent,
            })
            .layer_count(layer_count)
            .depth_attachment(&depth_att);
        rec.begin_rendering(&info);
        rec.set_viewport(extent);
        // Clear only the layers drawn now; the others keep their maps from earlier frames.
        let clear = [vk::ClearAttachment {
            aspect_mask: vk::ImageAspectFlags::DEPTH,
            color_attachment: 0,
            clear_value: vk::ClearValue {
                depth_stencil: vk::ClearDepthStencilValue {
                    depth: 1.0,
                    stencil: 0,
                },
            },
        }];
        let rects: Vec<vk::ClearRect> = vpl_layers
            .iter()
            .chain(std::iter::once(&self.vpl_layers))
            .map(|&l| vk::ClearRect {
                rect: vk::Rect2D {
                    offset: vk::Offset2D::default(),
                    extent,
                },
                base_array_layer: l,
                layer_count: 1,
            })
            .collect();
        rec.clear_attachments(&clear, &rects);
        rec.bind_pipeline(&self.pipeline);
        rec.bind_descriptor_set(vk::PipelineBindPoint::GRAPHICS, layout.handle, set);
        let stages = vk::ShaderStageFlags::VERTEX
            | vk::ShaderStageFlags::FRAGMENT
            | vk::ShaderStageFlags::COMPUTE;
        push[20] = first_slot as f32;
        push[21] = far;
        rec.push_constants(
            layout.handle,
            stages,
            &crate::render::upload::as_bytes(&push[..]),
        );
        rec.draw(vertex_count, 1);
        let before = rec.counts.triangles;
        if !vpl_layers.is_empty() {
            push[20] = (first_slot + 1) as f32;
            rec.push_constants(
                layout.handle,
                stages,
                &crate::render::upload::as_bytes(&push[..]),
            );
            rec.draw(vertex_count, vpl_layers.len() as u32);
        }
        let maps = (rec.counts.triangles - before) / (vertex_count as u64 / 3).max(1);
        rec.end_rendering();
        rec.barrier(
            &[image_barrier(
                self.image.handle,
                self.image.full_range(),
                attachment,
                sampled,
            )],
            &[],
        );
        Ok(maps as u32)
    }
}
