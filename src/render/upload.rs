//! Uploading a scene to GPU buffers, and the query-box geometry.

use std::sync::Arc;

use ash::vk;
use glam::{Mat4, Vec4};

use crate::error::Result;
use crate::gpu::memory::Buffer;
use crate::gpu::{
    AddressMode, GpuContext, Mips, OneShot, Recorder, Sampler, SamplerModes, Texture,
};
use crate::scene::{SamplerDesc, Scene, TextureImage, Wrap};

/// The scene's GPU buffers.
pub struct UploadedScene {
    /// Shared vertex buffer.
    pub vertices: Buffer,
    /// Shared index buffer.
    pub indices: Buffer,
    /// Per-object data (model, normal matrix, color).
    pub objects: Buffer,
}

pub use crate::gpu::{as_bytes, bytes_of, Pod};

/// Floats of one object's data: model matrix, normal matrix, color, parameters
/// (`shaders/include/scene_objects.glsl`).
pub const OBJECT_FLOATS: usize = 40;

/// One object's data as the scene shaders read it; `unlit`: its material is unlit.
pub fn object_data(transform: &Mat4, color: Vec4, unlit: bool) -> [f32; OBJECT_FLOATS] {
    let mut out = [0.0; OBJECT_FLOATS];
    out[..16].copy_from_slice(&transform.to_cols_array());
    out[16..32].copy_from_slice(&transform.inverse().transpose().to_cols_array());
    out[32..36].copy_from_slice(&color.to_array());
    out[36] = if unlit { 1.0 } else { 0.0 };
    out
}

/// Uploads vertices, indices and per-object data.
pub fn upload_scene(ctx: &Arc<GpuContext>, scene: &Scene) -> Result<UploadedScene> {
    upload_scene_with_spare(ctx, scene, 0)
}

/// [`upload_scene`] with room for `spare` more objects in the per-object buffer (which stays
/// host-visible, so transforms can be rewritten between frames).
pub fn upload_scene_with_spare(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    spare: usize,
) -> Result<UploadedScene> {
    let vertex_bytes = if scene.has_materials() {
        interleaved_vertices(scene)
    } else {
        as_bytes(&scene.vertices)
    };
    let vertices = Buffer::with_data(
        ctx,
        "scene vertices",
        &vertex_bytes,
        vk::BufferUsageFlags::VERTEX_BUFFER,
    )?;
    let indices = Buffer::with_data(
        ctx,
        "scene indices",
        &as_bytes(&scene.indices),
        vk::BufferUsageFlags::INDEX_BUFFER,
    )?;
    let slots = (scene.objects.len() + spare).max(1);
    let mut data: Vec<f32> = Vec::with_capacity(slots * OBJECT_FLOATS);
    for (i, o) in scene.objects.iter().enumerate() {
        data.extend_from_slice(&object_data(&o.transform, o.color, scene.is_unlit(i)));
    }
    data.resize(slots * OBJECT_FLOATS, 0.0);
    let objects = Buffer::with_data(
        ctx,
        "scene objects",
        &as_bytes(&data),
        vk::BufferUsageFlags::STORAGE_BUFFER,
    )?;
    Ok(UploadedScene {
        vertices,
        indices,
        objects,
    })
}

/// Position, normal, texture coordinates and color of every vertex, interleaved
/// ([`super::passes::MATERIAL_VERTEX_STRIDE`] bytes each); vertices without attributes (added
/// after loading, such as movers) get the defaults.
pub fn interleaved_vertices(scene: &Scene) -> Vec<u8> {
    let stride = super::passes::MATERIAL_VERTEX_STRIDE as usize;
    let mut out = Vec::with_capacity(scene.vertices.len() * stride);
    for (i, v) in scene.vertices.iter().enumerate() {
        let a = scene.attributes.get(i).copied().unwrap_or_default();
        out.extend_from_slice(bytes_of(&v.position));
        out.extend_from_slice(bytes_of(&v.normal));
        out.extend_from_slice(bytes_of(&a.uv));
        out.extend_from_slice(&a.color);
    }
    out
}

