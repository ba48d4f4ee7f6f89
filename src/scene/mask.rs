//! Alpha masks (glTF `MASK`) as the GI and the ray caster see them: per triangle, the texture
//! coordinates and the alpha of its corners, and the alpha channels of the masked materials'
//! textures. The shadow maps discard masked-out texels on the GPU, the ray caster lets rays through
//! them and the imperfect shadow maps place no points on them. All three sample level 0 of the
//! texture with the sampler's wrap modes and magnification filter (the render pass's mip chain does
//! not matter for a cutoff test at shadow-map resolution). A scene without masks has none of this.

use std::sync::Arc;

use glam::{Vec2, Vec3};

use super::material::sample_texels;
use super::{AlphaMode, SamplerDesc, Scene, TextureImage, Wrap};

/// No texture: the triangle's alpha is its corners' (base color factor x vertex color).
pub const NO_IMAGE: u32 = u32::MAX;
/// A point is kept when its alpha over the cutoff reaches this: 1 less a little, as the
/// rasterizer's interpolation of three equal corner values may come out an ulp below them
/// (the same constant is in include/gi_mask.glsl).
pub const KEEP: f32 = 1.0 - 1e-4;

/// The mask of one triangle. A point with barycentric weights `w` is kept when
/// `dot(alpha, w) * texture alpha >= 1`: `alpha` is already divided by the cutoff.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleMask {
    /// Index into [`TriangleMasks::images`], or [`NO_IMAGE`].
    pub image: u32,
    /// Texture coordinates of the corners.
    pub uv: [Vec2; 3],
    /// Alpha of the corners (base color factor x vertex color) over the cutoff.
    pub alpha: [f32; 3],
}

impl TriangleMask {
    /// An opaque triangle: every point is kept.
    pub const OPAQUE: TriangleMask = TriangleMask {
        image: NO_IMAGE,
        uv: [Vec2::ZERO; 3],
        alpha: [1.0; 3],
    };

    /// Whether this is [`TriangleMask::OPAQUE`]'s rule (no texture, every corner at least 1).
    pub fn is_opaque(&self) -> bool {
        self.image == NO_IMAGE && self.alpha.iter().all(|&a| a >= 1.0)
    }

    /// The mask of the part of the triangle whose corners have barycentric weights `w`
    /// (rows: the new corners) in the old one.
    pub fn sub(&self, w: [Vec3; 3]) -> TriangleMask {
        let at = |w: Vec3| {
            let uv = self.uv[0] * w.x + self.uv[1] * w.y + self.uv[2] * w.z;
            let a = self.alpha[0] * w.x + self.alpha[1] * w.y + self.alpha[2] * w.z;
            (uv, a)
        };
        let c = w.map(at);
        TriangleMask {
            image: self.image,
            uv: [c[0].0, c[1].0, c[2].0],
            alpha: [c[0].1, c[1].1, c[2].1],
        }
    }
}

/// The alpha channel of a masked material's texture and its sampler.
#[derive(Clone, Debug, PartialEq)]
pub struct MaskImage {
    pub width: u32,
    pub height: u32,
    /// Alpha, row by row from the top.
    pub alpha: Vec<u8>,
    pub sampler: SamplerDesc,
}

impl MaskImage {
    /// The alpha channel of `image` sampled with `sampler`.
    pub fn new(image: &TextureImage, sampler: &SamplerDesc) -> MaskImage {
        MaskImage {
            width: image.width,
            height: image.height,
            alpha: image.rgba.chunks_exact(4).map(|p| p[3]).collect(),
            sampler: *sampler,
        }
    }

    /// Alpha at `uv` (level 0, the sampler's wrap modes and magnification filter), as
    /// [`TextureImage::sample`] and the shadow pass (gi_shadow_masked.frag) take it.
    pub fn sample(&self, uv: Vec2) -> f32 {
        if self.alpha.len() < (self.width * self.height) as usize {
            return 1.0;
        }
        let fetch = |x: u32, y: u32| {
            let a = f32::from(self.alpha[(y * self.width + x) as usize]) / 255.0;
            glam::Vec4::splat(a)
        };
        sample_texels(self.width, self.height, uv, &self.sampler, fetch).w
    }
}

/// The masks of a [`crate::gi::geometry::WorldGeometry`]'s triangles: `triangles` is parallel to
/// its triangles, or empty when none is masked (then nothing costs anything).
#[derive(Clone, Debug, Default)]
pub struct TriangleMasks {
    /// One per triangle, or none at all.
    pub triangles: Vec<TriangleMask>,
    /// Alpha images, indexed by the scene's texture index (`None`: not used by a mask).
    pub images: Arc<Vec<Option<MaskImage>>>,
}

impl TriangleMasks {
    /// Whether any triangle is masked.
    pub fn any(&self) -> bool {
        !self.triangles.is_empty()
    }

