//! glTF content beyond core geometry: `EXT_meshopt_compression` buffer views (decoded with the
//! `meshopt` crate), `KHR_mesh_quantization` (accepted: the accessor readers take its integer
//! types), `EXT_texture_webp` (the material loader reads its image), camera nodes as the path
//! `gltf-cameras`, the first `KHR_lights_punctual` spot light as the light path `gltf-light`,
//! and one warning per extension that is not honored.

use ::gltf::accessor::Dimensions;
use ::gltf::animation::{Interpolation, Property};
use ::gltf::buffer::Data;
use ::gltf::json::validation::Checked;
use ::gltf::khr_lights_punctual::Kind;
use ::gltf::{Document, Node};
use glam::{Mat4, Quat, Vec3};
use serde_json::Value;

use super::paths::{keys_to_path, PathKey};
use super::CameraPath;

/// Name of the path through the file's camera nodes.
pub const CAMERAS_PATH: &str = "gltf-cameras";
/// Name of the path of the file's first spot light (position and the point it looks at).
pub const LIGHT_PATH: &str = "gltf-light";
const MESHOPT: &str = "EXT_meshopt_compression";
const QUANTIZATION: &str = "KHR_mesh_quantization";
/// The extension that places a node's mesh many times (the loader reads it while it walks
/// the nodes).
pub const INSTANCING: &str = "EXT_mesh_gpu_instancing";
/// The extension that gives a texture a WebP image (decoded like PNG and JPEG).
pub const WEBP: &str = "EXT_texture_webp";
/// The extension that gives a texture a KTX2 Basis Universal image (transcoded to RGBA8).
pub const BASISU: &str = "KHR_texture_basisu";
/// Extensions the loader honors; any other one in `extensionsUsed` gets a warning.
pub const HONORED: &[&str] = &[
    MESHOPT,
    QUANTIZATION,
    "KHR_lights_punctual",
    "KHR_texture_transform",
    INSTANCING,
    WEBP,
    BASISU,
    "KHR_materials_pbrSpecularGlossiness",
    "KHR_materials_unlit",
    super::gltf_draco::DRACO,
];
/// Extensions the loader does not honor but loads a file that requires anyway: they only give
/// textures images in a format it cannot decode (AVIF), so the file is drawn without those textures
/// (with warnings) instead of being refused.
pub const TOLERATED: &[&str] = &["EXT_texture_avif"];
/// Largest buffer a meshopt fallback may declare (it is allocated to receive decoded data).
const MAX_FALLBACK_BYTES: usize = 1 << 32;
/// Most samples taken of an animated light.
const MAX_LIGHT_SAMPLES: usize = 1024;
/// Half the angle the default sweep turns a static spot light through, degrees.
const SWEEP_DEGREES: f32 = 20.0;

/// Whether a validation error at `path` is `extensionsRequired[i] = "X"` for an X that is
/// honored or tolerated.
pub fn is_honored_required(path: &str) -> bool {
    path.starts_with("extensionsRequired")
        && HONORED
            .iter()
            .chain(TOLERATED)
            .any(|e| path.ends_with(&format!("\"{e}\"")))
}

/// One warning per used extension that is not honored (its content is ignored).
pub fn unsupported_warnings(doc: &Document) -> Vec<String> {
    doc.extensions_used()
        .filter(|e| !HONORED.contains(e))
        .map(|e| format!("extension {e} is not supported, ignored"))
        .collect()
}

fn meshopt_ext(ext: Option<&serde_json::Map<String, Value>>) -> Option<&Value> {
    ext?.get(MESHOPT)
}

/// For a buffer marked as an `EXT_meshopt_compression` fallback: zeros of its declared length
/// (decoded views are written into it); `Ok(None)` for any other buffer.
pub fn fallback_data(doc: &Document, index: usize) -> Result<Option<Data>, String> {
    let Some(buffer) = doc.as_json().buffers.get(index) else {
        return Ok(None);
    };
    let ext = buffer.extensions.as_ref().map(|e| &e.others);
    let fallback = meshopt_ext(ext)
        .and_then(|m| m.get("fallback"))
        .and_then(Value::as_bool)
        .unwrap_or(false);
    if !fallback {
        return Ok(None);
    }
    let len = usize::try_from(buffer.byte_length.0)
        .ok()
        .filter(|&l| l <= MAX_FALLBACK_BYTES)
        .ok_or_else(|| format!("meshopt fallback buffer {index} is too large"))?;
    Ok(Some(Data(vec![0; len])))
}

