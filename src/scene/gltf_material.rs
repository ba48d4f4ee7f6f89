//! glTF materials: base color textures (PNG, JPEG, WebP through `EXT_texture_webp`, and KTX2
//! Basis Universal through `KHR_texture_basisu`, from a GLB buffer view, a data URI or a file
//! next to the .gltf; the diffuse texture and factor of
//! `KHR_materials_pbrSpecularGlossiness` stand for them) with their samplers, alpha mode MASK
//! with its cutoff, alpha mode BLEND ([`Material::blend`]: blended in the forward pass, masked
//! at [`BLEND_CUTOFF`] in the others, with a warning that says so), and the
//! per-vertex TEXCOORD_n and COLOR_0 attributes. A texture whose image cannot be decoded
//! (AVIF, a broken file) is a one-line warning and the material is drawn without it.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use ::gltf::accessor::{DataType, Dimensions};
use ::gltf::buffer::Data;
use ::gltf::mesh::Semantic;
use ::gltf::texture::{MagFilter, MinFilter, WrappingMode};
use ::gltf::{Accessor, Document};

use super::gltf_draco::DracoPrimitive;
use super::gltf_ext::{BASISU, WEBP};
use super::material::{
    AlphaMode, Material, SamplerDesc, Texture, TextureImage, VertexAttributes, Wrap,
};

/// The alpha cutoff a BLEND material is drawn with in the passes that do not blend (the ID
/// pass, `gi`, moving copies): testing alpha is the closest a depth-tested pass comes, so
/// foliage and grates, which files often mark BLEND, keep their shape there instead of showing
/// as solid quads.
pub const BLEND_CUTOFF: f32 = 0.5;

/// How many materials or images a warning names before it counts the rest.
const NAMED_MOST: usize = 6;

/// "material 3", "materials 3, 7 and 12", "images 0, 1, 2, 3, 4, 5 and 194 more": the first
/// [`NAMED_MOST`] of `indices` of a `kind`, the rest counted (`None` for none).
fn named(kind: &str, indices: &[usize]) -> Option<String> {
    let (first, rest) = indices.split_at(indices.len().min(NAMED_MOST));
    let mut names: Vec<String> = first.iter().map(usize::to_string).collect();
    Some(match (names.len(), rest.len()) {
        (0, _) => return None,
        (1, _) => format!("{kind} {}", names[0]),
        (_, 0) => {
            let last = names.pop().unwrap_or_default();
            format!("{kind}s {} and {last}", names.join(", "))
        }
        (_, more) => format!("{kind}s {} and {more} more", names.join(", ")),
    })
}

/// Largest decoded image accepted (texels), so a hostile file cannot ask for gigabytes.
const MAX_TEXELS: u64 = 1 << 26;

/// Materials, textures and images loaded so far, each glTF one at most once.
#[derive(Default)]
pub(super) struct MaterialLoader {
    base: PathBuf,
    by_material: HashMap<usize, Option<u32>>,
    by_texture: HashMap<usize, Option<u32>>,
    by_image: HashMap<usize, Option<u32>>,
    pub materials: Vec<Material>,
    pub textures: Vec<Texture>,
    pub images: Vec<TextureImage>,
    /// Whether any primitive had vertex colors.
    pub attributes_used: bool,
    /// The glTF materials with alpha mode BLEND, in the order they were met.
    blended: Vec<usize>,
    /// Of those, the ones whose objects have no alpha under one: drawn opaque.
    opaque_blends: Vec<usize>,
    /// The glTF images that could not be decoded, and why, in the order they were met.
    failed_images: Vec<(usize, String)>,
    /// The glTF textures with no image to decode, and why, in the order they were met.
    failed_textures: Vec<(usize, String)>,
}

impl MaterialLoader {
    /// A loader resolving external images relative to `base`.
    pub fn new(base: &Path) -> MaterialLoader {
        MaterialLoader {
            base: base.to_path_buf(),
            ..Default::default()
        }
    }