    /// Whether the point of triangle `t` with weights (1 - a - b, a, b) is kept.
    pub fn keeps(&self, t: usize, a: f32, b: f32) -> bool {
        let Some(m) = self.triangles.get(t) else {
            return true;
        };
        if m.is_opaque() {
            return true;
        }
        let w = [1.0 - a - b, a, b];
        let alpha: f32 = m.alpha.iter().zip(w).map(|(x, w)| x * w).sum();
        let tex = match self.images.get(m.image as usize) {
            Some(Some(img)) => {
                let uv = m.uv[0] * w[0] + m.uv[1] * w[1] + m.uv[2] * w[2];
                img.sample(uv)
            }
            _ => 1.0,
        };
        alpha * tex >= KEEP
    }

    /// Appends one triangle's mask (`None`: opaque), keeping `triangles` empty while every
    /// triangle so far is opaque. `count` is the number of triangles before this one.
    pub fn push(&mut self, count: usize, mask: Option<TriangleMask>) {
        let mask = mask.filter(|m| !m.is_opaque());
        push_sparse(&mut self.triangles, count, mask, TriangleMask::OPAQUE);
    }

    /// Appends `other`'s masks after `count` triangles of this geometry.
    pub fn append(&mut self, count: usize, other: &TriangleMasks, other_count: usize) {
        let none = TriangleMask::OPAQUE;
        append_sparse(
            &mut self.triangles,
            count,
            &other.triangles,
            other_count,
            none,
        );
        if other.any() && self.images.is_empty() {
            self.images = other.images.clone();
        }
    }

    /// The mask of a triangle of `scene`'s object `object` with the given corner attributes
    /// indices, or `None` when its material is not masked. Loads the scene's mask images the
    /// first time.
    pub fn for_triangle(
        &mut self,
        scene: &Scene,
        object: usize,
        corners: [usize; 3],
    ) -> Option<TriangleMask> {
        let material = scene.object_material(object)?;
        let AlphaMode::Mask(cutoff) = material.alpha else {
            return None;
        };
        if cutoff <= 0.0 {
            return None;
        }
        if self.images.is_empty() {
            self.images = Arc::new(scene_mask_images(scene));
        }
        let factor = scene.objects[object].color.w;
        let a = corners.map(|i| scene.attributes.get(i).copied().unwrap_or_default());
        let image = material
            .base_color_texture
            .filter(|&t| matches!(self.images.get(t as usize), Some(Some(_))))
            .unwrap_or(NO_IMAGE);
        Some(TriangleMask {
            image,
            uv: a.map(|v| Vec2::from(v.uv)),
            alpha: a.map(|v| factor * v.color().w / cutoff),
        })
    }

    /// What the masked shadow pass reads, or `None` when no triangle is masked: per GPU vertex
    /// (three per triangle, in order) a vec4 (u, v, alpha over cutoff, image or -1), and the
    /// images as 32-bit words (see [`pack_images`]).
    /// `triangle_count` is the geometry's (triangles after the last mask are opaque).
    pub fn gpu_data(&self, triangle_count: usize) -> Option<(Vec<f32>, Vec<u32>)> {
        if !self.any() {
            return None;
        }
        let (words, index) = pack_images(&self.images);
        let mut vertices = Vec::with_capacity(triangle_count * 12);
        let opaque = std::iter::repeat(&TriangleMask::OPAQUE);
        for m in self.triangles.iter().chain(opaque).take(triangle_count) {
            let image = shader_image(&index, m.image);
            // Opaque triangles (no texture, corners at least 1) get a margin well above KEEP.
            let opaque = m.is_opaque();
            for k in 0..3 {
                let alpha = if opaque { 2.0 } else { m.alpha[k] };
                vertices.extend_from_slice(&[m.uv[k].x, m.uv[k].y, alpha, image]);
            }
        }
        Some((vertices, words))
    }
}

/// The alpha images of the textures `scene`'s masked materials use, by texture index.
fn scene_mask_images(scene: &Scene) -> Vec<Option<MaskImage>> {
    let mut out: Vec<Option<MaskImage>> = vec![None; scene.textures.len()];
    for m in &scene.materials {
        let (AlphaMode::Mask(_), Some(t)) = (m.alpha, m.base_color_texture) else {
            continue;
        };
        if let (Some(slot), Some((image, sampler))) =
            (out.get_mut(t as usize), scene.material_texture(m))
        {
            if slot.is_none() {
                *slot = Some(MaskImage::new(image, sampler));
            }
        }
    }
    out
}

/// The wrap mode as the GI shaders' two bits (masks and textures).
pub(crate) fn wrap_bits(w: Wrap) -> u32 {
    match w {
        Wrap::Repeat => 0,
        Wrap::MirroredRepeat => 1,
        Wrap::ClampToEdge => 2,
    }
}