/// One `EXT_meshopt_compression` buffer view's parameters.
struct Compressed {
    buffer: usize,
    offset: usize,
    length: usize,
    stride: usize,
    count: usize,
    mode: String,
    filter: String,
}

fn field(ext: &Value, name: &str, default: Option<u64>) -> Result<usize, String> {
    ext.get(name)
        .map(|v| {
            v.as_u64()
                .ok_or_else(|| format!("\"{name}\" is not a count"))
        })
        .unwrap_or_else(|| default.ok_or_else(|| format!("missing \"{name}\"")))
        .and_then(|v| usize::try_from(v).map_err(|_| format!("\"{name}\" is too large")))
}

fn parse_compressed(ext: &Value) -> Result<Compressed, String> {
    let text = |name: &str, default: &str| -> Result<String, String> {
        match ext.get(name) {
            None => Ok(default.to_string()),
            Some(v) => v
                .as_str()
                .map(str::to_string)
                .ok_or_else(|| format!("\"{name}\" is not a string")),
        }
    };
    Ok(Compressed {
        buffer: field(ext, "buffer", None)?,
        offset: field(ext, "byteOffset", Some(0))?,
        length: field(ext, "byteLength", None)?,
        stride: field(ext, "byteStride", None)?,
        count: field(ext, "count", None)?,
        mode: text("mode", "")?,
        filter: text("filter", "NONE")?,
    })
}

/// Decodes every `EXT_meshopt_compression` buffer view into the bytes its uncompressed view
/// covers, so the accessor readers see plain data.
pub fn decode_meshopt(doc: &Document, buffers: &mut [Data]) -> Result<(), String> {
    for (i, view) in doc.as_json().buffer_views.iter().enumerate() {
        let Some(ext) = meshopt_ext(view.extensions.as_ref().map(|e| &e.others)) else {
            continue;
        };
        let label = format!("buffer view {i} ({MESHOPT})");
        let c = parse_compressed(ext).map_err(|e| format!("{label}: {e}"))?;
        let src = buffers
            .get(c.buffer)
            .and_then(|b| b.0.get(c.offset..c.offset.checked_add(c.length)?))
            .ok_or_else(|| format!("{label}: compressed bytes lie outside buffer {}", c.buffer))?
            .to_vec();
        let decoded = decode_view(&src, &c).map_err(|e| format!("{label}: {e}"))?;
        let start = view.byte_offset.map(|o| o.0).unwrap_or(0) as usize;
        let len = view.byte_length.0 as usize;
        if decoded.len() > len {
            return Err(format!(
                "{label}: {} decoded bytes exceed the view's {len}",
                decoded.len()
            ));
        }
        let dst = buffers
            .get_mut(view.buffer.value())
            .and_then(|b| b.0.get_mut(start..start.checked_add(decoded.len())?))
            .ok_or_else(|| format!("{label}: the view lies outside its buffer"))?;
        dst.copy_from_slice(&decoded);
    }
    Ok(())
}

fn meshopt_err(e: meshopt::Error) -> String {
    format!("meshopt cannot decode it ({e})")
}