    /// Our material for a primitive's glTF material: `None` when it has neither a usable base
    /// color texture nor alpha mode MASK or BLEND nor `doubleSided` (then the base color factor
    /// says it all).
    pub fn material(
        &mut self,
        m: &::gltf::Material<'_>,
        doc: &Document,
        buffers: &[Data],
    ) -> Option<u32> {
        let index = m.index()?;
        if let Some(&known) = self.by_material.get(&index) {
            return known;
        }
        let texture =
            base_color_texture(m).and_then(|info| self.texture(&info.texture(), doc, buffers));
        let alpha = match m.alpha_mode() {
            ::gltf::material::AlphaMode::Mask => {
                let cutoff = m.alpha_cutoff().unwrap_or(0.5);
                AlphaMode::Mask(if cutoff.is_finite() { cutoff } else { 0.5 })
            }
            ::gltf::material::AlphaMode::Blend => {
                self.blended.push(index);
                AlphaMode::Mask(BLEND_CUTOFF)
            }
            ::gltf::material::AlphaMode::Opaque => AlphaMode::Opaque,
        };
        let double_sided = m.double_sided();
        let unlit = m.unlit();
        let ours = if texture.is_none() && alpha == AlphaMode::Opaque && !double_sided && !unlit {
            None
        } else {
            self.materials.push(Material {
                base_color_texture: texture,
                alpha,
                double_sided,
                blend: m.alpha_mode() == ::gltf::material::AlphaMode::Blend,
                unlit,
            });
            Some(self.materials.len() as u32 - 1)
        };
        self.by_material.insert(index, ours);
        ours
    }

    /// Draws opaque the objects whose BLEND material never has alpha under one on them (base
    /// color factor, texture texels and vertex colors all fully opaque; exporters mark opaque
    /// materials BLEND often): blending them would take them out of the culling hierarchy and
    /// draw them without depth writes, for no change in color. Each such object gets an
    /// opaque copy of its material; a BLEND material left with no blended object is named in
    /// the warnings as drawn opaque (`moving`: the materials of animated objects, which keep
    /// theirs). Returns how many objects changed.
    pub fn settle_opaque_blends(
        &mut self,
        objects: &mut [super::Object],
        attributes: &[VertexAttributes],
        moving: impl Iterator<Item = u32>,
    ) -> usize {
        let mut opaque_image: HashMap<u32, bool> = HashMap::new();
        let mut copies: HashMap<u32, u32> = HashMap::new();
        let mut still_blended = vec![false; self.materials.len()];
        for m in moving {
            if let Some(b) = still_blended.get_mut(m as usize) {
                *b = true;
            }
        }
        let mut changed = 0;
        for o in objects.iter_mut() {
            let Some(m) = o.material else { continue };
            let Some(&material) = self.materials.get(m as usize) else {
                continue;
            };
            if !material.blend {
                continue;
            }
            let texture_opaque = match material.base_color_texture {
                None => true,
                Some(t) => match self.textures.get(t as usize) {
                    None => true,
                    Some(tex) => *opaque_image.entry(tex.image).or_insert_with(|| {
                        self.images
                            .get(tex.image as usize)
                            .is_none_or(|i| i.rgba.chunks_exact(4).all(|p| p[3] == 255))
                    }),
                },
            };
            let start = o.vertex_offset as usize;
            let colors_opaque = attributes
                .get(start..start + o.vertex_count as usize)
                .is_none_or(|a| a.iter().all(|v| v.color[3] == 255));
            if o.color.w < 1.0 || !texture_opaque || !colors_opaque {
                still_blended[m as usize] = true;
                continue;
            }
            let copy = *copies.entry(m).or_insert_with(|| {
                self.materials.push(Material {
                    alpha: AlphaMode::Opaque,
                    blend: false,
                    ..material
                });
                self.materials.len() as u32 - 1
            });
            o.material = Some(copy);
            changed += 1;
        }
        let by_material = &self.by_material;
        let ours = |index: &usize| by_material.get(index).copied().flatten();
        let (blended, opaque): (Vec<usize>, Vec<usize>) = self.blended.iter().partition(|index| {
            ours(index).is_none_or(|m| still_blended.get(m as usize).copied().unwrap_or(true))
        });
        self.blended = blended;
        self.opaque_blends = opaque;
        changed
    }

