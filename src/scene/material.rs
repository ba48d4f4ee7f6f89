//! Materials as the renderer draws them: per-vertex texture coordinates and colors, base color
//! textures (sRGB RGBA8 images with a glTF sampler) and the alpha mode. The base color factor is
//! the object's `color`. Procedural scenes have none of these; a glTF file gets them when it
//! uses textures, vertex colors or alpha masks.

use glam::{Vec2, Vec3, Vec4};

/// Per-vertex material attributes, parallel to `Scene::vertices` when the scene has any.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct VertexAttributes {
    /// Base color texture coordinates.
    pub uv: [f32; 2],
    /// Vertex color (linear, unsigned normalized); white when the file has none.
    pub color: [u8; 4],
}

impl Default for VertexAttributes {
    fn default() -> Self {
        VertexAttributes {
            uv: [0.0; 2],
            color: [255; 4],
        }
    }
}

impl VertexAttributes {
    /// The vertex color as linear floats.
    pub fn color(&self) -> Vec4 {
        Vec4::from_array(self.color.map(|c| f32::from(c) / 255.0))
    }
}

/// Texture coordinate wrapping (glTF `wrapS`/`wrapT`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum Wrap {
    /// Tile.
    #[default]
    Repeat,
    /// Tile, mirrored every other time.
    MirroredRepeat,
    /// Clamp to the edge texel.
    ClampToEdge,
}

impl Wrap {
    /// `t` wrapped into [0, 1].
    pub fn apply(self, t: f32) -> f32 {
        match self {
            Wrap::Repeat => t - t.floor(),
            Wrap::MirroredRepeat => {
                let m = t.rem_euclid(2.0);
                if m > 1.0 {
                    2.0 - m
                } else {
                    m
                }
            }
            Wrap::ClampToEdge => t.clamp(0.0, 1.0),
        }
    }
}

/// A texture sampler (glTF sampler: wrap modes and filters; mipmaps when the minification filter
/// asks for them).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct SamplerDesc {
    /// Wrapping along u (glTF `wrapS`).
    pub wrap_u: Wrap,
    /// Wrapping along v (glTF `wrapT`).
    pub wrap_v: Wrap,
    /// Linear magnification (else nearest).
    pub mag_linear: bool,
    /// Linear minification within a level (else nearest).
    pub min_linear: bool,
    /// Whether mip levels are used.
    pub mipmaps: bool,
    /// Linear blending between levels (else nearest level).
    pub mip_linear: bool,
}

impl Default for SamplerDesc {
    /// glTF's default: repeat, and (filters left to the implementation) trilinear.
    fn default() -> Self {
        SamplerDesc {
            wrap_u: Wrap::Repeat,
            wrap_v: Wrap::Repeat,
            mag_linear: true,
            min_linear: true,
            mipmaps: true,
            mip_linear: true,
        }
    }
}

/// A decoded image: RGBA8, sRGB-encoded, row by row from the top.
#[derive(Clone, Debug, PartialEq)]
pub struct TextureImage {
    pub width: u32,
    pub height: u32,
    pub rgba: Vec<u8>,
}

/// sRGB-encoded 8-bit value to linear (a table of the 256 values, made on first use).
pub fn srgb_to_linear(c: u8) -> f32 {
    static TABLE: std::sync::OnceLock<[f32; 256]> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        std::array::from_fn(|i| {
            let c = i as f32 / 255.0;
            if c <= 0.04045 {
                c / 12.92
            } else {
                ((c + 0.055) / 1.055).powf(2.4)
            }
        })
    })[usize::from(c)]
}

/// Linear value to sRGB-encoded 8-bit.
pub fn linear_to_srgb(l: f32) -> u8 {
    let l = l.clamp(0.0, 1.0);
    let c = if l <= 0.003_130_8 {
        l * 12.92
    } else {
        1.055 * l.powf(1.0 / 2.4) - 0.055
    };
    (c * 255.0 + 0.5) as u8
}

impl TextureImage {
    /// Texel `(x, y)` as linear RGBA (alpha is stored linearly).
    pub fn texel(&self, x: u32, y: u32) -> Vec4 {
        let i = ((y.min(self.height - 1) * self.width + x.min(self.width - 1)) * 4) as usize;
        let p = &self.rgba[i..i + 4];
        Vec4::new(
            srgb_to_linear(p[0]),
            srgb_to_linear(p[1]),
            srgb_to_linear(p[2]),
            f32::from(p[3]) / 255.0,
        )
    }