/// Decodes one compressed view (mode ATTRIBUTES, TRIANGLES or INDICES) and applies its filter.
fn decode_view(src: &[u8], c: &Compressed) -> Result<Vec<u8>, String> {
    let mut out = match (c.mode.as_str(), c.stride) {
        ("ATTRIBUTES", s) if s % 4 == 0 && (4..=256).contains(&s) => {
            decode_attributes(src, c.count, s)
        }
        ("TRIANGLES", 2) => le_bytes16(meshopt::decode_index_buffer::<u16>(src, c.count)),
        ("TRIANGLES", 4) => le_bytes32(meshopt::decode_index_buffer::<u32>(src, c.count)),
        ("INDICES", 2) => le_bytes16(meshopt::decode_index_sequence::<u16>(src, c.count)),
        ("INDICES", 4) => le_bytes32(meshopt::decode_index_sequence::<u32>(src, c.count)),
        (mode, stride) => {
            return Err(format!(
                "mode \"{mode}\" with byteStride {stride} is not valid"
            ))
        }
    }?;
    apply_filter(&mut out, c)?;
    Ok(out)
}

fn le_bytes16(v: meshopt::Result<Vec<u16>>) -> Result<Vec<u8>, String> {
    Ok(v.map_err(meshopt_err)?
        .iter()
        .flat_map(|x| x.to_le_bytes())
        .collect())
}

fn le_bytes32(v: meshopt::Result<Vec<u32>>) -> Result<Vec<u8>, String> {
    Ok(v.map_err(meshopt_err)?
        .iter()
        .flat_map(|x| x.to_le_bytes())
        .collect())
}

/// A vertex of `N` bytes (the decoder's element type for a stride of `N`).
#[derive(Clone, Copy)]
struct Element<const N: usize>([u8; N]);

impl<const N: usize> Default for Element<N> {
    fn default() -> Self {
        Element([0; N])
    }
}

fn decode_elements<const N: usize>(src: &[u8], count: usize) -> Result<Vec<u8>, String> {
    let v: Vec<Element<N>> = meshopt::decode_vertex_buffer(src, count).map_err(meshopt_err)?;
    Ok(v.iter().flat_map(|e| e.0).collect())
}

/// `meshopt::decode_vertex_buffer` for a stride (multiple of 4, at most 256) known at run time.
fn decode_attributes(src: &[u8], count: usize, stride: usize) -> Result<Vec<u8>, String> {
    macro_rules! by_stride {
        ($($n:literal)*) => {
            match stride {
                $($n => decode_elements::<$n>(src, count),)*
                other => Err(format!("byteStride {other} is not a multiple of 4 up to 256")),
            }
        };
    }
    by_stride!(4 8 12 16 20 24 28 32 36 40 44 48 52 56 60 64 68 72 76 80 84 88 92 96 100 104
        108 112 116 120 124 128 132 136 140 144 148 152 156 160 164 168 172 176 180 184 188 192
        196 200 204 208 212 216 220 224 228 232 236 240 244 248 252 256)
}

/// Applies a view's filter (NONE, OCTAHEDRAL, QUATERNION, EXPONENTIAL) in place.
fn apply_filter(data: &mut [u8], c: &Compressed) -> Result<(), String> {
    match (c.filter.as_str(), c.stride) {
        ("NONE", _) => {}
        ("OCTAHEDRAL", 4) => {
            let mut v: Vec<[i8; 4]> = data
                .chunks_exact(4)
                .map(|b| [b[0] as i8, b[1] as i8, b[2] as i8, b[3] as i8])
                .collect();
            meshopt::decode_filter_oct(&mut v);
            for (d, x) in data.chunks_exact_mut(4).zip(v) {
                d.copy_from_slice(&x.map(|c| c as u8));
            }
        }
        ("OCTAHEDRAL", 8) | ("QUATERNION", 8) => {
            let mut v: Vec<[i16; 4]> = data
                .chunks_exact(8)
                .map(|b| std::array::from_fn(|k| i16::from_le_bytes([b[2 * k], b[2 * k + 1]])))
                .collect();
            if c.filter == "OCTAHEDRAL" {
                meshopt::decode_filter_oct(&mut v);
            } else {
                meshopt::decode_filter_quat(&mut v);
            }
            for (d, x) in data.chunks_exact_mut(8).zip(v) {
                let bytes: Vec<u8> = x.iter().flat_map(|c| c.to_le_bytes()).collect();
                d.copy_from_slice(&bytes);
            }
        }
        // Each 32-bit component is decoded on its own, so any stride is a run of them.
        ("EXPONENTIAL", s) if s % 4 == 0 => {
            let mut v: Vec<[u32; 1]> = data
                .chunks_exact(4)
                .map(|b| [u32::from_le_bytes([b[0], b[1], b[2], b[3]])])
                .collect();
            meshopt::decode_filter_exp(&mut v);
            for (d, x) in data.chunks_exact_mut(4).zip(v) {
                d.copy_from_slice(&x[0].to_le_bytes());
            }
        }
        (filter, stride) => {
            return Err(format!(
                "filter \"{filter}\" with byteStride {stride} is not supported"
            ))
        }
    }
    Ok(())
}