    /// The warnings about materials, textures and images, each kind in one line that names the
    /// first few (a file can have hundreds): the BLEND materials, the textures without an image
    /// to decode and the images that could not be decoded, grouped by reason.
    pub fn warnings(&self) -> Vec<String> {
        let mut out = Vec::new();
        for (kind, failed) in [
            ("texture", &self.failed_textures),
            ("image", &self.failed_images),
        ] {
            let mut reasons: Vec<(&str, Vec<usize>)> = Vec::new();
            for (index, reason) in failed {
                match reasons.iter_mut().find(|(r, _)| r == reason) {
                    Some((_, indices)) => indices.push(*index),
                    None => reasons.push((reason, vec![*index])),
                }
            }
            for (reason, indices) in reasons {
                if let Some(who) = named(kind, &indices) {
                    let these = match (kind, indices.len()) {
                        ("texture", 1) => "it",
                        ("texture", _) => "them",
                        (_, 1) => "this texture",
                        _ => "these textures",
                    };
                    out.push(format!("{who}: {reason}; drawn without {these}"));
                }
            }
        }
        out.extend(named("material", &self.blended).map(|who| {
            format!(
                "{who}: alpha mode BLEND, blended after the opaque objects, back to front by \
                 object, tested against the opaque depth when heavy; alpha-tested at \
                 {BLEND_CUTOFF} in gi and in moving copies"
            )
        }));
        out.extend(named("material", &self.opaque_blends).map(|who| {
            format!(
                "{who}: alpha mode BLEND with no alpha under one (factor, texture, vertex \
                 colors): drawn opaque, and culled as opaque objects are"
            )
        }));
        out
    }

    fn texture(
        &mut self,
        t: &::gltf::Texture<'_>,
        doc: &Document,
        buffers: &[Data],
    ) -> Option<u32> {
        if let Some(&known) = self.by_texture.get(&t.index()) {
            return known;
        }
        let image = match texture_image(t, doc) {
            Ok(image) => self.image(&image, buffers),
            Err(e) => {
                self.failed_textures.push((t.index(), e));
                None
            }
        };
        let ours = image.map(|image| {
            self.textures.push(Texture {
                image,
                sampler: sampler_desc(&t.sampler()),
            });
            self.textures.len() as u32 - 1
        });
        self.by_texture.insert(t.index(), ours);
        ours
    }

    fn image(&mut self, img: &::gltf::Image<'_>, buffers: &[Data]) -> Option<u32> {
        if let Some(&known) = self.by_image.get(&img.index()) {
            return known;
        }
        let ours = match decode_image(img, &self.base, buffers) {
            Ok(decoded) => {
                self.images.push(decoded);
                Some(self.images.len() as u32 - 1)
            }
            Err(e) => {
                self.failed_images.push((img.index(), e));
                None
            }
        };
        self.by_image.insert(img.index(), ours);
        ours
    }

    /// The texture coordinate set a material's base color texture reads (0 when none).
    /// `KHR_texture_transform` may name another set.
    fn tex_coord_set(m: &::gltf::Material<'_>) -> u32 {
        base_color_texture(m).map_or(0, |info| {
            info.texture_transform()
                .and_then(|t| t.tex_coord())
                .unwrap_or(info.tex_coord())
        })
    }

    /// The `KHR_texture_transform` of a material's base color texture (`None` when it has
    /// none). gltfpack writes one for every textured material whose texture coordinates it
    /// quantizes.
    fn uv_transform(m: &::gltf::Material<'_>) -> Option<UvTransform> {
        let t = base_color_texture(m)?.texture_transform()?;
        Some(UvTransform::new(t.offset(), t.rotation(), t.scale()))
    }
}

/// The material's base color factor: the diffuse factor of
/// `KHR_materials_pbrSpecularGlossiness` when the material has that extension (it takes the
/// place of the metallic-roughness model, which such files often give only as a fallback),
/// else the metallic-roughness base color factor.
pub(super) fn base_color_factor(m: &::gltf::Material<'_>) -> [f32; 4] {
    match m.pbr_specular_glossiness() {
        Some(sg) => sg.diffuse_factor(),
        None => m.pbr_metallic_roughness().base_color_factor(),
    }
}

/// The material's base color texture, chosen as [`base_color_factor`] chooses the factor.
fn base_color_texture<'a>(m: &::gltf::Material<'a>) -> Option<::gltf::texture::Info<'a>> {
    match m.pbr_specular_glossiness() {
        Some(sg) => sg.diffuse_texture(),
        None => m.pbr_metallic_roughness().base_color_texture(),
    }
}

/// `KHR_texture_transform`: texture coordinates scaled, then rotated counter-clockwise about
/// the origin, then offset, as a 2x3 affine map (rows).
#[derive(Clone, Copy, Debug, PartialEq)]
struct UvTransform([[f32; 3]; 2]);