    /// Samples level 0 at `uv` with the sampler's wrap modes and magnification filter, as
    /// the GPU does for a magnified texture (linear RGBA). For the CPU ray caster's hit colors.
    pub fn sample(&self, uv: Vec2, s: &SamplerDesc) -> Vec4 {
        if !self.has_texels() {
            return Vec4::ONE;
        }
        sample_texels(self.width, self.height, uv, s, |x, y| self.texel(x, y))
    }

    /// Whether the image has texels: both sizes positive and the bytes of all of them there.
    /// Without, [`TextureImage::sample`] reads it as white.
    pub fn has_texels(&self) -> bool {
        let texels = self.width as usize * self.height as usize;
        texels > 0 && self.rgba.len() >= texels * 4
    }

    /// The mip levels below this one, each [`TextureImage::halved`] from the one before, down
    /// to 1x1 (none for a 1x1 image).
    pub fn mip_chain(&self) -> Vec<TextureImage> {
        let mut chain: Vec<TextureImage> = Vec::new();
        let mut last = self;
        while last.width > 1 || last.height > 1 {
            chain.push(last.halved());
            last = chain.last().expect("pushed");
        }
        chain
    }

    /// The next mip level: half the size (rounded down, at least 1), each texel the average of
    /// the 2x2 (or fewer at odd edges) texels it covers, averaged in linear space.
    pub fn halved(&self) -> TextureImage {
        let (w, h) = ((self.width / 2).max(1), (self.height / 2).max(1));
        let mut rgba = Vec::with_capacity((w * h * 4) as usize);
        for y in 0..h {
            for x in 0..w {
                let mut sum = Vec4::ZERO;
                let mut n = 0.0;
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let (sx, sy) = (2 * x + dx, 2 * y + dy);
                    if sx < self.width && sy < self.height {
                        sum += self.texel(sx, sy);
                        n += 1.0;
                    }
                }
                let avg = sum / n;
                rgba.extend_from_slice(&[
                    linear_to_srgb(avg.x),
                    linear_to_srgb(avg.y),
                    linear_to_srgb(avg.z),
                    (avg.w.clamp(0.0, 1.0) * 255.0 + 0.5) as u8,
                ]);
            }
        }
        TextureImage {
            width: w,
            height: h,
            rgba,
        }
    }

    /// The mean color of the image (linear RGBA).
    pub fn mean(&self) -> Vec4 {
        let n = (self.width * self.height).max(1) as f32;
        let mut sum = Vec4::ZERO;
        for y in 0..self.height {
            for x in 0..self.width {
                sum += self.texel(x, y);
            }
        }
        sum / n
    }
}

/// A texture: an image of the scene and how it is sampled.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Texture {
    /// Index into `Scene::images`.
    pub image: u32,
    /// The sampler.
    pub sampler: SamplerDesc,
}

/// How a material's alpha is used.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum AlphaMode {
    /// Alpha is ignored.
    #[default]
    Opaque,
    /// Fragments whose alpha is below the cutoff are discarded (glTF `MASK`, `alphaCutoff`).
    Mask(f32),
}

/// A material: an optional base color texture, the alpha mode, whether back faces are drawn,
/// whether it is blended and whether it is lit.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Material {
    /// Index into `Scene::textures`.
    pub base_color_texture: Option<u32>,
    /// Opaque or masked.
    pub alpha: AlphaMode,
    /// glTF `doubleSided`: drawn without back-face culling (back faces lit with the flipped
    /// normal).
    pub double_sided: bool,
    /// glTF alpha mode `BLEND`: the forward pass draws the object blended over what is behind
    /// it, after every opaque object, back to front, without writing depth; it hides nothing,
    /// so it stays out of the culling hierarchy ([`super::Scene::hierarchy`]); the renderer
    /// tests its box against the opaque depth itself when it is heavy enough to pay for the
    /// test. Every other pass (the ID pass, `gi`, moving copies)
    /// draws it as `alpha` says (a glTF BLEND material is masked at 0.5).
    pub blend: bool,
    /// glTF `KHR_materials_unlit`: the forward pass draws its color as it is, without the
    /// light (lighting baked into the texture). `gi` lights it as any surface.
    pub unlit: bool,
}