/// World transform of every node reachable from `roots` (its first instance); `None` for the
/// others.
pub fn world_transforms(doc: &Document, roots: &[Node<'_>]) -> Vec<Option<Mat4>> {
    let n = doc.nodes().len();
    let mut world = vec![None; n];
    let mut stack: Vec<(Node<'_>, Mat4, usize)> = roots
        .iter()
        .rev()
        .map(|r| (r.clone(), Mat4::IDENTITY, 0))
        .collect();
    while let Some((node, parent, depth)) = stack.pop() {
        if depth > n || world.get(node.index()).is_none_or(|w| w.is_some()) {
            continue;
        }
        let m = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        world[node.index()] = Some(m);
        let children: Vec<_> = node.children().collect();
        for c in children.into_iter().rev() {
            stack.push((c, m, depth + 1));
        }
    }
    world
}

/// A key at `m`'s origin looking down its -Z axis.
fn key_of(m: &Mat4, time: f32) -> Option<PathKey> {
    let position = m.transform_point3(Vec3::ZERO);
    let forward = m.transform_vector3(Vec3::NEG_Z).try_normalize()?;
    position.is_finite().then_some(PathKey {
        time,
        position,
        target: position + forward,
    })
}

/// The path through the camera nodes in document order (one key per camera).
pub fn camera_path(doc: &Document, world: &[Option<Mat4>]) -> Option<CameraPath> {
    let keys: Vec<PathKey> = doc
        .nodes()
        .filter(|n| n.camera().is_some())
        .filter_map(|n| world.get(n.index()).copied().flatten())
        .enumerate()
        .filter_map(|(i, m)| key_of(&m, i as f32))
        .collect();
    (!keys.is_empty()).then(|| keys_to_path(CAMERAS_PATH, &keys))
}

/// The first spot light's path: its animation when its node is animated, else a sweep of
/// ±`SWEEP_DEGREES` (20°) around its direction. Warnings go to `warnings`.
pub fn light_path(
    doc: &Document,
    world: &[Option<Mat4>],
    buffers: &[Data],
    warnings: &mut Vec<String>,
) -> Option<CameraPath> {
    let (node, m) = doc.nodes().find_map(|n| {
        let spot = matches!(n.light().map(|l| l.kind()), Some(Kind::Spot { .. }));
        let m = world.get(n.index()).copied().flatten()?;
        spot.then_some((n, m))
    })?;
    let local = Mat4::from_cols_array_2d(&node.transform().matrix());
    let parent = m * local.inverse();
    let animated = animated_keys(doc, &node, &parent, buffers, warnings);
    if animated.len() >= 2 {
        return Some(keys_to_path(LIGHT_PATH, &animated));
    }
    let key = key_of(&m, 0.0)?;
    let dir = key.target - key.position;
    let axis = if dir.normalize().dot(Vec3::Y).abs() < 0.9 {
        Vec3::Y
    } else {
        Vec3::X
    };
    let keys: Vec<PathKey> = [-1.0f32, 0.0, 1.0]
        .iter()
        .enumerate()
        .map(|(i, s)| PathKey {
            time: i as f32,
            position: key.position,
            target: key.position
                + Quat::from_axis_angle(axis, (s * SWEEP_DEGREES).to_radians()) * dir,
        })
        .collect();
    Some(keys_to_path(LIGHT_PATH, &keys))
}

/// A node's rest translation, rotation and scale.
pub(super) type Trs = (Vec3, Quat, Vec3);

/// The rest translation, rotation and scale of `node`.
pub(super) fn rest_trs(node: &Node<'_>) -> Trs {
    let (t, r, s) = node.transform().decomposed();
    (
        Vec3::from_array(t),
        Quat::from_array(r),
        Vec3::from_array(s),
    )
}

/// The local transform at time `t` of a node at rest at `rest` under `channels`, its own (of
/// two channels of one property, the later one wins).
pub(super) fn local_at<'c>(
    (mut translation, mut rotation, mut scale): Trs,
    channels: impl IntoIterator<Item = &'c Channel>,
    t: f32,
) -> Mat4 {
    for c in channels {
        let v = c.at(t);
        match c.property {
            Property::Rotation => rotation = Quat::from_array(v).normalize(),
            Property::Scale => scale = Vec3::new(v[0], v[1], v[2]),
            _ => translation = Vec3::new(v[0], v[1], v[2]),
        }
    }
    Mat4::from_scale_rotation_translation(scale, rotation, translation)
}

/// A sampler's key times and interpolation, and where a time falls among them: what the
/// transform and the morph-weights channels share.
#[derive(Clone, Debug)]
struct Keys {
    times: Vec<f32>,
    interpolation: Interpolation,
}

/// Where a time falls among the keys: on key `k` (before the first, after the last, or
/// between two STEP keys), or between keys `k` and `k + 1` at fraction `f`.
enum Span {
    Key(usize),
    Between(usize, f32),
}

impl Keys {
    /// The times of the sampler input `input` (a SCALAR accessor).
    fn read(
        input: &::gltf::Accessor<'_>,
        interpolation: Interpolation,
        buffers: &[Data],
    ) -> Result<Keys, String> {
        let times = super::gltf_material::read_elements(input, buffers)?
            .into_iter()
            .map(|e| e[0])
            .collect();
        Ok(Keys {
            times,
            interpolation,
        })
    }

    /// Whether the times can be played: some, increasing and finite.
    fn usable(&self) -> bool {
        !self.times.is_empty()
            && self.times.windows(2).all(|w| w[0] < w[1])
            && self.times.iter().all(|t| t.is_finite())
    }

    /// Output groups the keys need: one per key, three for a cubic spline (in-tangent, value,
    /// out-tangent).
    fn groups(&self) -> usize {
        self.times.len() * if self.cubic() { 3 } else { 1 }
    }

    fn cubic(&self) -> bool {
        self.interpolation == Interpolation::CubicSpline
    }

    /// The output group that holds key `k`'s value (cubic splines use their key values only).
    fn value_group(&self, k: usize) -> usize {
        if self.cubic() {
            3 * k + 1
        } else {
            k
        }
    }

    /// Where `t` falls (clamped to the first and last keys).
    fn span(&self, t: f32) -> Span {
        let n = self.times.len();
        let i = self.times.partition_point(|&x| x <= t);
        if i == 0 {
            return Span::Key(0);
        }
        if i >= n || self.interpolation == Interpolation::Step {
            return Span::Key(i.min(n) - 1);
        }
        let (a, b) = (self.times[i - 1], self.times[i]);
        Span::Between(i - 1, ((t - a) / (b - a).max(1e-9)).clamp(0.0, 1.0))
    }

    /// The time of the last key.
    fn end(&self) -> f32 {
        self.times.last().copied().unwrap_or(0.0)
    }
}

/// One animation channel of a node: key times, values (translation or scale xyz, or rotation
/// xyzw) and interpolation.
#[derive(Clone, Debug)]
pub(super) struct Channel {
    pub node: usize,
    pub property: Property,
    keys: Keys,
    values: Vec<[f32; 4]>,
}

impl Channel {
    /// The channel's value at `t` (clamped; cubic splines use their key values only).
    pub fn at(&self, t: f32) -> [f32; 4] {
        let value = |k: usize| self.values[self.keys.value_group(k)];
        match self.keys.span(t) {
            Span::Key(k) => value(k),
            Span::Between(k, f) => {
                let (va, vb) = (value(k), value(k + 1));
                if self.property == Property::Rotation {
                    Quat::from_array(va)
                        .normalize()
                        .slerp(Quat::from_array(vb).normalize(), f)
                        .to_array()
                } else {
                    std::array::from_fn(|c| va[c] + (vb[c] - va[c]) * f)
                }
            }
        }
    }

    /// The time of its last key.
    pub fn end(&self) -> f32 {
        self.keys.end()
    }

    /// Reads a translation, rotation or scale channel; `Ok(None)` for other properties (morph
    /// weights) and for channels without usable keys (empty, unsorted, short or non-finite).
    pub fn read(
        doc: &Document,
        ch: &::gltf::animation::Channel<'_>,
        buffers: &[Data],
    ) -> Result<Option<Channel>, String> {
        // A path or an interpolation the gltf crate does not know (`pointer` of
        // KHR_animation_pointer) is not valid to it: `property()` and `interpolation()` would
        // panic on them, so they are read from the JSON.
        let Some(json) = channel_json(doc, ch) else {
            return Ok(None);
        };
        let (property, interpolation) = match (json.path, json.interpolation) {
            (
                Checked::Valid(p @ (Property::Translation | Property::Rotation | Property::Scale)),
                Checked::Valid(i),
            ) => (p, i),
            _ => return Ok(None),
        };
        // Read with the loader's own accessor reader: the crate's reader panics on component
        // types the spec does not allow here.
        let (input, output) = (&json.input, &json.output);
        let dims = match property {
            Property::Rotation => Dimensions::Vec4,
            _ => Dimensions::Vec3,
        };
        json.check_dimensions(dims)?;
        let keys = Keys::read(input, interpolation, buffers)?;
        let values = super::gltf_material::read_elements(output, buffers)?;
        let finite = values.iter().flatten().all(|v| v.is_finite());
        if !keys.usable() || values.len() < keys.groups() || !finite {
            return Ok(None);
        }
        Ok(Some(Channel {
            node: json.node,
            property,
            keys,
            values,
        }))
    }
}

/// A morph-weights channel of a node: key times, each key's weights (one per morph target)
/// and interpolation.
#[derive(Clone, Debug)]
pub(super) struct WeightsChannel {
    pub node: usize,
    keys: Keys,
    /// `targets` weights per output group ([`Keys::groups`]).
    values: Vec<f32>,
    targets: usize,
}

impl WeightsChannel {
    /// Writes the weights at `t` into `out` (one per target; clamped in time; cubic splines
    /// use their key values only).
    pub fn at(&self, t: f32, out: &mut Vec<f32>) {
        let n = self.targets;
        let key = |k: usize| {
            let start = self.keys.value_group(k) * n;
            &self.values[start..start + n]
        };
        out.clear();
        match self.keys.span(t) {
            Span::Key(k) => out.extend_from_slice(key(k)),
            Span::Between(k, f) => {
                out.extend(key(k).iter().zip(key(k + 1)).map(|(x, y)| x + (y - x) * f))
            }
        }
    }

    /// The time of its last key.
    pub fn end(&self) -> f32 {
        self.keys.end()
    }

    /// Reads a morph-weights channel; `Ok(None)` for other properties and for channels
    /// without usable keys (empty, unsorted, non-finite, or outputs that are not a whole
    /// number of weights per key).
    pub fn read(
        doc: &Document,
        ch: &::gltf::animation::Channel<'_>,
        buffers: &[Data],
    ) -> Result<Option<WeightsChannel>, String> {
        let Some(json) = channel_json(doc, ch) else {
            return Ok(None);
        };
        let (Checked::Valid(Property::MorphTargetWeights), Checked::Valid(interpolation)) =
            (json.path, json.interpolation)
        else {
            return Ok(None);
        };
        let (input, output) = (&json.input, &json.output);
        json.check_dimensions(Dimensions::Scalar)?;
        let keys = Keys::read(input, interpolation, buffers)?;
        let values: Vec<f32> = super::gltf_material::read_elements(output, buffers)?
            .into_iter()
            .map(|e| e[0])
            .collect();
        let groups = keys.groups();
        let finite = values.iter().all(|v| v.is_finite());
        if !keys.usable() || values.is_empty() || !values.len().is_multiple_of(groups) || !finite {
            return Ok(None);
        }
        Ok(Some(WeightsChannel {
            node: json.node,
            targets: values.len() / groups,
            keys,
            values,
        }))
    }
}

/// An animation channel as its JSON gives it, its indices checked against the document.
struct ChannelJson<'d> {
    node: usize,
    path: Checked<Property>,
    interpolation: Checked<Interpolation>,
    input: ::gltf::Accessor<'d>,
    output: ::gltf::Accessor<'d>,
}