impl UvTransform {
    /// The map of `offset`, `rotation` (radians) and `scale`.
    pub fn new(offset: [f32; 2], rotation: f32, scale: [f32; 2]) -> UvTransform {
        let (s, c) = rotation.sin_cos();
        UvTransform([
            [c * scale[0], s * scale[1], offset[0]],
            [-s * scale[0], c * scale[1], offset[1]],
        ])
    }

    /// Whether it maps (u, v) to itself.
    pub fn is_identity(&self) -> bool {
        self.0 == [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    }

    /// The transformed coordinates.
    pub fn apply(&self, [u, v]: [f32; 2]) -> [f32; 2] {
        self.0.map(|r| r[0] * u + r[1] * v + r[2])
    }
}

fn wrap(mode: WrappingMode) -> Wrap {
    match mode {
        WrappingMode::ClampToEdge => Wrap::ClampToEdge,
        WrappingMode::MirroredRepeat => Wrap::MirroredRepeat,
        WrappingMode::Repeat => Wrap::Repeat,
    }
}

/// Our sampler for a glTF sampler; unset filters are linear with linear mipmaps.
fn sampler_desc(s: &::gltf::texture::Sampler<'_>) -> SamplerDesc {
    let (min_linear, mipmaps, mip_linear) = match s.min_filter() {
        None | Some(MinFilter::LinearMipmapLinear) => (true, true, true),
        Some(MinFilter::Nearest) => (false, false, false),
        Some(MinFilter::Linear) => (true, false, false),
        Some(MinFilter::NearestMipmapNearest) => (false, true, false),
        Some(MinFilter::LinearMipmapNearest) => (true, true, false),
        Some(MinFilter::NearestMipmapLinear) => (false, true, true),
    };
    SamplerDesc {
        wrap_u: wrap(s.wrap_s()),
        wrap_v: wrap(s.wrap_t()),
        mag_linear: s.mag_filter() != Some(MagFilter::Nearest),
        min_linear,
        mipmaps,
        mip_linear,
    }
}

/// The image a texture reads: the `EXT_texture_webp` or `KHR_texture_basisu` image when it
/// names one, else the core `source`; an error saying why when there is none (its only images
/// are in extensions that are not decoded, such as `EXT_texture_avif`).
fn texture_image<'d>(
    t: &::gltf::Texture<'d>,
    doc: &'d Document,
) -> Result<::gltf::Image<'d>, String> {
    let extensions = t.extensions();
    let ext_source = |name: &str| extensions?.get(name)?.get("source");
    for ext in [WEBP, BASISU] {
        if let Some(source) = ext_source(ext) {
            return source
                .as_u64()
                .and_then(|i| doc.images().nth(usize::try_from(i).ok()?))
                .ok_or_else(|| format!("its {ext} source {source} is not an image of the file"));
        }
    }
    if let Some(image) = t.source() {
        return Ok(image);
    }
    let others: Vec<&str> = extensions
        .into_iter()
        .flatten()
        .filter(|(_, v)| v.get("source").is_some())
        .map(|(k, _)| k.as_str())
        .collect();
    Err(match others.as_slice() {
        [] => "it has no image".to_string(),
        names => format!(
            "its only image is given by {}, which is not supported",
            names.join(", ")
        ),
    })
}

/// The encoded bytes of an image and a name for messages.
fn image_bytes(img: &::gltf::Image<'_>, base: &Path, buffers: &[Data]) -> Result<Vec<u8>, String> {
    match img.source() {
        ::gltf::image::Source::View { view, .. } => {
            let data = buffers
                .get(view.buffer().index())
                .ok_or("its buffer view refers to a missing buffer")?;
            let end = view
                .offset()
                .checked_add(view.length())
                .filter(|&e| e <= data.len())
                .ok_or_else(|| format!("buffer view {} exceeds its buffer", view.index()))?;
            Ok(data[view.offset()..end].to_vec())
        }
        ::gltf::image::Source::Uri { uri, .. } => {
            if let Some(rest) = uri.strip_prefix("data:") {
                let (_, payload) = rest
                    .split_once(";base64,")
                    .ok_or("its data URI is not base64")?;
                return base64_decode(payload);
            }
            if uri.contains(':') {
                return Err(format!("URI scheme of '{uri}' is not supported"));
            }
            let path = base.join(super::gltf::percent_decode(uri)?);
            match std::fs::metadata(&path) {
                Ok(meta) if !meta.is_file() => Err(format!("'{uri}' is not a regular file")),
                Ok(_) => std::fs::read(&path).map_err(|e| format!("cannot read '{uri}': {e}")),
                Err(e) => Err(format!("cannot read '{uri}': {e}")),
            }
        }
    }
}

