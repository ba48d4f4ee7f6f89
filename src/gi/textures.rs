//! Base color textures in the GI's G-buffer: per triangle of a textured material, the texture
//! coordinates and the color without the texture (base color factor x vertex color) of its
//! corners, and the images, each with its mip chain from a level no larger than
//! [`MAX_EDGE`] texels, read as the sampler says (filters within and between levels, wrap
//! modes). The G-buffer pass (`gi_gbuffer_textured*.frag`) reads the albedo of
//! each pixel from them, so the image shows the texture; the VPLs and the ray caster keep one
//! albedo per triangle, its texture averaged over it ([`WorldGeometry::albedo`]).
//!
//! [`WorldGeometry::albedo`]: crate::gi::geometry::WorldGeometry::albedo

use std::sync::Arc;

use glam::{Vec2, Vec3};

use crate::scene::mask::{append_sparse, numbered, push_sparse, shader_image, wrap_bits};
use crate::scene::material::srgb_to_linear;
use crate::scene::{SamplerDesc, Scene, TextureImage};

/// The largest edge of an image's first level in the G-buffer's data: larger images are taken
/// from their mip chain (a G-buffer pixel rarely needs more, and a scene's textures stay a few
/// MiB each).
pub const MAX_EDGE: u32 = 512;

/// The G-buffer's texture data of all images together is kept under this many bytes (and
/// under the device's `maxStorageBufferRange`): larger, every image is taken from its next
/// level down until it fits.
pub const MAX_BYTES: u64 = 64 << 20;

/// What the G-buffer reads of one textured triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TexturedTriangle {
    /// Index of the scene image ([`TriangleTextures::images`]), or [`NO_IMAGE`].
    pub image: u32,
    /// The sampler's wrap modes and filters as the shader's flag bits ([`sampler_bits`]).
    pub sampler: u32,
    /// Texture coordinates of the corners.
    pub uv: [Vec2; 3],
    /// Linear color of the corners without the texture: base color factor x vertex color.
    pub color: [Vec3; 3],
}

/// No texture: the G-buffer takes the triangle's albedo.
pub const NO_IMAGE: u32 = u32::MAX;

impl TexturedTriangle {
    /// A triangle without a texture.
    pub const NONE: TexturedTriangle = TexturedTriangle {
        image: NO_IMAGE,
        sampler: 0,
        uv: [Vec2::ZERO; 3],
        color: [Vec3::ONE; 3],
    };

    /// Whether the triangle has no texture.
    pub fn is_none(&self) -> bool {
        self.image == NO_IMAGE
    }

    /// The part of the triangle whose corners have barycentric weights `w` (rows: the new
    /// corners) in this one.
    pub fn sub(&self, w: [Vec3; 3]) -> TexturedTriangle {
        let uv = w.map(|w| self.uv[0] * w.x + self.uv[1] * w.y + self.uv[2] * w.z);
        let color = w.map(|w| self.color[0] * w.x + self.color[1] * w.y + self.color[2] * w.z);
        TexturedTriangle { uv, color, ..*self }
    }
}

/// The textures of a [`WorldGeometry`](crate::gi::geometry::WorldGeometry)'s triangles:
/// `triangles` is parallel to its triangles, or empty when none is textured (then nothing
/// costs anything).
#[derive(Clone, Debug, Default)]
pub struct TriangleTextures {
    /// One per triangle, or none at all.
    pub triangles: Vec<TexturedTriangle>,
    /// The scene's images by index, each its mip chain from the level no larger than
    /// [`MAX_EDGE`] down to 1x1 (`None`: used by no textured triangle).
    pub images: Arc<Vec<Option<Vec<TextureImage>>>>,
}

impl TriangleTextures {
    /// Whether any triangle is textured.
    pub fn any(&self) -> bool {
        !self.triangles.is_empty()
    }