/// The images as the shader reads them: a header of four words per image (first word of its
/// texels, width, height, flags: wrap u in bits 0-1, wrap v in bits 2-3, linear filter in bit
/// 4), then each image's alpha bytes, four to a word (little end first). Returns the words and
/// each texture index's image number in them.
pub fn pack_images(images: &[Option<MaskImage>]) -> (Vec<u32>, Vec<Option<u32>>) {
    let used: Vec<&MaskImage> = images.iter().flatten().collect();
    let mut words = vec![0u32; used.len() * 4];
    for (i, img) in used.iter().enumerate() {
        let s = &img.sampler;
        let flags = wrap_bits(s.wrap_u) | wrap_bits(s.wrap_v) << 2 | u32::from(s.mag_linear) << 4;
        let header = [words.len() as u32, img.width, img.height, flags];
        words[i * 4..i * 4 + 4].copy_from_slice(&header);
        words.extend(img.alpha.chunks(4).map(|c| {
            c.iter()
                .enumerate()
                .fold(0u32, |w, (k, &b)| w | u32::from(b) << (8 * k))
        }));
    }
    (words, numbered(images))
}

/// Each entry's number among those that are `Some`, in order (`None` for the others): where
/// an image of a sparse list lies among the images packed.
pub(crate) fn numbered<T>(images: &[Option<T>]) -> Vec<Option<u32>> {
    let mut next = 0;
    images
        .iter()
        .map(|m| {
            m.as_ref().map(|_| {
                next += 1;
                next - 1
            })
        })
        .collect()
}

/// Image `image`'s number among the packed ones (`index`, from [`numbered`]) as the GI shaders
/// read it from a vertex: -1 when it has none (no image, or one not packed).
pub(crate) fn shader_image(index: &[Option<u32>], image: u32) -> f32 {
    index
        .get(image as usize)
        .copied()
        .flatten()
        .map_or(-1.0, |i| i as f32)
}

/// Appends one triangle's entry to per-triangle data kept sparse (the GI's masks and
/// textures): `v` stays empty while every entry so far is `none`, and is padded with `none`
/// up to `count` (the triangles before this one) when `item` is the first that is not.
pub(crate) fn push_sparse<T: Copy>(v: &mut Vec<T>, count: usize, item: Option<T>, none: T) {
    match item {
        Some(t) => {
            v.resize(count, none);
            v.push(t);
        }
        None if !v.is_empty() => v.resize(count + 1, none),
        None => {}
    }
}

/// Appends `other` (the sparse data of `other_count` triangles) after `count` triangles of
/// `v`, keeping both sparse as [`push_sparse`] does.
pub(crate) fn append_sparse<T: Copy>(
    v: &mut Vec<T>,
    count: usize,
    other: &[T],
    other_count: usize,
    none: T,
) {
    if other.is_empty() {
        if !v.is_empty() {
            v.resize(count + other_count, none);
        }
        return;
    }
    v.resize(count, none);
    v.extend_from_slice(other);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn holes() -> MaskImage {
        // 2x2: opaque, clear / clear, opaque.
        MaskImage {
            width: 2,
            height: 2,
            alpha: vec![255, 0, 0, 255],
            sampler: SamplerDesc {
                mag_linear: false,
                ..SamplerDesc::default()
            },
        }
    }

    #[test]
    fn keeps_follows_the_texture_and_the_cutoff() {
        let mask = TriangleMask {
            image: 0,
            uv: [Vec2::ZERO, Vec2::X, Vec2::Y],
            alpha: [2.0; 3],
        };
        let masks = TriangleMasks {
            triangles: vec![mask, TriangleMask::OPAQUE],
            images: Arc::new(vec![Some(holes())]),
        };
        // (a, b) weights corners 1 (u = 1) and 2 (v = 1).
        assert!(masks.keeps(0, 0.1, 0.1)); // uv (0.1, 0.1): opaque texel
        assert!(!masks.keeps(0, 0.6, 0.1)); // uv (0.6, 0.1): clear texel
        assert!(!masks.keeps(0, 0.1, 0.6));
        assert!(masks.keeps(1, 0.6, 0.1));
        // Corner alpha below the cutoff: nothing is kept.
        let faint = TriangleMasks {
            triangles: vec![TriangleMask {
                alpha: [0.5; 3],
                ..mask
            }],
            ..masks.clone()
        };
        assert!(!faint.keeps(0, 0.1, 0.1));
    }

    #[test]
    fn sub_triangles_interpolate_and_push_pads() {
        let mask = TriangleMask {
            image: 0,
            uv: [Vec2::ZERO, Vec2::X, Vec2::Y],
            alpha: [1.0, 3.0, 5.0],
        };
        let half = mask.sub([Vec3::X, Vec3::new(0.5, 0.5, 0.0), Vec3::Z]);
        assert_eq!(half.uv[1], Vec2::new(0.5, 0.0));
        assert_eq!(half.alpha, [1.0, 2.0, 5.0]);
        let mut masks = TriangleMasks::default();
        masks.push(0, None);
        masks.push(1, None);
        assert!(!masks.any());
        masks.push(2, Some(mask));
        masks.push(3, None);
        assert_eq!(masks.triangles.len(), 4);
        assert!(masks.triangles[0].is_opaque() && !masks.triangles[2].is_opaque());
    }

    #[test]
    fn packed_images_hold_headers_and_bytes() {
        let (words, index) = pack_images(&[None, Some(holes())]);
        assert_eq!(index, vec![None, Some(0)]);
        assert_eq!(&words[..4], &[4, 2, 2, 0]);
        assert_eq!(words[4], 0xFF00_00FF);
    }
}