/// The identifier a KTX 2.0 file starts with.
const KTX2_MAGIC: [u8; 12] = [
    0xAB, b'K', b'T', b'X', b' ', b'2', b'0', 0xBB, b'\r', b'\n', 0x1A, b'\n',
];

/// Decodes a PNG, JPEG, WebP or KTX2 (Basis Universal) image to sRGB RGBA8.
fn decode_image(
    img: &::gltf::Image<'_>,
    base: &Path,
    buffers: &[Data],
) -> Result<TextureImage, String> {
    let bytes = image_bytes(img, base, buffers)?;
    if bytes.starts_with(&KTX2_MAGIC) {
        return decode_basis(&bytes);
    }
    let format = image::guess_format(&bytes).map_err(|_| {
        let mime = match img.source() {
            ::gltf::image::Source::View { mime_type, .. } => Some(mime_type),
            ::gltf::image::Source::Uri { mime_type, uri } => mime_type.or_else(|| {
                let media = uri.strip_prefix("data:")?.split([';', ',']).next()?;
                (!media.is_empty()).then_some(media)
            }),
        };
        match mime {
            Some(m @ ("image/png" | "image/jpeg" | "image/webp")) => format!(
                "its {} bytes are not the {} image it declares",
                bytes.len(),
                match m {
                    "image/png" => "PNG",
                    "image/jpeg" => "JPEG",
                    _ => "WebP",
                }
            ),
            Some("image/ktx2") => format!(
                "its {} bytes are not the KTX2 image it declares",
                bytes.len()
            ),
            m => format!(
                "format {} is not supported (PNG, JPEG, WebP and KTX2 are)",
                m.unwrap_or("unknown")
            ),
        }
    })?;
    let mut reader = image::ImageReader::with_format(std::io::Cursor::new(&bytes), format);
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(MAX_TEXELS * 16);
    reader.limits(limits);
    let decoded = reader
        .decode()
        .map_err(|e| format!("cannot decode {format:?}: {e}"))?;
    let (width, height) = (decoded.width(), decoded.height());
    if width == 0 || height == 0 || u64::from(width) * u64::from(height) > MAX_TEXELS {
        return Err(format!("size {width}x{height} is empty or too large"));
    }
    Ok(TextureImage {
        width,
        height,
        rgba: decoded.into_rgba8().into_raw(),
    })
}

/// Transcodes the first level of a KTX2 Basis Universal image (ETC1S or UASTC, zstd
/// supercompressed or not) to RGBA8 with the pure-Rust `basisu` transcoder. The texel values
/// are the encoded ones, sRGB for a base color texture as the glTF spec asks. A file that is not
/// Basis (a KTX2 of a raw GPU format), a cube map, an array or a video is refused with the reason.
fn decode_basis(bytes: &[u8]) -> Result<TextureImage, String> {
    let basis = |e: basisu::Error| format!("cannot transcode its KTX2 Basis data: {e:?}");
    // The transcoder is young and meets hostile bytes here: a panic in it is contained and
    // becomes this texture's warning instead of failing the file.
    std::panic::catch_unwind(|| {
        let tex = basisu::Transcoder::new(bytes).map_err(basis)?;
        if tex.face_count() > 1 || tex.layer_count() > 1 || tex.is_video() {
            return Err(format!(
                "its KTX2 image has {} faces and {} layers{}: a 2D texture is expected",
                tex.face_count(),
                tex.layer_count(),
                if tex.is_video() { " (a video)" } else { "" }
            ));
        }
        let (width, height) = tex.base_dimensions();
        if width == 0 || height == 0 || u64::from(width) * u64::from(height) > MAX_TEXELS {
            return Err(format!("size {width}x{height} is empty or too large"));
        }
        let rgba = tex
            .transcode(0, basisu::TargetFormat::Rgba32, basisu::DecodeFlags::NONE)
            .map_err(basis)?;
        if rgba.len() != width as usize * height as usize * 4 {
            return Err(format!(
                "its KTX2 image transcoded to {} bytes for {width}x{height} texels",
                rgba.len()
            ));
        }
        Ok(TextureImage {
            width,
            height,
            rgba,
        })
    })
    .unwrap_or_else(|_| Err("the KTX2 transcoder failed on this image (a panic, contained)".into()))
}