    /// Appends one triangle's texture (`None`: untextured), keeping `triangles` empty while
    /// no triangle so far is textured. `count` is the number of triangles before this one.
    pub fn push(&mut self, count: usize, texture: Option<TexturedTriangle>) {
        let texture = texture.filter(|t| !t.is_none());
        push_sparse(&mut self.triangles, count, texture, TexturedTriangle::NONE);
    }

    /// Appends a piece of `source`'s triangle `index` whose corners are the weights `w` of
    /// its corners, after `count` triangles of this geometry.
    pub fn push_piece(
        &mut self,
        count: usize,
        source: &TriangleTextures,
        index: usize,
        w: [Vec3; 3],
    ) {
        let t = source.triangles.get(index).map(|t| t.sub(w));
        self.push(count, t);
    }

    /// Appends `other`'s textures after `count` triangles of this geometry. Both index the
    /// same scene's images (the same scene's geometries are appended); this one takes the
    /// images `other` has and it lacks.
    pub fn append(&mut self, count: usize, other: &TriangleTextures, other_count: usize) {
        let none = TexturedTriangle::NONE;
        append_sparse(
            &mut self.triangles,
            count,
            &other.triangles,
            other_count,
            none,
        );
        if !other.any() {
            return;
        }
        if self.images.iter().all(Option::is_none) {
            self.images = other.images.clone();
            return;
        }
        let lacks = |(i, o): (usize, &Option<Vec<TextureImage>>)| {
            o.is_some() && self.images.get(i).is_none_or(Option::is_none)
        };
        if other.images.iter().enumerate().any(lacks) {
            let images = Arc::make_mut(&mut self.images);
            if images.len() < other.images.len() {
                images.resize(other.images.len(), None);
            }
            for (mine, theirs) in images.iter_mut().zip(other.images.iter()) {
                if mine.is_none() {
                    mine.clone_from(theirs);
                }
            }
        }
    }

    /// The texture of a triangle of `scene`'s object `object` with the given corner
    /// attribute indices, or `None` when its material has no usable base color texture.
    /// `levels` gives an image's mip chain from its level no larger than [`MAX_EDGE`] down to
    /// 1x1 the first time it is used.
    pub fn for_triangle<'a>(
        &mut self,
        scene: &'a Scene,
        object: usize,
        corners: [usize; 3],
        levels: impl FnOnce(&'a TextureImage) -> Vec<TextureImage>,
    ) -> Option<TexturedTriangle> {
        let material = scene.object_material(object)?;
        let texture = scene.textures.get(material.base_color_texture? as usize)?;
        let image = scene.images.get(texture.image as usize)?;
        if !image.has_texels() {
            return None;
        }
        let slot = texture.image as usize;
        if self.images.get(slot).is_none_or(Option::is_none) {
            let images = Arc::make_mut(&mut self.images);
            if images.len() < scene.images.len() {
                images.resize(scene.images.len(), None);
            }
            images[slot] = Some(levels(image));
        }
        let factor = scene.objects[object].color.truncate();
        let a = corners.map(|i| scene.attributes.get(i).copied().unwrap_or_default());
        Some(TexturedTriangle {
            image: texture.image,
            sampler: sampler_bits(&texture.sampler),
            uv: a.map(|v| Vec2::from(v.uv)),
            color: a.map(|v| factor * v.color().truncate()),
        })
    }

    /// What the textured G-buffer pass reads, or `None` when no triangle is textured: per GPU
    /// vertex (three per triangle, in order) two vec4, (u, v, image or -1, sampler bits) and
    /// (color, 0); and the images as 32-bit words ([`pack_images`], within `max_bytes`).
    /// `triangle_count` is the geometry's (triangles after the last textured one have none).
    pub fn gpu_data(&self, triangle_count: usize, max_bytes: u64) -> Option<(Vec<f32>, Vec<u32>)> {
        if !self.any() {
            return None;
        }
        let (words, index) = pack_images(&self.images, max_bytes);
        let mut vertices = Vec::with_capacity(triangle_count * 24);
        let none = std::iter::repeat(&TexturedTriangle::NONE);
        for t in self.triangles.iter().chain(none).take(triangle_count) {
            let image = shader_image(&index, t.image);
            for k in 0..3 {
                let (uv, c) = (t.uv[k], t.color[k]);
                vertices.extend_from_slice(&[uv.x, uv.y, image, t.sampler as f32]);
                vertices.extend_from_slice(&[c.x, c.y, c.z, 0.0]);
            }
        }
        Some((vertices, words))
    }
}