/// A scene's textures on the GPU: one texture per image (with its mip chain), one sampler per
/// scene texture, and a 1x1 white texture for objects without one. Binding route: one combined
/// image sampler per descriptor set, one set per scene texture (set 0 is the white one), bound
/// per object when it changes (no descriptor indexing needed; every bind is counted).
pub struct SceneMaterials {
    /// Samplers, one per scene texture, then the white texture's.
    pub samplers: Vec<Sampler>,
    /// Images, one per scene image, then the white one.
    pub images: Vec<Texture>,
    /// Whether mips were blitted on the device (else made on the CPU).
    pub blitted_mips: bool,
}

/// Our sampler modes for a scene sampler.
pub fn sampler_modes(s: &SamplerDesc) -> SamplerModes {
    let wrap = |w: Wrap| match w {
        Wrap::Repeat => AddressMode::Repeat,
        Wrap::MirroredRepeat => AddressMode::MirroredRepeat,
        Wrap::ClampToEdge => AddressMode::ClampToEdge,
    };
    SamplerModes {
        wrap_u: wrap(s.wrap_u),
        wrap_v: wrap(s.wrap_v),
        mag_linear: s.mag_linear,
        min_linear: s.min_linear,
        mipmaps: s.mipmaps,
        mip_linear: s.mip_linear,
    }
}

impl SceneMaterials {
    /// Uploads every image of `scene` (halved on the CPU while larger than
    /// maxImageDimension2D) with a full mip chain: blitted with linear filtering when the
    /// device supports it for the texture format, else made on the CPU (a box filter in linear
    /// space).
    pub fn upload(
        ctx: &Arc<GpuContext>,
        oneshot: &mut OneShot,
        recorder: &mut Recorder,
        scene: &Scene,
    ) -> Result<SceneMaterials> {
        let blit = Texture::can_blit_mips(ctx);
        let white = TextureImage {
            width: 1,
            height: 1,
            rgba: vec![255; 4],
        };
        let mut images = Vec::with_capacity(scene.images.len() + 1);
        for (i, img) in scene.images.iter().chain([&white]).enumerate() {
            let name = format!("texture image {i}");
            images.push(upload_image(ctx, oneshot, recorder, &name, img, blit)?);
        }
        let mut samplers = Vec::with_capacity(scene.textures.len() + 1);
        for t in &scene.textures {
            samplers.push(Sampler::with_modes(ctx, &sampler_modes(&t.sampler))?);
        }
        samplers.push(Sampler::with_modes(
            ctx,
            &sampler_modes(&SamplerDesc::default()),
        )?);
        Ok(SceneMaterials {
            samplers,
            images,
            blitted_mips: blit,
        })
    }

    /// The (image, sampler) of each descriptor set: set 0 the white texture, set 1 + t the
    /// scene's texture t.
    pub fn set_textures(&self, scene: &Scene) -> Vec<(&Texture, &Sampler)> {
        let (white_image, white_sampler) = (self.images.len() - 1, self.samplers.len() - 1);
        let mut out = vec![(&self.images[white_image], &self.samplers[white_sampler])];
        for (t, tex) in scene.textures.iter().enumerate() {
            let image = (tex.image as usize).min(white_image);
            out.push((&self.images[image], &self.samplers[t]));
        }
        out
    }
}

fn upload_image(
    ctx: &Arc<GpuContext>,
    oneshot: &mut OneShot,
    recorder: &mut Recorder,
    name: &str,
    img: &TextureImage,
    blit: bool,
) -> Result<Texture> {
    let max = ctx.info.max_image_dimension_2d.max(1);
    let mut level0 = img.clone();
    while level0.width > max || level0.height > max {
        level0 = level0.halved();
    }
    let size = (level0.width, level0.height);
    if blit {
        return Texture::upload(ctx, oneshot, recorder, name, size, &level0.rgba, Mips::Blit);
    }
    let rest: Vec<Vec<u8>> = level0.mip_chain().into_iter().map(|l| l.rgba).collect();
    Texture::upload(
        ctx,
        oneshot,
        recorder,
        name,
        size,
        &level0.rgba,
        Mips::Given(&rest),
    )
}