/// Standard base64 (padding optional; whitespace ignored).
fn base64_decode(text: &str) -> Result<Vec<u8>, String> {
    let mut out = Vec::with_capacity(text.len() / 4 * 3);
    let (mut acc, mut bits) = (0u32, 0u32);
    for c in text.bytes() {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            b'=' | b' ' | b'\n' | b'\r' | b'\t' => continue,
            _ => return Err("its data URI is not valid base64".to_string()),
        };
        acc = (acc << 6) | u32::from(v);
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
        }
    }
    Ok(out)
}

/// Reads any accessor of up to four components (float, or integer normalized or not) as
/// `[f32; 4]` elements (missing components are 0, alpha 1 for colors is the caller's job).
pub(super) fn read_elements(acc: &Accessor<'_>, buffers: &[Data]) -> Result<Vec<[f32; 4]>, String> {
    let dims = match acc.dimensions() {
        Dimensions::Scalar => 1,
        Dimensions::Vec2 => 2,
        Dimensions::Vec3 => 3,
        Dimensions::Vec4 => 4,
        d => return Err(format!("expected up to four components, found {d:?}")),
    };
    let (bytes, stride) = super::gltf::check_accessor(acc, buffers)?;
    let ty = acc.data_type();
    let size = ty.size();
    let normalized = acc.normalized();
    let component = |b: &[u8]| -> f32 {
        match ty {
            DataType::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            DataType::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
            DataType::U8 if normalized => f32::from(b[0]) / 255.0,
            DataType::U8 => f32::from(b[0]),
            DataType::I8 if normalized => (f32::from(b[0] as i8) / 127.0).max(-1.0),
            DataType::I8 => f32::from(b[0] as i8),
            DataType::U16 if normalized => f32::from(u16::from_le_bytes([b[0], b[1]])) / 65535.0,
            DataType::U16 => f32::from(u16::from_le_bytes([b[0], b[1]])),
            DataType::I16 if normalized => {
                (f32::from(i16::from_le_bytes([b[0], b[1]])) / 32767.0).max(-1.0)
            }
            DataType::I16 => f32::from(i16::from_le_bytes([b[0], b[1]])),
        }
    };
    Ok((0..acc.count())
        .map(|i| {
            let e = &bytes[i * stride..];
            let mut out = [0.0; 4];
            for (k, o) in out.iter_mut().enumerate().take(dims) {
                *o = component(&e[k * size..]);
            }
            out
        })
        .collect())
}

/// A primitive's COLOR_0 and the TEXCOORD_n its material's base color texture reads, under
/// that texture's `KHR_texture_transform`, for its `n` vertices (defaults where absent), and
/// whether it had vertex colors (texture coordinates alone matter only with a texture).
/// Non-finite values, read or transformed, are an error naming the attribute.
pub(super) fn primitive_attributes(
    prim: &::gltf::Primitive<'_>,
    buffers: &[Data],
    n: usize,
    label: &str,
    draco: Option<&DracoPrimitive>,
) -> Result<(Vec<VertexAttributes>, bool), String> {
    let material = prim.material();
    let set = MaterialLoader::tex_coord_set(&material);
    let transform = MaterialLoader::uv_transform(&material).filter(|t| !t.is_identity());
    let mut out = vec![VertexAttributes::default(); n];
    let mut found = false;
    for (semantic, name) in [
        (Semantic::TexCoords(set), format!("TEXCOORD_{set}")),
        (Semantic::Colors(0), "COLOR_0".to_string()),
    ] {
        let Some(acc) = prim.get(&semantic) else {
            continue;
        };
        let elems = match draco.and_then(|d| d.attribute(&name)) {
            Some(values) => values.to_vec(),
            None => read_elements(&acc, buffers)
                .map_err(|e| format!("{label}: {name} accessor {}: {e}", acc.index()))?,
        };
        if elems.len() != n {
            return Err(format!(
                "{label}: {name} accessor {} has {} elements for {n} vertices",
                acc.index(),
                elems.len()
            ));
        }
        if let Some(i) = elems.iter().position(|e| !e.iter().all(|c| c.is_finite())) {
            return Err(format!("{label}: {name} of vertex {i} is not finite"));
        }
        let rgb_only = acc.dimensions() == Dimensions::Vec3;
        for (i, (a, e)) in out.iter_mut().zip(&elems).enumerate() {
            if matches!(semantic, Semantic::TexCoords(_)) {
                a.uv = [e[0], e[1]];
                if let Some(t) = transform {
                    a.uv = t.apply(a.uv);
                    if !a.uv.iter().all(|c| c.is_finite()) {
                        return Err(format!(
                            "{label}: {name} of vertex {i} is not finite after the \
                             material's KHR_texture_transform"
                        ));
                    }
                }
            } else {
                let alpha = if rgb_only { 1.0 } else { e[3] };
                a.color =
                    [e[0], e[1], e[2], alpha].map(|c| (c.clamp(0.0, 1.0) * 255.0 + 0.5) as u8);
            }
        }
        found |= !matches!(semantic, Semantic::TexCoords(_));
    }
    Ok((out, found))
}