impl ChannelJson<'_> {
    /// Checks the sampler: scalar key times and values of `dims` (an error saying what they
    /// are otherwise).
    fn check_dimensions(&self, dims: Dimensions) -> Result<(), String> {
        let (input, output) = (self.input.dimensions(), self.output.dimensions());
        if input != Dimensions::Scalar || output != dims {
            return Err(format!(
                "its input is {input:?} and its output {output:?} ({dims:?} expected)"
            ));
        }
        Ok(())
    }
}

/// The JSON of an animation channel and its sampler, `None` when an index in it (target node,
/// sampler, input or output accessor) is out of range: the crate's accessors for them unwrap.
fn channel_json<'d>(
    doc: &'d Document,
    ch: &::gltf::animation::Channel<'_>,
) -> Option<ChannelJson<'d>> {
    let anim = doc.as_json().animations.get(ch.animation().index())?;
    let json = anim.channels.get(ch.index())?;
    let sampler = anim.samplers.get(json.sampler.value())?;
    let node = json.target.node.value();
    if node >= doc.nodes().len() {
        return None;
    }
    Some(ChannelJson {
        node,
        path: json.target.path,
        interpolation: sampler.interpolation,
        input: doc.accessors().nth(sampler.input.value())?,
        output: doc.accessors().nth(sampler.output.value())?,
    })
}