/// Samples a `width` x `height` level at `uv` with the sampler's wrap modes and magnification
/// filter (nearest, or bilinear between the four nearest texels), reading texels with `texel`
/// (called with coordinates inside the image). An empty image samples as 1.
pub fn sample_texels(
    width: u32,
    height: u32,
    uv: Vec2,
    s: &SamplerDesc,
    texel: impl Fn(u32, u32) -> Vec4,
) -> Vec4 {
    if width == 0 || height == 0 {
        return Vec4::ONE;
    }
    let (w, h) = (width as f32, height as f32);
    let u = s.wrap_u.apply(uv.x) * w;
    let v = s.wrap_v.apply(uv.y) * h;
    if !s.mag_linear {
        return texel((u as u32).min(width - 1), (v as u32).min(height - 1));
    }
    let (fx, fy) = (u - 0.5, v - 0.5);
    let (x0, y0) = (fx.floor(), fy.floor());
    let (tx, ty) = (fx - x0, fy - y0);
    let wrap = |i: f32, n: u32, mode: Wrap| -> u32 {
        let n = n as i64;
        let i = i as i64;
        match mode {
            Wrap::Repeat => i.rem_euclid(n) as u32,
            Wrap::ClampToEdge => i.clamp(0, n - 1) as u32,
            Wrap::MirroredRepeat => {
                let m = i.rem_euclid(2 * n);
                (if m >= n { 2 * n - 1 - m } else { m }) as u32
            }
        }
    };
    let xs = [wrap(x0, width, s.wrap_u), wrap(x0 + 1.0, width, s.wrap_u)];
    let ys = [wrap(y0, height, s.wrap_v), wrap(y0 + 1.0, height, s.wrap_v)];
    let top = texel(xs[0], ys[0]).lerp(texel(xs[1], ys[0]), tx);
    let bottom = texel(xs[0], ys[1]).lerp(texel(xs[1], ys[1]), tx);
    top.lerp(bottom, ty)
}

/// What the scene's materials need of one object: its base color (factor x vertex color x
/// texture) at a point given by barycentric weights of a triangle's corners (linear RGBA).
pub fn surface_color(
    base: Vec4,
    attributes: &[VertexAttributes; 3],
    weights: Vec3,
    texture: Option<(&TextureImage, &SamplerDesc)>,
) -> Vec4 {
    let mut uv = Vec2::ZERO;
    let mut color = Vec4::ZERO;
    for (a, w) in attributes.iter().zip(weights.to_array()) {
        uv += Vec2::from(a.uv) * w;
        color += a.color() * w;
    }
    let tex = texture.map_or(Vec4::ONE, |(img, s)| img.sample(uv, s));
    base * color * tex
}

#[cfg(test)]
mod tests {
    use super::*;

    fn checker() -> TextureImage {
        // 2x2: white, black / black, white.
        let rgba = [255, 0, 0, 255]
            .iter()
            .flat_map(|&c| [c, c, c, 255])
            .collect();
        TextureImage {
            width: 2,
            height: 2,
            rgba,
        }
    }

    #[test]
    fn srgb_round_trip() {
        for c in [0u8, 1, 10, 100, 128, 200, 255] {
            assert_eq!(linear_to_srgb(srgb_to_linear(c)), c);
        }
    }

    #[test]
    fn nearest_and_wrap_modes() {
        let img = checker();
        let nearest = SamplerDesc {
            mag_linear: false,
            ..SamplerDesc::default()
        };
        assert_eq!(img.sample(Vec2::new(0.25, 0.25), &nearest).x, 1.0);
        assert_eq!(img.sample(Vec2::new(0.75, 0.25), &nearest).x, 0.0);
        // Repeat: 1.25 is 0.25.
        assert_eq!(img.sample(Vec2::new(1.25, 0.25), &nearest).x, 1.0);
        // Mirrored: 1.25 is 0.75.
        let mirrored = SamplerDesc {
            wrap_u: Wrap::MirroredRepeat,
            ..nearest
        };
        assert_eq!(img.sample(Vec2::new(1.25, 0.25), &mirrored).x, 0.0);
        // Clamp: 3.0 is the right edge.
        let clamp = SamplerDesc {
            wrap_u: Wrap::ClampToEdge,
            ..nearest
        };
        assert_eq!(img.sample(Vec2::new(3.0, 0.25), &clamp).x, 0.0);
        // Linear at the centre of the image: the mean of the four texels.
        let mid = img.sample(Vec2::new(0.5, 0.5), &SamplerDesc::default()).x;
        assert!((mid - 0.5).abs() < 1e-4, "{mid}");
    }

    #[test]
    fn halving_averages_in_linear_space() {
        let half = checker().halved();
        assert_eq!((half.width, half.height), (1, 1));
        assert_eq!(half.rgba[0], linear_to_srgb(0.5));
        assert_eq!(half.rgba[3], 255);
    }
}