#[cfg(test)]
mod tests {
    use super::{base64_decode, MaterialLoader, UvTransform};

    /// The extension's own example: offset (0, 1), a quarter turn and half scale use the lower
    /// left quadrant of the image, turned clockwise.
    #[test]
    fn texture_transforms_map_coordinates_as_the_extension_says() {
        let t = UvTransform::new([0.0, 1.0], std::f32::consts::FRAC_PI_2, [0.5, 0.5]);
        let corners = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
        let want = [[0.0, 1.0], [0.0, 0.5], [0.5, 0.5], [0.5, 1.0]];
        for (c, w) in corners.into_iter().zip(want) {
            let got = t.apply(c);
            assert!(
                (got[0] - w[0]).abs() < 1e-6 && (got[1] - w[1]).abs() < 1e-6,
                "{c:?} -> {got:?}, want {w:?}"
            );
        }
        // Scale before offset; the identity is recognised.
        let t = UvTransform::new([0.25, -1.0], 0.0, [2.0, 3.0]);
        assert_eq!(t.apply([1.0, 1.0]), [2.25, 2.0]);
        assert!(UvTransform::new([0.0; 2], 0.0, [1.0; 2]).is_identity());
        assert!(!t.is_identity());
    }

    #[test]
    fn blend_materials_get_one_warning_that_names_the_first_few() {
        let warning = |blended: Vec<usize>| {
            MaterialLoader {
                blended,
                ..Default::default()
            }
            .warnings()
        };
        let tail = "blended after the opaque objects, back to front by object, tested \
                    against the opaque depth when heavy; alpha-tested at 0.5 in gi and in \
                    moving copies";
        assert!(warning(vec![]).is_empty());
        assert_eq!(
            warning(vec![3]),
            [format!("material 3: alpha mode BLEND, {tail}")]
        );
        assert_eq!(
            warning(vec![3, 7, 12]),
            [format!("materials 3, 7 and 12: alpha mode BLEND, {tail}")]
        );
        assert_eq!(
            warning((0..200).collect()),
            [format!(
                "materials 0, 1, 2, 3, 4, 5 and 194 more: alpha mode BLEND, {tail}"
            )]
        );
    }

    #[test]
    fn images_that_fail_for_one_reason_share_a_warning() {
        let ktx2 = "format image/ktx2 is not supported (PNG and JPEG are)".to_string();
        let loader = MaterialLoader {
            failed_images: vec![
                (2, ktx2.clone()),
                (4, "cannot read 'a.png'".to_string()),
                (5, ktx2.clone()),
                (9, ktx2),
            ],
            ..Default::default()
        };
        assert_eq!(
            loader.warnings(),
            [
                "images 2, 5 and 9: format image/ktx2 is not supported (PNG and JPEG are); \
                 drawn without these textures",
                "image 4: cannot read 'a.png'; drawn without this texture",
            ]
        );
    }

    #[test]
    fn base64_decodes() {
        assert_eq!(base64_decode("TWFu").unwrap(), b"Man");
        assert_eq!(base64_decode("TWE=").unwrap(), b"Ma");
        assert_eq!(base64_decode("TQ==").unwrap(), b"M");
        assert!(base64_decode("T*==").is_err());
    }
}