/// Reads the translation and rotation channels that animate `node`; channels whose accessors
/// do not check out are skipped with a warning.
fn node_channels(
    doc: &Document,
    node: &Node<'_>,
    buffers: &[Data],
    warnings: &mut Vec<String>,
) -> Vec<Channel> {
    let mut out = Vec::new();
    for anim in doc.animations() {
        for ch in anim.channels() {
            let json = channel_json(doc, &ch);
            if !json.is_some_and(|j| {
                j.node == node.index()
                    && matches!(
                        j.path,
                        Checked::Valid(Property::Translation | Property::Rotation)
                    )
            }) {
                continue;
            }
            match Channel::read(doc, &ch, buffers) {
                Ok(Some(c)) => out.push(c),
                Ok(None) => {}
                Err(e) => warnings.push(format!(
                    "animation {} channel {}: {e}, light animation ignored",
                    anim.index(),
                    ch.index()
                )),
            }
        }
    }
    out
}

/// Keys of `node` sampled at its animation's key times (at most [`MAX_LIGHT_SAMPLES`]).
fn animated_keys(
    doc: &Document,
    node: &Node<'_>,
    parent: &Mat4,
    buffers: &[Data],
    warnings: &mut Vec<String>,
) -> Vec<PathKey> {
    let channels = node_channels(doc, node, buffers, warnings);
    let mut times: Vec<f32> = channels
        .iter()
        .flat_map(|c| c.keys.times.iter().copied())
        .filter(|t| t.is_finite())
        .collect();
    times.sort_by(f32::total_cmp);
    times.dedup();
    if times.len() > MAX_LIGHT_SAMPLES {
        let n = times.len();
        times = (0..MAX_LIGHT_SAMPLES)
            .map(|i| times[i * (n - 1) / (MAX_LIGHT_SAMPLES - 1)])
            .collect();
    }
    let rest = rest_trs(node);
    times
        .iter()
        .filter_map(|&t| key_of(&(*parent * local_at(rest, &channels, t)), t))
        .collect()
}
