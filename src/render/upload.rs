//! Uploading a scene to GPU buffers, and the query-box geometry.

use std::sync::Arc;

use ash::vk;
use glam::{Mat4, Vec3, Vec4};

use crate::error::Result;
use crate::gpu::memory::Buffer;
use crate::gpu::GpuContext;
use crate::scene::{Aabb, Scene};

/// The scene's GPU buffers.
pub struct UploadedScene {
    /// Shared vertex buffer.
    pub vertices: Buffer,
    /// Shared index buffer.
    pub indices: Buffer,
    /// Per-object data (model, normal matrix, color).
    pub objects: Buffer,
}

pub use crate::gpu::{as_bytes, Pod};

/// Floats of one object's data: model matrix, normal matrix, color.
pub const OBJECT_FLOATS: usize = 36;

/// One object's data as the scene shaders read it.
pub fn object_data(transform: &Mat4, color: Vec4) -> [f32; OBJECT_FLOATS] {
    let mut out = [0.0; OBJECT_FLOATS];
    out[..16].copy_from_slice(&transform.to_cols_array());
    out[16..32].copy_from_slice(&transform.inverse().transpose().to_cols_array());
    out[32..].copy_from_slice(&color.to_array());
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
    let vertices = Buffer::with_data(
        ctx,
        "scene vertices",
        &as_bytes(&scene.vertices),
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
    for o in &scene.objects {
        data.extend_from_slice(&object_data(&o.transform, o.color));
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

/// Indices for `n` boxes of 8 corners each (corner c = x | y << 1 | z << 2), 12 triangles each.
pub fn box_indices(n: u32) -> Vec<u32> {
    const FACES: [u32; 36] = [
        0, 2, 1, 1, 2, 3, // -z
        4, 5, 6, 5, 7, 6, // +z
        0, 1, 4, 1, 5, 4, // -y
        2, 6, 3, 3, 6, 7, // +y
        0, 4, 2, 2, 4, 6, // -x
        1, 3, 5, 3, 7, 5, // +x
    ];
    (0..n)
        .flat_map(|b| FACES.iter().map(move |i| i + 8 * b))
        .collect()
}

/// Appends the world-space corners of `boxes` (8 per box) to `out`.
pub fn box_corners_into(boxes: &[Aabb], out: &mut Vec<[f32; 3]>) {
    for b in boxes {
        for c in 0..8 {
            let p = Vec3::new(
                if c & 1 == 0 { b.min.x } else { b.max.x },
                if c & 2 == 0 { b.min.y } else { b.max.y },
                if c & 4 == 0 { b.min.z } else { b.max.z },
            );
            out.push(p.to_array());
        }
    }
}