/// An sRGB-encoded 8-bit value as 8-bit linear.
fn linear(c: u8) -> u8 {
    (srgb_to_linear(c) * 255.0).round() as u8
}

/// A sampler as the textured G-buffer's flag bits: wrap u in bits 0-1, wrap v in bits 2-3,
/// linear magnification (bit 4), linear minification within a level (bit 5), mip levels used
/// (bit 6), linear between levels (bit 7).
pub fn sampler_bits(s: &SamplerDesc) -> u32 {
    wrap_bits(s.wrap_u)
        | wrap_bits(s.wrap_v) << 2
        | u32::from(s.mag_linear) << 4
        | u32::from(s.min_linear) << 5
        | u32::from(s.mipmaps) << 6
        | u32::from(s.mip_linear) << 7
}

/// The images (each a mip chain down to 1x1) as the shader reads them: a header of four words
/// per image (first word of its first level, width and height of that level, number of
/// levels), then each image's levels from one no larger than [`MAX_EDGE`],
/// one after the other from the largest, one word per texel (RGBA8, red in the low byte), the
/// color linear (decoded from sRGB here, so the shader filters without decoding; 8 bits of
/// linear color, as the G-buffer's albedo keeps it). An image whose levels would take the words past `max_bytes` starts one level
/// lower, as do all images larger than it, until they fit (or every image is 1x1). Returns the
/// words and each image index's number in them.
pub fn pack_images(
    images: &[Option<Vec<TextureImage>>],
    max_bytes: u64,
) -> (Vec<u32>, Vec<Option<u32>>) {
    // An image without levels is packed as none.
    let images: Vec<Option<&[TextureImage]>> = (images.iter())
        .map(|c| c.as_deref().filter(|c| !c.is_empty()))
        .collect();
    let chains: Vec<&[TextureImage]> = images.iter().flatten().copied().collect();
    let words_from = |chain: &[TextureImage], first: usize| -> u64 {
        chain[first.min(chain.len() - 1)..]
            .iter()
            .map(|l| u64::from(l.width) * u64::from(l.height))
            .sum()
    };
    // The largest edge allowed: halved while the words do not fit.
    let mut edge = MAX_EDGE;
    let first_level = |chain: &[TextureImage], edge: u32| -> usize {
        chain
            .iter()
            .position(|l| l.width.max(l.height) <= edge)
            .unwrap_or(chain.len() - 1)
    };
    loop {
        let words: u64 = chains
            .iter()
            .map(|c| words_from(c, first_level(c, edge)))
            .sum::<u64>()
            + 4 * chains.len() as u64;
        if words * 4 <= max_bytes || edge <= 1 {
            break;
        }
        edge /= 2;
    }
    let mut words = vec![0u32; chains.len() * 4];
    for (i, chain) in chains.iter().enumerate() {
        let first = first_level(chain, edge);
        let levels = &chain[first..];
        let header = [
            words.len() as u32,
            levels[0].width,
            levels[0].height,
            levels.len() as u32,
        ];
        words[i * 4..i * 4 + 4].copy_from_slice(&header);
        for level in levels {
            words.extend(
                level
                    .rgba
                    .chunks_exact(4)
                    .map(|p| u32::from_le_bytes([linear(p[0]), linear(p[1]), linear(p[2]), p[3]])),
            );
        }
    }
    (words, numbered(&images))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Wrap;

    /// `image` and its mip chain.
    fn chain(image: TextureImage) -> Vec<TextureImage> {
        let rest = image.mip_chain();
        std::iter::once(image).chain(rest).collect()
    }

    fn image(width: u32, height: u32) -> TextureImage {
        TextureImage {
            width,
            height,
            rgba: (0..width * height)
                .flat_map(|i| [i as u8, 0, 255, 255])
                .collect(),
        }
    }

    #[test]
    fn pieces_interpolate_coordinates_and_colors() {
        let t = TexturedTriangle {
            image: 0,
            sampler: 3,
            uv: [Vec2::ZERO, Vec2::X, Vec2::Y],
            color: [Vec3::ONE, Vec3::ZERO, Vec3::X],
        };
        let half = t.sub([Vec3::X, Vec3::new(0.5, 0.5, 0.0), Vec3::Z]);
        assert_eq!(half.uv[1], Vec2::new(0.5, 0.0));
        assert_eq!(half.color[1], Vec3::splat(0.5));
        assert_eq!((half.image, half.sampler), (0, 3));
        let mut all = TriangleTextures::default();
        all.push(0, None);
        all.push(1, Some(TexturedTriangle::NONE));
        assert!(!all.any());
        all.push(2, Some(t));
        all.push(3, None);
        assert_eq!(all.triangles.len(), 4);
        assert!(all.triangles[0].is_none() && !all.triangles[2].is_none());
        // Appended geometries of one scene pool their images.
        let image = |n: u8| TextureImage {
            width: 1,
            height: 1,
            rgba: vec![n; 4],
        };
        all.images = Arc::new(vec![Some(vec![image(1)]), None]);
        let other = TriangleTextures {
            triangles: vec![TexturedTriangle { image: 1, ..t }],
            images: Arc::new(vec![None, Some(vec![image(2)])]),
        };
        let mut pooled = all.clone();
        pooled.append(4, &other, 1);
        assert_eq!(pooled.triangles.len(), 5);
        assert_eq!(
            *pooled.images,
            vec![Some(vec![image(1)]), Some(vec![image(2)])]
        );
        let mut more = TriangleTextures::default();
        more.push_piece(0, &all, 2, [Vec3::X, Vec3::Y, Vec3::Z]);
        more.push_piece(1, &all, 7, [Vec3::X, Vec3::Y, Vec3::Z]);
        assert_eq!(more.triangles, vec![t, TexturedTriangle::NONE]);
    }

    #[test]
    fn packed_images_hold_every_level_within_the_budget() {
        let (words, index) = pack_images(&[None, Some(chain(image(4, 2)))], 1 << 20);
        assert_eq!(index, vec![None, Some(0)]);
        // 4x2, 2x1, 1x1: 11 texels after the header.
        assert_eq!(&words[..4], &[4, 4, 2, 3]);
        assert_eq!(words.len(), 4 + 8 + 2 + 1);
        // Texel 1: sRGB (1, 0, 255) is linear (0.0003, 0, 1).
        assert_eq!(words[5], u32::from_le_bytes([0, 0, 255, 255]));
        assert_eq!(linear(188), 128);
        // Too large for the budget: the image starts at a smaller level.
        let big = chain(image(1024, 1024));
        let (words, _) = pack_images(&[Some(big.clone())], 1 << 20);
        assert!(words.len() * 4 <= 1 << 20, "{}", words.len());
        assert_eq!(&words[1..4], &[256, 256, 9]);
        // At most MAX_EDGE even where the budget allows more.
        let (words, _) = pack_images(&[Some(big)], 64 << 20);
        assert_eq!(&words[1..4], &[MAX_EDGE, MAX_EDGE, 10]);
    }

    #[test]
    fn sampler_bits_follow_the_shader_layout() {
        let s = SamplerDesc {
            wrap_u: Wrap::ClampToEdge,
            wrap_v: Wrap::MirroredRepeat,
            mag_linear: true,
            min_linear: false,
            mipmaps: true,
            mip_linear: true,
        };
        assert_eq!(sampler_bits(&s), 2 | 1 << 2 | 1 << 4 | 1 << 6 | 1 << 7);
    }
}
