//! glTF 2.0 loading (.gltf with external or data-URI buffers, and .glb): flattens the node
//! hierarchy of the default scene into one [`Object`] per primitive instance over shared geometry,
//! validating every accessor so malformed files give a one-line error instead of a panic.

use std::borrow::Cow;
use std::collections::HashMap;
use std::path::Path;

use ::gltf::accessor::{DataType, Dimensions};
use ::gltf::buffer::Data;
use ::gltf::mesh::{Mode, Semantic};
use ::gltf::{Accessor, Document, Gltf, Node};
use glam::{Mat4, Vec3, Vec4};

use super::gltf_draco::DracoPrimitive;
use super::gltf_ext::INSTANCING;
use super::gltf_material::{primitive_attributes, MaterialLoader};
use super::{Aabb, CameraPath, CameraPose, Object, Scene, Vertex, VertexAttributes};
use crate::Error;

/// Direction towards the directional light the loader gives every glTF scene (not
/// normalized): from above, a little from the side.
pub const DEFAULT_SUN: Vec3 = Vec3::new(0.4, 1.0, 0.3);

/// Upper bound on node visits while flattening the hierarchy (guards against exponential DAGs).
const MAX_NODE_VISITS: usize = 10_000_000;

/// How far from the origin a vertex may lie, in scene units, after its node transforms. f32
/// keeps about 7 digits, so a scene this large cannot be drawn anyway; beyond it the products
/// of three coordinates in the path finder's ray tests would overflow.
pub(super) const MAX_COORDINATE: f32 = 1.0e12;

/// Loads a `.gltf` or `.glb` file into a [`Scene`].
///
/// Every triangle primitive reachable from the default scene (or the first scene, or all root
/// nodes when the file has no scenes) becomes one [`Object`] per node instance (and per
/// instance of a node's `EXT_mesh_gpu_instancing`); instances of the same mesh share their
/// vertex and index range. Returns the scene and a list of warnings about
/// content that was skipped (non-triangle primitives, unusable normals, ...).
///
/// Any malformed input (unreadable or truncated file, invalid JSON, missing or short buffers,
/// out-of-range accessors or indices, non-finite positions, no triangles at all) gives
/// [`Error::Scene`] with a single line `"<path>: <problem>"`.
pub fn load_gltf(path: &Path) -> Result<(Scene, Vec<String>), Error> {
    load_gltf_playing(path, &AnimationChoice::First)
}

/// Which of a glTF file's animations is played (`--animation`): its objects become movers
/// and the meshes it deforms are posed each frame; the others are not played.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum AnimationChoice {
    /// The file's first animation (the default).
    #[default]
    First,
    /// None: the scene is drawn in its default pose, every object static.
    Nothing,
    /// The animation at this index of the file's list.
    Index(usize),
    /// The first animation with this name.
    Name(String),
}

impl std::str::FromStr for AnimationChoice {
    type Err = std::convert::Infallible;

    /// `none`, an index (`0`, `1`, ...) or a name.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Ok(match s {
            "none" => AnimationChoice::Nothing,
            _ => match s.parse() {
                Ok(i) => AnimationChoice::Index(i),
                Err(_) => AnimationChoice::Name(s.to_string()),
            },
        })
    }
}

/// [`load_gltf`] playing the animation `choice` names instead of the first; a choice the file
/// does not have is an [`Error::Scene`] that lists the file's animations.
pub fn load_gltf_playing(
    path: &Path,
    choice: &AnimationChoice,
) -> Result<(Scene, Vec<String>), Error> {
    // Known panics of the `gltf` crate are checked for before it runs (see `parse` and
    // `check_external_uri`); any other is contained here and becomes the same one-line error.
    let loaded = std::panic::catch_unwind(|| load(path, choice))
        .unwrap_or_else(|_| Err("the glTF crate failed on this file (a panic, contained)".into()));
    loaded.map_err(|problem| {
        let problem = problem.replace(['\n', '\r'], " ");
        Error::Scene(format!("{}: {problem}", path.display()))
    })
}

/// Geometry of one loaded primitive in the scene's shared buffers (object space).
#[derive(Clone, Copy)]
struct PrimGeom {
    first_index: u32,
    index_count: u32,
    vertex_offset: u32,
    vertex_count: u32,
    /// The box of the vertices its triangles use, in the mesh's space.
    bounds: Aabb,
    color: Vec4,
    material: Option<u32>,
    /// For a mesh that the animation deforms, its index there.
    deformed: Option<usize>,
}

/// A mesh in one pose: its index, for a skinned node or one the animation deforms that node
/// (its vertices are its own), and the bits of its morph weights.
#[derive(Clone, PartialEq, Eq, Hash)]
struct MeshKey {
    mesh: usize,
    own_node: Option<usize>,
    weights: Vec<u32>,
}

/// What the default pose does to one node's mesh: its morph-target weights, and for a
/// skinned node its skin's joint matrices and the node's own world transform (which the
/// skin replaces; vertices without weight keep it).
struct Pose {
    weights: Vec<f32>,
    skin: Option<super::gltf_skin::SkinPose>,
    /// For a node whose mesh the animation deforms: how.
    deform: Option<Deform>,
}

/// How the animation deforms a node's mesh.
#[derive(Clone, Copy)]
struct Deform {
    node: usize,
    /// The rig of its skin (when skinned).
    rig: Option<usize>,
    /// Whether its morph weights are animated.
    morph: bool,
}

/// Accumulates shared geometry and objects while walking the document.
struct Loader<'a> {
    doc: &'a Document,
    buffers: &'a [Data],
    vertices: Vec<Vertex>,
    indices: Vec<u32>,
    objects: Vec<Object>,
    warnings: Vec<String>,
    meshes: HashMap<MeshKey, Vec<PrimGeom>>,
    /// Every node's world transform (skins read their joints' from it).
    world: Vec<Option<Mat4>>,
    /// The joint matrices of each skin used so far.
    skins: HashMap<usize, Vec<Mat4>>,
    /// The animation's rig of each skin it plays, by skin index.
    rigs: HashMap<usize, usize>,
    /// The file's first animation and the objects it moves.
    animation: super::animation::Animation,
    /// The `EXT_mesh_gpu_instancing` transforms of each node read so far (a node that several
    /// parents share is visited once per parent).
    node_instances: HashMap<usize, Option<Vec<Mat4>>>,
    /// Per primitive's first index: the first index of its copy with the winding turned over,
    /// for nodes that mirror it.
    mirrored: HashMap<u32, u32>,
    /// Per-vertex texture coordinates and colors, parallel to `vertices`.
    attributes: Vec<VertexAttributes>,
    /// The vertex ranges appended so far (offset, count), by a hash of their vertices and
    /// attributes: primitives with equal vertices (one accessor shared by several primitives,
    /// as multi-material exports write, or a mesh stored twice) share one range.
    vertex_ranges: HashMap<u64, Vec<(u32, u32)>>,
    materials: MaterialLoader,
}

fn load(path: &Path, choice: &AnimationChoice) -> Result<(Scene, Vec<String>), String> {
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read file: {e}"))?;
    let Gltf { document, blob } = parse(&bytes)?;
    drop(bytes);
    let base = path.parent().unwrap_or_else(|| Path::new("."));
    let mut buffers = load_buffers(&document, base, blob)?;
    super::gltf_ext::decode_meshopt(&document, &mut buffers)?;

    let mut warnings = super::gltf_ext::unsupported_warnings(&document);
    let played = chosen_animation(&document, choice)?;
    let mut animation = read_animation(&document, played, &buffers, &mut warnings);
    if document.skins().len() > 0 {
        let (nodes, order) = rest_nodes(&document);
        animation.set_nodes(nodes, order);
    }
    let mut loader = Loader {
        doc: &document,
        buffers: &buffers,
        vertices: Vec::new(),
        indices: Vec::new(),
        objects: Vec::new(),
        warnings,
        meshes: HashMap::new(),
        world: if document.skins().len() > 0 {
            super::gltf_skin::all_world_transforms(&document)
        } else {
            Vec::new()
        },
        skins: HashMap::new(),
        rigs: HashMap::new(),
        node_instances: HashMap::new(),
        animation,
        mirrored: HashMap::new(),
        attributes: Vec::new(),
        vertex_ranges: HashMap::new(),
        materials: MaterialLoader::new(base),
    };
    for root in root_nodes(&document) {
        loader.walk(&document, root)?;
    }
    let animation = std::mem::take(&mut loader.animation);
    let animations = document.animations().len();
    let moved = animation.objects.len() + animation.deformed.len();
    if moved > 0 {
        let skinned = match animation.deformed_meshes() {
            0 => String::new(),
            n => format!(", {n} mesh(es) skinned or morphed on the CPU each frame"),
        };
        let still = if loader.objects.is_empty() {
            " (nothing stands still: paths are found on their start)"
        } else {
            ""
        };
        loader.warnings.push(format!(
            "animation {} moves {moved} object(s): they are movers, placed every frame ({} \
             frames a second, a loop of {:.2} s{skinned}){still}{}",
            played.unwrap_or(0),
            super::animation::ANIMATION_FPS,
            animation.duration(),
            match animations - 1 {
                0 => String::new(),
                n => format!(
                    "; {n} other animation(s) not played ({}; --animation picks one)",
                    animation_list(&document, played)
                ),
            }
        ));
    } else if animations > 0 {
        loader.warnings.push(match (choice, played) {
            (AnimationChoice::Index(_) | AnimationChoice::Name(_), Some(i)) => {
                format!("animation {i} moves no mesh: the scene is drawn in its default pose")
            }
            (_, Some(_)) => format!(
                "{animations} animation(s) not played: the scene is drawn in its default pose"
            ),
            (_, None) => format!(
                "{animations} animation(s) not played (--animation none): the scene is drawn \
                 in its default pose"
            ),
        });
    }
    if loader.objects.is_empty() && moved == 0 {
        return Err("no triangle geometry".to_string());
    }

    let bounds = all_bounds(&loader.objects, Some(&animation));
    let name = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut paths = vec![default_path(&bounds)];
    let world = super::gltf_ext::world_transforms(&document, &root_nodes(&document));
    paths.extend(super::gltf_ext::camera_path(&document, &world));
    paths.extend(super::gltf_ext::light_path(
        &document,
        &world,
        &buffers,
        &mut loader.warnings,
    ));
    let mut mats = loader.materials;
    let moving = animation
        .objects
        .iter()
        .map(|a| &a.object)
        .chain(animation.deformed.iter().map(|a| &a.object))
        .filter_map(|o| o.material);
    mats.settle_opaque_blends(&mut loader.objects, &loader.attributes, moving);
    loader.warnings.extend(mats.warnings());
    let attributes = if mats.attributes_used || !mats.materials.is_empty() {
        loader.attributes
    } else {
        Vec::new()
    };
    let scene = Scene {
        name,
        vertices: loader.vertices,
        indices: loader.indices,
        objects: loader.objects,
        paths,
        sun_dir: DEFAULT_SUN.normalize(),
        attributes,
        materials: mats.materials,
        images: mats.images,
        textures: mats.textures,
        animation: (moved > 0).then(|| std::sync::Arc::new(animation)),
    };
    Ok((scene, loader.warnings))
}

/// Loads every buffer (GLB binary chunk, data URI or external file relative to `base`) and
/// checks it holds at least its declared byte length.
fn load_buffers(
    doc: &Document,
    base: &Path,
    mut blob: Option<Vec<u8>>,
) -> Result<Vec<Data>, String> {
    let mut buffers = Vec::with_capacity(doc.buffers().len());
    for buffer in doc.buffers() {
        let source = match buffer.source() {
            ::gltf::buffer::Source::Bin => "the GLB binary chunk".to_string(),
            ::gltf::buffer::Source::Uri(uri) if uri.starts_with("data:") => {
                "its data URI".to_string()
            }
            ::gltf::buffer::Source::Uri(uri) => format!("'{uri}'"),
        };
        if let Some(zeros) = super::gltf_ext::fallback_data(doc, buffer.index())? {
            buffers.push(zeros);
            continue;
        }
        if let ::gltf::buffer::Source::Uri(uri) = buffer.source() {
            check_external_uri(base, uri)
                .map_err(|e| format!("cannot load buffer {} from {source}: {e}", buffer.index()))?;
        }
        let data = Data::from_source_and_blob(buffer.source(), Some(base), &mut blob)
            .map_err(|e| format!("cannot load buffer {} from {source}: {e}", buffer.index()))?;
        if data.len() < buffer.length() {
            return Err(format!(
                "buffer {} is short: {} bytes declared, {} in {source}",
                buffer.index(),
                buffer.length(),
                data.len()
            ));
        }
        buffers.push(data);
    }
    Ok(buffers)
}

/// Checks an external buffer URI before the `gltf` crate reads it: its percent-encoding must
/// decode to UTF-8 (the crate unwraps the decoding and panics otherwise) and the file it names,
/// if it exists, must be a regular file (a device such as `/dev/zero` would be read forever).
fn check_external_uri(base: &Path, uri: &str) -> Result<(), String> {
    let path = if let Some(rest) = uri.strip_prefix("file://").or(uri.strip_prefix("file:")) {
        Path::new(rest).to_path_buf()
    } else if uri.contains(':') {
        return Ok(());
    } else {
        base.join(percent_decode(uri)?)
    };
    match std::fs::metadata(&path) {
        Ok(meta) if !meta.is_file() => Err("not a regular file".to_string()),
        _ => Ok(()),
    }
}

/// Decodes `%XX` escapes (others are kept as they are); an error if the result is not UTF-8.
pub(super) fn percent_decode(uri: &str) -> Result<String, String> {
    let bytes = uri.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        let hex = bytes
            .get(i + 1..i + 3)
            .filter(|h| h.iter().all(u8::is_ascii_hexdigit))
            .and_then(|h| std::str::from_utf8(h).ok())
            .and_then(|h| u8::from_str_radix(h, 16).ok());
        match (bytes[i], hex) {
            (b'%', Some(byte)) => {
                out.push(byte);
                i += 3;
            }
            (b, _) => {
                out.push(b);
                i += 1;
            }
        }
    }
    String::from_utf8(out).map_err(|_| "the URI's percent-encoding is not UTF-8".to_string())
}

/// Parses and validates the document, tolerating only missing POSITION `min`/`max` (required
/// by the spec but often omitted by exporters; bounds are computed from the data anyway) and
/// accessors without a buffer view (the spec allows them: their elements are zeros).
///
/// The crate's own validation indexes `accessors` with a primitive's POSITION index unchecked
/// (gltf-json 1.4.1 panics on `"POSITION": 2147483647`), so attribute indices are checked here
/// first and the crate's validation is run only then.
fn parse(bytes: &[u8]) -> Result<Gltf, String> {
    check_glb_header(bytes)?;
    let Gltf { document, blob } =
        Gltf::from_slice_without_validation(bytes).map_err(|e| format!("invalid glTF: {e}"))?;
    check_attribute_indices(document.as_json())?;
    let mut errors = Vec::new();
    {
        use ::gltf::json::validation::Validate;
        let root = document.as_json();
        root.validate(root, ::gltf::json::Path::new, &mut |path, error| {
            errors.push((path(), error))
        });
    }
    errors.retain(|(path, error)| {
        let path = path.to_string();
        let tolerated = (*error == ::gltf::json::validation::Error::Missing
            && (path.ends_with(".min")
                || path.ends_with(".max")
                || (path.starts_with("accessors[") && path.ends_with("].bufferView"))))
            || (*error == ::gltf::json::validation::Error::Unsupported
                && super::gltf_ext::is_honored_required(&path));
        !tolerated
    });
    if errors.is_empty() {
        Ok(Gltf { document, blob })
    } else {
        Err(validation_message(document.as_json(), &errors))
    }
}

/// Most validation errors a load error lists (a file can have thousands: one per accessor of a
/// compressed mesh).
const LISTED_ERRORS: usize = 5;

/// A load error for a document that failed validation: the required extensions the loader
/// does not support first (they often cause the rest), then the first [`LISTED_ERRORS`]
/// errors and how many more there are.
fn validation_message(
    root: &::gltf::json::Root,
    errors: &[(::gltf::json::Path, ::gltf::json::validation::Error)],
) -> String {
    let unsupported: Vec<&str> = root
        .extensions_required
        .iter()
        .enumerate()
        .filter(|(i, _)| {
            // The crate's path for it reads `extensionsRequired[i] = "NAME"`.
            let path = format!("extensionsRequired[{i}]");
            errors.iter().any(|(p, _)| p.to_string().starts_with(&path))
        })
        .map(|(_, name)| name.as_str())
        .collect();
    let mut out = String::from("invalid glTF: ");
    if !unsupported.is_empty() {
        out += &format!(
            "it requires extensions this loader does not support ({}); ",
            unsupported.join(", ")
        );
    }
    let listed: Vec<String> = errors
        .iter()
        .take(LISTED_ERRORS)
        .map(|(path, error)| format!("{path}: {error}"))
        .collect();
    out += &listed.join("; ");
    if errors.len() > LISTED_ERRORS {
        out += &format!("; and {} more", errors.len() - LISTED_ERRORS);
    }
    out
}

/// A GLB header's total length covers at least the header itself (the gltf crate subtracts the
/// header size from it unchecked: an overflow panic in debug builds, found by fuzzing).
fn check_glb_header(bytes: &[u8]) -> Result<(), String> {
    if !bytes.starts_with(b"glTF") {
        return Ok(());
    }
    let length = bytes
        .get(8..12)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .ok_or("invalid glTF: truncated GLB header")?;
    if length < 12 {
        return Err(format!(
            "invalid glTF: GLB length {length} is shorter than its 12-byte header"
        ));
    }
    Ok(())
}

/// Every primitive's attribute and morph-target accessor indices lie within `accessors`.
fn check_attribute_indices(root: &::gltf::json::Root) -> Result<(), String> {
    let count = root.accessors.len();
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            let targets = prim.targets.iter().flatten().flat_map(|t| {
                [&t.positions, &t.normals, &t.tangents]
                    .into_iter()
                    .flatten()
                    .map(|i| i.value())
            });
            let attributes = prim.attributes.values().map(|i| i.value());
            if let Some(bad) = attributes.chain(targets).find(|&i| i >= count) {
                return Err(format!(
                    "mesh {m} primitive {p}: attribute accessor {bad} out of range (the file has {count} accessors)"
                ));
            }
        }
    }
    Ok(())
}

/// The nodes to start from: the default scene's, else the first scene's, else every node that
/// is nobody's child.
fn root_nodes(doc: &Document) -> Vec<Node<'_>> {
    if let Some(scene) = doc.default_scene().or_else(|| doc.scenes().next()) {
        return scene.nodes().collect();
    }
    parentless_nodes(doc)
}

/// Every node that is nobody's child.
/// Vertices of `positions` and `normals`, pairwise.
fn vertices_of(positions: &[Vec3], normals: &[Vec3]) -> Vec<Vertex> {
    positions
        .iter()
        .zip(normals)
        .map(|(p, n)| Vertex {
            position: p.to_array(),
            normal: n.to_array(),
        })
        .collect()
}

/// Every node's parent and rest transform, and the nodes reachable from a parentless node in
/// an order that puts each after its parent (a node under several parents keeps the first;
/// nodes only a cycle reaches are left out of the order).
fn rest_nodes(doc: &Document) -> (Vec<super::animation::RestNode>, Vec<usize>) {
    let mut nodes: Vec<super::animation::RestNode> = doc
        .nodes()
        .map(|n| super::animation::RestNode {
            parent: None,
            rest: super::gltf_ext::rest_trs(&n),
        })
        .collect();
    let mut seen = vec![false; nodes.len()];
    let mut order = Vec::new();
    let mut stack: Vec<(Node<'_>, Option<usize>)> = parentless_nodes(doc)
        .into_iter()
        .rev()
        .map(|n| (n, None))
        .collect();
    while let Some((node, parent)) = stack.pop() {
        let i = node.index();
        if seen.get(i) != Some(&false) {
            continue;
        }
        seen[i] = true;
        nodes[i].parent = parent;
        order.push(i);
        let children: Vec<_> = node.children().collect();
        for c in children.into_iter().rev() {
            stack.push((c, Some(i)));
        }
    }
    (nodes, order)
}

pub(super) fn parentless_nodes(doc: &Document) -> Vec<Node<'_>> {
    let mut is_child = vec![false; doc.nodes().len()];
    for node in doc.nodes() {
        for child in node.children() {
            if let Some(flag) = is_child.get_mut(child.index()) {
                *flag = true;
            }
        }
    }
    doc.nodes()
        .filter(|n| !is_child.get(n.index()).copied().unwrap_or(false))
        .collect()
}

/// The index of the animation `choice` names (`None` for none; the first of a file without
/// animations is none), or an error listing the file's animations.
fn chosen_animation(doc: &Document, choice: &AnimationChoice) -> Result<Option<usize>, String> {
    let count = doc.animations().len();
    let found = match choice {
        AnimationChoice::First => return Ok((count > 0).then_some(0)),
        AnimationChoice::Nothing => return Ok(None),
        AnimationChoice::Index(i) => (*i < count).then_some(*i),
        AnimationChoice::Name(name) => doc
            .animations()
            .position(|a| a.name() == Some(name.as_str())),
    };
    found.map(Some).ok_or_else(|| {
        let what = match choice {
            AnimationChoice::Name(name) => format!("no animation named \"{name}\""),
            AnimationChoice::Index(i) => format!("no animation {i}"),
            _ => "no such animation".to_string(),
        };
        match count {
            0 => format!("{what}: the file has no animation"),
            _ => format!(
                "{what}: the file's animations are {}",
                animation_list(doc, None)
            ),
        }
    })
}

/// The file's animations but `except` as `--animation` takes them: "0 \"Survey\", 1
/// \"Walk\", ..." (the first 12).
fn animation_list(doc: &Document, except: Option<usize>) -> String {
    let mut list: Vec<String> = doc
        .animations()
        .filter(|a| Some(a.index()) != except)
        .take(12)
        .map(|a| animation_label(&a))
        .collect();
    if doc.animations().len() > 12 + usize::from(except.is_some()) {
        list.push("...".to_string());
    }
    list.join(", ")
}

/// An animation as `--animation` takes it: `1 "Walk"`, or the index alone without a name.
fn animation_label(a: &::gltf::Animation<'_>) -> String {
    match a.name() {
        Some(name) => format!("{} \"{}\"", a.index(), name.escape_debug()),
        None => a.index().to_string(),
    }
}

/// The translation, rotation, scale and morph-weights channels of animation `index` (those
/// that cannot be read are left out with a warning); an animation that moves nothing without
/// one.
fn read_animation(
    doc: &Document,
    index: Option<usize>,
    buffers: &[Data],
    warnings: &mut Vec<String>,
) -> super::animation::Animation {
    let (mut channels, mut weights) = (Vec::new(), Vec::new());
    let anim = index.and_then(|i| doc.animations().nth(i));
    if let Some(anim) = &anim {
        for ch in anim.channels() {
            let read = match super::gltf_ext::Channel::read(doc, &ch, buffers) {
                Ok(Some(c)) => {
                    channels.push(c);
                    Ok(())
                }
                Ok(None) => super::gltf_ext::WeightsChannel::read(doc, &ch, buffers)
                    .map(|w| weights.extend(w)),
                Err(e) => Err(e),
            };
            if let Err(e) = read {
                warnings.push(format!(
                    "animation {} channel {}: {e}, left out",
                    anim.index(),
                    ch.index()
                ))
            }
        }
    }
    let mut animation = super::animation::Animation::new(channels, weights);
    if let Some(anim) = &anim {
        animation.set_label(animation_label(anim));
    }
    animation
}

/// A camera orbit around `bounds`: four keys at 1.5x the bounding radius, looking at the
/// center; around a small model (a radius under 0.4) at least two near planes off its
/// bounding sphere, so that the near plane never cuts it.
fn default_path(bounds: &Aabb) -> CameraPath {
    let center = bounds.center();
    let radius = (bounds.extent().length() * 0.5).max(1e-3);
    let distance = (1.5 * radius).max(radius + 2.0 * super::camera::NEAR_PLANE);
    let keys = (0..4)
        .map(|k| {
            let a = std::f32::consts::FRAC_PI_4 + k as f32 * std::f32::consts::FRAC_PI_2;
            let dir = Vec3::new(a.cos(), 0.35, a.sin()).normalize();
            CameraPose {
                eye: center + dir * distance,
                target: center,
            }
        })
        .collect();
    CameraPath {
        name: "default".to_string(),
        keys,
    }
}

/// The box of `objects` and of the objects `animation` moves (at its start).
fn all_bounds(objects: &[Object], animation: Option<&super::animation::Animation>) -> Aabb {
    let moved = animation.into_iter().flat_map(|a| {
        (a.objects.iter().map(|a| &a.object)).chain(a.deformed.iter().map(|a| &a.object))
    });
    (objects.iter().chain(moved)).fold(Aabb::EMPTY, |b, o| b.union(&o.bounds))
}

/// Makes the "default" orbit of a loaded glTF scene again for its objects' current size (after
/// [`Scene::magnify`], which scales the orbit with the model, and with it its distance from
/// the near plane), around `around` when given (the scene less its
/// [backdrop](super::backdrop)), else around every object.
pub(super) fn refit_default_path(scene: &mut Scene, around: Option<Aabb>) {
    let bounds = around.unwrap_or_else(|| all_bounds(&scene.objects, scene.animation.as_deref()));
    if let Some(p) = scene.paths.iter_mut().find(|p| p.name == "default") {
        *p = default_path(&bounds);
    }
}

impl Loader<'_> {
    /// Depth-first walk from `root`, composing transforms and instancing meshes.
    fn walk(&mut self, doc: &Document, root: Node<'_>) -> Result<(), String> {
        let node_count = doc.nodes().len();
        let mut visits = 0usize;
        // Per node: its parent's world transform, its depth, and when it hangs from an animated
        // node, the world transform above the topmost such node and the nodes from it down.
        type Animated = Option<(Mat4, Vec<(usize, super::gltf_ext::Trs)>)>;
        let mut stack: Vec<(Node<'_>, Mat4, usize, Animated)> =
            vec![(root, Mat4::IDENTITY, 0usize, None)];
        while let Some((node, parent, depth, animated)) = stack.pop() {
            visits += 1;
            if depth > node_count {
                return Err(format!(
                    "node {} is part of a cycle in the node hierarchy",
                    node.index()
                ));
            }
            if visits > MAX_NODE_VISITS {
                return Err("node hierarchy expands to too many instances".to_string());
            }
            let local = Mat4::from_cols_array_2d(&node.transform().matrix());
            let world = parent * local;
            if !world.is_finite() {
                return Err(format!("node {} has a non-finite transform", node.index()));
            }
            let animated = match animated {
                Some((above, mut chain)) => {
                    chain.push((node.index(), super::gltf_ext::rest_trs(&node)));
                    Some((above, chain))
                }
                None if self.animation.animates(node.index()) => Some((
                    parent,
                    vec![(node.index(), super::gltf_ext::rest_trs(&node))],
                )),
                None => None,
            };
            if let Some(mesh) = node.mesh() {
                let instances = match self.node_instances.get(&node.index()) {
                    Some(known) => known.clone(),
                    None => {
                        let read = self.instances(doc, &node)?;
                        self.node_instances.insert(node.index(), read.clone());
                        read
                    }
                };
                visits += instances.as_ref().map_or(0, Vec::len);
                if visits > MAX_NODE_VISITS {
                    return Err("node hierarchy expands to too many instances".to_string());
                }
                let pose = Pose {
                    weights: super::gltf_skin::morph_weights(&node),
                    skin: match node.skin() {
                        Some(skin) => Some(super::gltf_skin::SkinPose {
                            joints: self.joint_matrices(&skin)?,
                            fallback: world,
                        }),
                        None => None,
                    },
                    deform: self.deform(&node, &mesh)?,
                };
                let geoms = self.mesh_geometry(&mesh, &node, &pose)?;
                // glTF: the transform of a node that holds a skinned mesh is ignored; its
                // vertices are in world space after skinning.
                let placed = if pose.skin.is_some() {
                    Mat4::IDENTITY
                } else {
                    world
                };
                for instance in instances.unwrap_or_else(|| vec![Mat4::IDENTITY]) {
                    let world = placed * instance;
                    if !world.is_finite() {
                        return Err(format!(
                            "node {}: an instance has a non-finite transform",
                            node.index()
                        ));
                    }
                    // glTF: a node whose transform mirrors (negative determinant) turns its
                    // triangles' winding over, so that their fronts still face out. The
                    // renderer and the ray scene take counter-clockwise in world space as the
                    // front: such a node draws a copy of the indices with the winding turned
                    // over.
                    let mirrors = world.determinant() < 0.0;
                    for geom in &geoms {
                        let mut geom = *geom;
                        if mirrors {
                            geom.first_index = self.mirrored_indices(&geom)?;
                        }
                        let bounds = self.world_bounds(&geom, &world);
                        let reach = bounds.min.abs().max(bounds.max.abs()).max_element();
                        if reach.is_nan() || reach > MAX_COORDINATE {
                            return Err(format!(
                                "node {}, mesh {}: its vertices reach {reach:.3e} units from \
                                 the origin (at most {MAX_COORDINATE:e}: is the file damaged?)",
                                node.index(),
                                mesh.index()
                            ));
                        }
                        let object = Object {
                            first_index: geom.first_index,
                            index_count: geom.index_count,
                            vertex_offset: geom.vertex_offset,
                            vertex_count: geom.vertex_count,
                            transform: world,
                            color: geom.color,
                            bounds,
                            material: geom.material,
                        };
                        // Skinned vertices are in world space: they move only when the
                        // animation moves their joints (and then each frame is skinned anew).
                        // An unskinned morphed mesh keeps its node's (animated) transform.
                        match (&animated, &pose.skin, geom.deformed) {
                            (_, Some(_), Some(mesh)) | (None, None, Some(mesh)) => {
                                self.animation.add_deformed(object, mesh, None)
                            }
                            (Some((above, chain)), None, Some(mesh)) => {
                                self.animation.add_deformed(
                                    object,
                                    mesh,
                                    Some((*above, chain.clone(), instance, geom.bounds)),
                                )
                            }
                            (Some((above, chain)), None, None) => self.animation.add(
                                object,
                                geom.bounds,
                                *above,
                                chain.clone(),
                                instance,
                            ),
                            _ => self.objects.push(object),
                        }
                    }
                }
            }
            let children: Vec<_> = node.children().collect();
            for child in children.into_iter().rev() {
                stack.push((child, world, depth + 1, animated.clone()));
            }
        }
        Ok(())
    }

    /// The instance transforms of a node with `EXT_mesh_gpu_instancing` (`None` without it):
    /// per instance TRANSLATION x ROTATION x SCALE from its accessors, each absent one the
    /// identity. Every instance becomes an object of its own, so the culler tests each.
    fn instances(&self, doc: &Document, node: &Node<'_>) -> Result<Option<Vec<Mat4>>, String> {
        let Some(ext) = node.extension_value(INSTANCING) else {
            return Ok(None);
        };
        let label = format!("node {} {INSTANCING}", node.index());
        let attributes = ext
            .get("attributes")
            .and_then(serde_json::Value::as_object)
            .ok_or_else(|| format!("{label}: no attributes"))?;
        let read = |name: &str, dims: Dimensions| -> Result<Option<Vec<[f32; 4]>>, String> {
            let Some(index) = attributes.get(name) else {
                return Ok(None);
            };
            let acc = index
                .as_u64()
                .and_then(|i| doc.accessors().nth(usize::try_from(i).ok()?))
                .ok_or_else(|| format!("{label}: {name} names no accessor"))?;
            if acc.dimensions() != dims {
                return Err(format!(
                    "{label}: {name} accessor {} is {:?}, not {dims:?}",
                    acc.index(),
                    acc.dimensions()
                ));
            }
            let elems = super::gltf_material::read_elements(&acc, self.buffers)
                .map_err(|e| format!("{label}: {name} accessor {}: {e}", acc.index()))?;
            if let Some(i) = elems.iter().position(|e| !e.iter().all(|c| c.is_finite())) {
                return Err(format!("{label}: {name} of instance {i} is not finite"));
            }
            Ok(Some(elems))
        };
        let t = read("TRANSLATION", Dimensions::Vec3)?;
        let r = read("ROTATION", Dimensions::Vec4)?;
        let s = read("SCALE", Dimensions::Vec3)?;
        let counts: Vec<usize> = [&t, &r, &s]
            .iter()
            .filter_map(|a| a.as_ref().map(Vec::len))
            .collect();
        let Some(&count) = counts.first() else {
            return Err(format!("{label}: none of TRANSLATION, ROTATION and SCALE"));
        };
        if counts.iter().any(|&c| c != count) {
            return Err(format!("{label}: its accessors count {counts:?} instances"));
        }
        Ok(Some(
            (0..count)
                .map(|i| {
                    let t = t
                        .as_ref()
                        .map_or(Vec3::ZERO, |t| Vec3::from_slice(&t[i][..3]));
                    let r = r.as_ref().map_or(glam::Quat::IDENTITY, |r| {
                        Vec4::from_array(r[i])
                            .try_normalize()
                            .map_or(glam::Quat::IDENTITY, glam::Quat::from_vec4)
                    });
                    let s = s
                        .as_ref()
                        .map_or(Vec3::ONE, |s| Vec3::from_slice(&s[i][..3]));
                    Mat4::from_scale_rotation_translation(s, r, t)
                })
                .collect(),
        ))
    }

    /// The first index of a copy of `geom`'s indices with each triangle's winding turned
    /// over, appended to the shared indices on first use.
    fn mirrored_indices(&mut self, geom: &PrimGeom) -> Result<u32, String> {
        if let Some(&first) = self.mirrored.get(&geom.first_index) {
            return Ok(first);
        }
        let start = geom.first_index as usize;
        let range = start..start + geom.index_count as usize;
        let first = u32::try_from(self.indices.len())
            .ok()
            .filter(|&f| f.checked_add(geom.index_count).is_some())
            .ok_or_else(|| "scene exceeds 2^32 vertices or indices".to_string())?;
        let turned: Vec<u32> = self.indices[range]
            .chunks_exact(3)
            .flat_map(|t| [t[0], t[2], t[1]])
            .collect();
        self.indices.extend_from_slice(&turned);
        self.mirrored.insert(geom.first_index, first);
        Ok(first)
    }

    /// The world bounds of `geom`'s triangles under `world`: its local box transformed when
    /// `world` only scales and translates (exact then), else the box of its transformed
    /// vertices (a rotated box's bounds can be far larger than what it holds: a floor turned
    /// about a slanted axis would get a box as tall as it is wide).
    fn world_bounds(&self, geom: &PrimGeom, world: &Mat4) -> Aabb {
        let axis_aligned = [world.x_axis, world.y_axis, world.z_axis]
            .iter()
            .enumerate()
            .all(|(i, col)| (0..3).all(|j| j == i || col[j] == 0.0));
        if axis_aligned {
            return geom.bounds.transformed(world);
        }
        let start = geom.first_index as usize;
        let base = geom.vertex_offset as usize;
        let mut bounds = Aabb::EMPTY;
        for &i in &self.indices[start..start + geom.index_count as usize] {
            let p = Vec3::from_array(self.vertices[base + i as usize].position);
            bounds.grow(world.transform_point3(p));
        }
        bounds
    }

    /// How the animation deforms `node`'s `mesh`: when it moves a joint of the node's skin
    /// or the node itself (which the skin's vertices without weight follow), or animates the
    /// node's morph weights and the mesh has morph targets. `None` when it leaves the mesh's
    /// shape still.
    fn deform(
        &mut self,
        node: &Node<'_>,
        mesh: &::gltf::Mesh<'_>,
    ) -> Result<Option<Deform>, String> {
        let morph = self.animation.weights_of(node.index()).is_some()
            && mesh.primitives().any(|p| p.morph_targets().len() > 0);
        let skin = node.skin();
        let skin_moves = skin.as_ref().is_some_and(|skin| {
            let joints: Vec<usize> = skin.joints().map(|j| j.index()).collect();
            self.animation.moves_any(&joints) || self.animation.moves_any(&[node.index()])
        });
        if !morph && !skin_moves {
            return Ok(None);
        }
        let rig = match skin {
            Some(skin) => Some(self.rig(&skin)?),
            None => None,
        };
        Ok(Some(Deform {
            node: node.index(),
            rig,
            morph,
        }))
    }

    /// The animation's rig for `skin`, made once.
    fn rig(&mut self, skin: &::gltf::Skin<'_>) -> Result<usize, String> {
        if let Some(&r) = self.rigs.get(&skin.index()) {
            return Ok(r);
        }
        let joints: Vec<usize> = skin.joints().map(|j| j.index()).collect();
        let inverse_bind = super::gltf_skin::inverse_bind_matrices(skin, self.buffers)?;
        let r = self.animation.add_rig(super::animation::Rig {
            joints,
            inverse_bind,
        });
        self.rigs.insert(skin.index(), r);
        Ok(r)
    }

    /// The joint matrices of `skin`, computed on first use.
    fn joint_matrices(&mut self, skin: &::gltf::Skin<'_>) -> Result<Vec<Mat4>, String> {
        if let Some(m) = self.skins.get(&skin.index()) {
            return Ok(m.clone());
        }
        let m = super::gltf_skin::joint_matrices(skin, &self.world, self.buffers)?;
        self.skins.insert(skin.index(), m.clone());
        Ok(m)
    }

    /// The triangle primitives of `mesh` in `pose` (at `node`), loading them into the shared
    /// buffers on first use.
    fn mesh_geometry(
        &mut self,
        mesh: &::gltf::Mesh<'_>,
        node: &Node<'_>,
        pose: &Pose,
    ) -> Result<Vec<PrimGeom>, String> {
        let key = MeshKey {
            mesh: mesh.index(),
            own_node: (pose.skin.is_some() || pose.deform.is_some()).then_some(node.index()),
            weights: pose.weights.iter().map(|w| w.to_bits()).collect(),
        };
        if let Some(geoms) = self.meshes.get(&key) {
            return Ok(geoms.clone());
        }
        let label = match mesh.name() {
            Some(name) => format!("mesh {} '{name}'", mesh.index()),
            None => format!("mesh {}", mesh.index()),
        };
        let mut geoms = Vec::new();
        for prim in mesh.primitives() {
            let label = format!("{label} primitive {}", prim.index());
            if let Some(geom) = self.load_primitive(&prim, &label, pose)? {
                geoms.push(geom);
            }
        }
        self.meshes.insert(key, geoms.clone());
        Ok(geoms)
    }

    /// Loads one primitive; `Ok(None)` when it is skipped (with a warning).
    fn load_primitive(
        &mut self,
        prim: &::gltf::Primitive<'_>,
        label: &str,
        pose: &Pose,
    ) -> Result<Option<PrimGeom>, String> {
        let mode = prim.mode();
        if !matches!(
            mode,
            Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
        ) {
            self.warnings
                .push(format!("{label}: mode {mode:?} is not supported, skipped"));
            return Ok(None);
        }
        let draco = super::gltf_draco::decode(prim, self.doc, self.buffers)
            .map_err(|e| format!("{label}: {e}"))?;
        let draco = draco.as_ref();
        let mut positions = self.primitive_positions(prim, label, draco)?;
        // Targets whose weights the animation plays are kept, and applied each frame.
        let targets = match pose.deform {
            Some(d) if d.morph && prim.morph_targets().len() > 0 => {
                super::gltf_skin::morph_targets(prim, self.buffers, positions.len(), label)?
            }
            _ => Vec::new(),
        };
        let morph = if targets.is_empty() {
            super::gltf_skin::morph_deltas(
                prim,
                &pose.weights,
                self.buffers,
                positions.len(),
                label,
            )?
        } else {
            super::gltf_skin::MorphDeltas::default()
        };
        for (p, d) in positions.iter_mut().zip(morph.positions.iter().flatten()) {
            *p += *d;
            if !p.is_finite() {
                return Err(format!("{label}: a morphed position is not finite"));
            }
        }
        let mut indices = match draco {
            // A Draco stream's faces are triangles whatever the mode says.
            Some(d) => d.indices.clone(),
            None => self.primitive_indices(prim, label, positions.len(), mode)?,
        };
        if indices.is_empty() {
            self.warnings
                .push(format!("{label}: no triangles, skipped"));
            return Ok(None);
        }
        let mut normals = self.primitive_normals(
            prim,
            label,
            &positions,
            &indices,
            draco,
            morph.normals.as_deref(),
        )?;
        let deform = pose
            .deform
            .filter(|d| d.rig.is_some() || !targets.is_empty());
        let rest: Vec<Vertex> = match deform {
            Some(_) => vertices_of(&positions, &normals),
            None => Vec::new(),
        };
        let mut influences = None;
        if let Some(skin) = &pose.skin {
            let triangles = super::gltf_skin::Triangles {
                positions: &mut positions,
                normals: &mut normals,
                indices: &mut indices,
            };
            let (valid, read) =
                super::gltf_skin::skin_vertices(prim, skin, self.buffers, draco, triangles, label)?;
            influences = Some(read);
            if valid.contains(&false) {
                let computed = computed_normals(&positions, &indices);
                for ((n, c), ok) in normals.iter_mut().zip(computed).zip(valid) {
                    if !ok {
                        *n = c;
                    }
                }
            }
        }
        let color = base_color(prim);
        let gm = prim.material();
        let (attributes, found) =
            primitive_attributes(prim, self.buffers, positions.len(), label, draco)?;
        self.materials.attributes_used |= found;
        let material = self.materials.material(&gm, self.doc, self.buffers);
        let own = deform.is_some();
        let mut geom =
            self.append_geometry(&positions, &normals, &attributes, &indices, color, own)?;
        geom.material = material;
        if let Some(d) = deform {
            let range =
                geom.vertex_offset as usize..(geom.vertex_offset + geom.vertex_count) as usize;
            let skin = d.rig.zip(influences).map(|(rig, inf)| (inf, rig));
            geom.deformed = Some(self.animation.add_deformed_mesh(
                super::animation::DeformedMesh {
                    first_vertex: geom.vertex_offset,
                    rest,
                    loaded: self.vertices[range].to_vec(),
                    skin,
                    targets,
                    node: d.node,
                },
            ));
        }
        Ok(Some(geom))
    }

    /// The POSITION attribute, all finite.
    fn primitive_positions(
        &self,
        prim: &::gltf::Primitive<'_>,
        label: &str,
        draco: Option<&DracoPrimitive>,
    ) -> Result<Vec<Vec3>, String> {
        let positions = match draco.and_then(|d| d.attribute("POSITION")) {
            Some(values) => values.iter().map(|v| Vec3::new(v[0], v[1], v[2])).collect(),
            None => {
                let pos_acc = prim
                    .get(&Semantic::Positions)
                    .ok_or_else(|| format!("{label}: no POSITION attribute"))?;
                read_vec3(&pos_acc, self.buffers)
                    .map_err(|e| format!("{label}: POSITION accessor {}: {e}", pos_acc.index()))?
            }
        };
        if let Some(d) = draco.filter(|d| d.points != positions.len()) {
            return Err(format!(
                "{label}: its Draco stream has {} points and its POSITION {}",
                d.points,
                positions.len()
            ));
        }
        if let Some(i) = positions.iter().position(|p| !p.is_finite()) {
            return Err(format!("{label}: vertex {i} has a non-finite position"));
        }
        Ok(positions)
    }

    /// The primitive's triangles as a list of indices, checked against the `n` vertices: the
    /// index accessor's values, or `0..n` when there is none, read in `mode`'s topology.
    fn primitive_indices(
        &self,
        prim: &::gltf::Primitive<'_>,
        label: &str,
        n: usize,
        mode: Mode,
    ) -> Result<Vec<u32>, String> {
        let seq = match prim.indices() {
            Some(acc) => {
                let idx = read_indices(&acc, self.buffers)
                    .map_err(|e| format!("{label}: index accessor {}: {e}", acc.index()))?;
                if let Some(&bad) = idx.iter().find(|&&i| i as usize >= n) {
                    return Err(format!(
                        "{label}: index {bad} out of range (vertex count {n})"
                    ));
                }
                if mode == Mode::Triangles && !idx.len().is_multiple_of(3) {
                    return Err(format!(
                        "{label}: index count {} is not a multiple of 3",
                        idx.len()
                    ));
                }
                idx
            }
            None => {
                if mode == Mode::Triangles && !n.is_multiple_of(3) {
                    return Err(format!(
                        "{label}: non-indexed vertex count {n} is not a multiple of 3"
                    ));
                }
                let n32 = u32::try_from(n).map_err(|_| format!("{label}: too many vertices"))?;
                (0..n32).collect()
            }
        };
        Ok(match mode {
            Mode::Triangles => seq,
            _ => strip_or_fan_triangles(&seq, mode == Mode::TriangleFan),
        })
    }

    /// Appends the indices, and the vertices with their attributes unless an equal range is
    /// there already, to the shared buffers, which must stay addressable by `u32`.
    fn append_geometry(
        &mut self,
        positions: &[Vec3],
        normals: &[Vec3],
        attributes: &[VertexAttributes],
        indices: &[u32],
        color: Vec4,
        own: bool,
    ) -> Result<PrimGeom, String> {
        let vertices = vertices_of(positions, normals);
        let n = vertices.len();
        let key = {
            use std::hash::{Hash, Hasher};
            let mut h = std::collections::hash_map::DefaultHasher::new();
            bytemuck::cast_slice::<Vertex, u8>(&vertices).hash(&mut h);
            bytemuck::cast_slice::<VertexAttributes, u8>(attributes).hash(&mut h);
            h.finish()
        };
        let same = |&(offset, count): &(u32, u32)| {
            let range = offset as usize..offset as usize + count as usize;
            count as usize == n
                && bytemuck::cast_slice::<Vertex, u8>(&self.vertices[range.clone()])
                    == bytemuck::cast_slice::<Vertex, u8>(&vertices)
                && self.attributes[range] == *attributes
        };
        let shared = (!own)
            .then(|| self.vertex_ranges.get(&key))
            .flatten()
            .and_then(|ranges| ranges.iter().find(|r| same(r)))
            .map(|&(offset, _)| offset);
        let appended = if shared.is_some() { 0 } else { n };
        let vertex_offset = shared.or_else(|| u32::try_from(self.vertices.len()).ok());
        let first_index = u32::try_from(self.indices.len()).ok();
        let fits = self
            .vertices
            .len()
            .checked_add(appended)
            .is_some_and(|v| v <= u32::MAX as usize)
            && self
                .indices
                .len()
                .checked_add(indices.len())
                .is_some_and(|v| v <= u32::MAX as usize);
        let (Some(vertex_offset), Some(first_index), true) = (vertex_offset, first_index, fits)
        else {
            return Err("scene exceeds 2^32 vertices or indices".to_string());
        };

        // The box of the vertices the triangles use: primitives that share one accessor each
        // get the box of their own part.
        let mut bounds = Aabb::EMPTY;
        for &i in indices {
            bounds.grow(positions[i as usize]);
        }
        if shared.is_none() {
            self.vertices.extend_from_slice(&vertices);
            self.attributes
                .resize(vertex_offset as usize, VertexAttributes::default());
            self.attributes.extend_from_slice(attributes);
            if !own {
                self.vertex_ranges
                    .entry(key)
                    .or_default()
                    .push((vertex_offset, n as u32));
            }
        }
        self.indices.extend_from_slice(indices);
        Ok(PrimGeom {
            first_index,
            index_count: indices.len() as u32,
            vertex_offset,
            vertex_count: n as u32,
            bounds,
            color,
            material: None,
            deformed: None,
        })
    }

    /// The NORMAL attribute (decoded from the primitive's Draco stream, or read from its
    /// accessor) plus the morph targets' displacement `turned`, when usable, else area-weighted
    /// averaged face normals; invalid individual normals are replaced by computed ones.
    fn primitive_normals(
        &mut self,
        prim: &::gltf::Primitive<'_>,
        label: &str,
        positions: &[Vec3],
        indices: &[u32],
        draco: Option<&DracoPrimitive>,
        turned: Option<&[Vec3]>,
    ) -> Result<Vec<Vec3>, String> {
        let mut normals = match draco.and_then(|d| d.attribute("NORMAL")) {
            Some(values) => values.iter().map(|v| Vec3::new(v[0], v[1], v[2])).collect(),
            None => {
                let Some(acc) = prim.get(&Semantic::Normals) else {
                    return Ok(computed_normals(positions, indices));
                };
                if acc.count() != positions.len() || acc.dimensions() != Dimensions::Vec3 {
                    self.warnings.push(format!(
                        "{label}: NORMAL accessor {} has {} {:?} elements for {} vertices, normals recomputed",
                        acc.index(),
                        acc.count(),
                        acc.dimensions(),
                        positions.len()
                    ));
                    return Ok(computed_normals(positions, indices));
                }
                read_vec3(&acc, self.buffers)
                    .map_err(|e| format!("{label}: NORMAL accessor {}: {e}", acc.index()))?
            }
        };
        for (n, d) in normals.iter_mut().zip(turned.into_iter().flatten()) {
            *n += *d;
        }
        let mut computed: Option<Vec<Vec3>> = None;
        for (i, n) in normals.iter_mut().enumerate() {
            match n.try_normalize() {
                Some(unit) => *n = unit,
                None => {
                    let c = computed.get_or_insert_with(|| computed_normals(positions, indices));
                    *n = c[i];
                }
            }
        }
        Ok(normals)
    }
}

/// The triangles of a strip (or with `fan`, a fan) of the vertices `seq`, as a list with glTF's
/// vertex order: triangle `i` of a strip is `(v[i], v[i + 1 + i % 2], v[i + 2 - i % 2])`, of a
/// fan `(v[i + 1], v[i + 2], v[0])`. Triangles with a repeated vertex (those that stitch strips
/// together) are left out; they cover no pixel.
fn strip_or_fan_triangles(seq: &[u32], fan: bool) -> Vec<u32> {
    (0..seq.len().saturating_sub(2))
        .map(|i| {
            if fan {
                [seq[i + 1], seq[i + 2], seq[0]]
            } else {
                [seq[i], seq[i + 1 + i % 2], seq[i + 2 - i % 2]]
            }
        })
        .filter(|[a, b, c]| a != b && b != c && a != c)
        .flatten()
        .collect()
}

/// The material's base color factor, clamped to [0, 1]; white if it is not finite.
fn base_color(prim: &::gltf::Primitive<'_>) -> Vec4 {
    let factor = super::gltf_material::base_color_factor(&prim.material());
    let color = Vec4::from_array(factor);
    if color.is_finite() {
        color.clamp(Vec4::ZERO, Vec4::ONE)
    } else {
        Vec4::ONE
    }
}

/// Area-weighted vertex normals averaged over the triangles using each vertex; unused or
/// degenerate vertices get +Y. `indices` must be in range for `positions`.
fn computed_normals(positions: &[Vec3], indices: &[u32]) -> Vec<Vec3> {
    let mut acc = vec![Vec3::ZERO; positions.len()];
    for tri in indices.chunks_exact(3) {
        let [a, b, c] = [tri[0] as usize, tri[1] as usize, tri[2] as usize];
        let n = (positions[b] - positions[a]).cross(positions[c] - positions[a]);
        if n.is_finite() {
            acc[a] += n;
            acc[b] += n;
            acc[c] += n;
        }
    }
    acc.into_iter()
        .map(|n| n.try_normalize().unwrap_or(Vec3::Y))
        .collect()
}

/// Most bytes an accessor without a buffer view, or a sparse one, may expand to (its elements
/// are written out densely; those of other accessors are read where they lie).
const MAX_DENSE_ACCESSOR_BYTES: usize = 1 << 28;

/// The bytes of a buffer view, after checking that it lies inside its buffer.
pub(super) fn view_bytes<'b>(
    view: &::gltf::buffer::View<'_>,
    buffers: &'b [Data],
) -> Result<&'b [u8], String> {
    let buffer = view.buffer();
    let data = buffers
        .get(buffer.index())
        .ok_or("refers to a missing buffer")?;
    let data_len = data.len().min(buffer.length());
    let end = view
        .offset()
        .checked_add(view.length())
        .filter(|&end| end <= data_len)
        .ok_or_else(|| {
            format!(
                "buffer view {} (offset {}, length {}) exceeds buffer {} ({data_len} bytes)",
                view.index(),
                view.offset(),
                view.length(),
                buffer.index()
            )
        })?;
    Ok(&data[view.offset()..end])
}

/// The `count` elements of `elem` bytes, `stride` apart from `offset` in `view`'s bytes, after
/// checking that they lie inside it.
fn view_elements<'b>(
    view: &::gltf::buffer::View<'_>,
    buffers: &'b [Data],
    offset: usize,
    count: usize,
    elem: usize,
    stride: usize,
) -> Result<&'b [u8], String> {
    let bytes = view_bytes(view, buffers)?;
    let needed = if count == 0 {
        Some(offset)
    } else {
        (count - 1)
            .checked_mul(stride)
            .and_then(|v| v.checked_add(elem))
            .and_then(|v| v.checked_add(offset))
    };
    match needed {
        Some(end) if end <= bytes.len() => Ok(&bytes[offset..end]),
        _ => Err(format!(
            "{count} elements at offset {offset} read past the end of buffer view {} ({} bytes)",
            view.index(),
            bytes.len()
        )),
    }
}

/// The bytes an accessor reads and its element stride, after checking that every element lies
/// inside its buffer view and the view inside its buffer. An accessor without a view reads
/// zeros; a sparse one its base values (or zeros) with the sparse values written over them
/// (both are returned densely packed).
fn accessor_bytes<'b>(
    acc: &Accessor<'_>,
    buffers: &'b [Data],
) -> Result<(Cow<'b, [u8]>, usize), String> {
    let elem = acc.size();
    let count = acc.count();
    let base = match acc.view() {
        Some(view) => {
            let stride = view.stride().unwrap_or(elem);
            if stride < elem {
                return Err(format!(
                    "byte stride {stride} is smaller than the element size {elem}"
                ));
            }
            Some((
                view_elements(&view, buffers, acc.offset(), count, elem, stride)?,
                stride,
            ))
        }
        None => None,
    };
    let sparse = acc.sparse();
    if let (Some((bytes, stride)), None) = (base, &sparse) {
        return Ok((Cow::Borrowed(bytes), stride));
    }
    let len = count
        .checked_mul(elem)
        .filter(|&l| l <= MAX_DENSE_ACCESSOR_BYTES)
        .ok_or_else(|| {
            format!(
                "{count} elements without a buffer view or sparse are more than {} MiB",
                MAX_DENSE_ACCESSOR_BYTES >> 20
            )
        })?;
    let mut dense = match base {
        Some((bytes, stride)) => {
            let mut dense = Vec::with_capacity(len);
            for i in 0..count {
                dense.extend_from_slice(&bytes[i * stride..i * stride + elem]);
            }
            dense
        }
        None => vec![0; len],
    };
    if let Some(sparse) = sparse {
        let n = sparse.count();
        if n == 0 {
            return Err("sparse count is 0".to_string());
        }
        let (indices, values) = (sparse.indices(), sparse.values());
        let isize = indices.index_type().size();
        let at = |what: &str, e: String| format!("sparse {what}: {e}");
        let index_bytes =
            view_elements(&indices.view(), buffers, indices.offset(), n, isize, isize)
                .map_err(|e| at("indices", e))?;
        let value_bytes = view_elements(&values.view(), buffers, values.offset(), n, elem, elem)
            .map_err(|e| at("values", e))?;
        let mut previous = None;
        for (k, b) in index_bytes.chunks_exact(isize).enumerate() {
            let i = unsigned_le(b, isize) as usize;
            if i >= count {
                return Err(format!(
                    "sparse index {i} out of range (element count {count})"
                ));
            }
            if previous.is_some_and(|p| p >= i) {
                return Err(format!("sparse indices do not increase (index {k} is {i})"));
            }
            previous = Some(i);
            dense[i * elem..(i + 1) * elem].copy_from_slice(&value_bytes[k * elem..(k + 1) * elem]);
        }
    }
    Ok((Cow::Owned(dense), elem))
}

/// Checks that an accessor's elements lie inside its view and buffer (for readers elsewhere)
/// and returns them with their stride.
pub(super) fn check_accessor<'b>(
    acc: &Accessor<'_>,
    buffers: &'b [Data],
) -> Result<(Cow<'b, [u8]>, usize), String> {
    accessor_bytes(acc, buffers)
}

/// Reads a VEC3 accessor (float or, normalized or not, integer components) as `Vec3`s.
pub(super) fn read_vec3(acc: &Accessor<'_>, buffers: &[Data]) -> Result<Vec<Vec3>, String> {
    if acc.dimensions() != Dimensions::Vec3 {
        return Err(format!(
            "expected VEC3 elements, found {:?}",
            acc.dimensions()
        ));
    }
    Ok(super::gltf_material::read_elements(acc, buffers)?
        .into_iter()
        .map(|e| Vec3::new(e[0], e[1], e[2]))
        .collect())
}

/// Reads a SCALAR unsigned-integer index accessor.
fn read_indices(acc: &Accessor<'_>, buffers: &[Data]) -> Result<Vec<u32>, String> {
    if acc.dimensions() != Dimensions::Scalar {
        return Err(format!(
            "expected SCALAR indices, found {:?}",
            acc.dimensions()
        ));
    }
    let ty = acc.data_type();
    if !matches!(ty, DataType::U8 | DataType::U16 | DataType::U32) {
        return Err(format!(
            "index component type {ty:?} is not an unsigned integer"
        ));
    }
    let (bytes, stride) = accessor_bytes(acc, buffers)?;
    Ok((0..acc.count())
        .map(|i| unsigned_le(&bytes[i * stride..], ty.size()))
        .collect())
}

/// The little-endian unsigned integer in the first `size` (1, 2 or 4) bytes of `b`: an index
/// of an index accessor or of a sparse accessor's indices.
fn unsigned_le(b: &[u8], size: usize) -> u32 {
    match size {
        1 => u32::from(b[0]),
        2 => u32::from(u16::from_le_bytes([b[0], b[1]])),
        _ => u32::from_le_bytes([b[0], b[1], b[2], b[3]]),
    }
}

/// Writers of small glTF files for tests (this crate's and the main crate's integration tests).
#[doc(hidden)]
pub mod testdata {
    /// Assembles a glTF document: one binary buffer, tightly packed buffer views (one per
    /// accessor) and hand-written JSON for meshes, nodes and materials.
    #[derive(Default)]
    pub struct GltfBuilder {
        /// The binary buffer contents.
        pub bin: Vec<u8>,
        /// JSON objects of the buffer views.
        pub views: Vec<String>,
        /// JSON objects of the accessors.
        pub accessors: Vec<String>,
        /// JSON objects of the meshes.
        pub meshes: Vec<String>,
        /// JSON objects of the materials.
        pub materials: Vec<String>,
        /// JSON objects of the nodes.
        pub nodes: Vec<String>,
        /// Root nodes of the single scene; `None` writes no `scenes` at all.
        pub scene_nodes: Option<Vec<usize>>,
        /// Overrides the declared buffer byteLength (to fake short buffers).
        pub buffer_length_override: Option<usize>,
        /// Top-level JSON members written first, each followed by a comma (for example
        /// `"extensionsUsed":["X"],`).
        pub head: String,
    }

    impl GltfBuilder {
        /// Appends `bytes` as a new buffer view (4-byte aligned) and returns its index.
        pub fn view(&mut self, bytes: &[u8]) -> usize {
            while !self.bin.len().is_multiple_of(4) {
                self.bin.push(0);
            }
            self.views.push(format!(
                r#"{{"buffer":0,"byteOffset":{},"byteLength":{}}}"#,
                self.bin.len(),
                bytes.len()
            ));
            self.bin.extend_from_slice(bytes);
            self.views.len() - 1
        }

        /// Adds a VEC3 float accessor over `data` and returns its index.
        pub fn vec3(&mut self, data: &[[f32; 3]]) -> usize {
            let bytes: Vec<u8> = data
                .iter()
                .flatten()
                .flat_map(|f| f.to_le_bytes())
                .collect();
            let view = self.view(&bytes);
            self.accessor(view, 5126, "VEC3", data.len())
        }

        /// Adds a SCALAR float accessor over `times` (increasing, from 0: an animation
        /// sampler's input, which must give its min and max) and returns its index.
        pub fn key_times(&mut self, times: &[f32]) -> usize {
            let bytes: Vec<u8> = times.iter().flat_map(|t| t.to_le_bytes()).collect();
            let view = self.view(&bytes);
            let i = self.accessor(view, 5126, "SCALAR", times.len());
            let max = times.iter().copied().fold(0.0, f32::max);
            self.accessors[i] =
                self.accessors[i].replace('}', &format!(r#","min":[0],"max":[{max}]}}"#));
            i
        }

        /// Adds a SCALAR u32 index accessor over `data` and returns its index.
        pub fn indices_u32(&mut self, data: &[u32]) -> usize {
            let bytes: Vec<u8> = data.iter().flat_map(|i| i.to_le_bytes()).collect();
            let view = self.view(&bytes);
            self.accessor(view, 5125, "SCALAR", data.len())
        }

        /// Adds a SCALAR u16 index accessor over `data` and returns its index.
        pub fn indices_u16(&mut self, data: &[u16]) -> usize {
            let bytes: Vec<u8> = data.iter().flat_map(|i| i.to_le_bytes()).collect();
            let view = self.view(&bytes);
            self.accessor(view, 5123, "SCALAR", data.len())
        }

        /// Adds an accessor with the given view, component type, type name and count.
        pub fn accessor(
            &mut self,
            view: usize,
            component_type: u32,
            ty: &str,
            count: usize,
        ) -> usize {
            self.accessors.push(format!(
                r#"{{"bufferView":{view},"componentType":{component_type},"type":"{ty}","count":{count}}}"#
            ));
            self.accessors.len() - 1
        }

        /// Adds the unit cube (24 vertices with face normals, 36 u16 indices) as a mesh with
        /// the given color and returns the mesh index.
        pub fn cube_mesh(&mut self, color: [f32; 4]) -> usize {
            let (positions, normals, indices) = cube();
            let pos = self.vec3(&positions);
            let nrm = self.vec3(&normals);
            let idx = self.indices_u16(&indices);
            self.materials.push(format!(
                r#"{{"pbrMetallicRoughness":{{"baseColorFactor":[{},{},{},{}]}}}}"#,
                color[0], color[1], color[2], color[3]
            ));
            let material = self.materials.len() - 1;
            self.meshes.push(format!(
                r#"{{"name":"cube","primitives":[{{"attributes":{{"POSITION":{pos},"NORMAL":{nrm}}},"indices":{idx},"material":{material}}}]}}"#
            ));
            self.meshes.len() - 1
        }

        /// Adds a node instancing `mesh` at `translation` and returns its index.
        pub fn node(&mut self, mesh: usize, translation: [f32; 3]) -> usize {
            self.nodes.push(format!(
                r#"{{"mesh":{mesh},"translation":[{},{},{}]}}"#,
                translation[0], translation[1], translation[2]
            ));
            self.nodes.len() - 1
        }

        /// The JSON document; `uri` is the buffer's URI (`None` for the GLB binary chunk).
        pub fn json(&self, uri: Option<&str>) -> String {
            let uri = uri.map(|u| format!(r#","uri":"{u}""#)).unwrap_or_default();
            let length = self.buffer_length_override.unwrap_or(self.bin.len());
            let scenes = match &self.scene_nodes {
                Some(nodes) => {
                    let list: Vec<String> = nodes.iter().map(|n| n.to_string()).collect();
                    format!(r#""scene":0,"scenes":[{{"nodes":[{}]}}],"#, list.join(","))
                }
                None => String::new(),
            };
            format!(
                r#"{{{}"asset":{{"version":"2.0"}},{scenes}"nodes":[{}],"meshes":[{}],"materials":[{}],"accessors":[{}],"bufferViews":[{}],"buffers":[{{"byteLength":{length}{uri}}}]}}"#,
                self.head,
                self.nodes.join(","),
                self.meshes.join(","),
                self.materials.join(","),
                self.accessors.join(","),
                self.views.join(","),
            )
        }

        /// A `.gltf` document with the buffer embedded as a base64 data URI.
        pub fn gltf_embedded(&self) -> String {
            let uri = format!("data:application/octet-stream;base64,{}", base64(&self.bin));
            self.json(Some(&uri))
        }

        /// The `.glb` bytes: header, JSON chunk and binary chunk.
        pub fn glb(&self) -> Vec<u8> {
            let mut json = self.json(None).into_bytes();
            while !json.len().is_multiple_of(4) {
                json.push(b' ');
            }
            let mut bin = self.bin.clone();
            while !bin.len().is_multiple_of(4) {
                bin.push(0);
            }
            let total = 12 + 8 + json.len() + 8 + bin.len();
            let mut out = Vec::with_capacity(total);
            out.extend_from_slice(b"glTF");
            out.extend_from_slice(&2u32.to_le_bytes());
            out.extend_from_slice(&(total as u32).to_le_bytes());
            out.extend_from_slice(&(json.len() as u32).to_le_bytes());
            out.extend_from_slice(b"JSON");
            out.extend_from_slice(&json);
            out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
            out.extend_from_slice(b"BIN\0");
            out.extend_from_slice(&bin);
            out
        }
    }

    /// Positions, normals and indices of the cube [-0.5, 0.5]^3 (4 vertices per face).
    pub fn cube() -> (Vec<[f32; 3]>, Vec<[f32; 3]>, Vec<u16>) {
        let mut positions = Vec::new();
        let mut normals = Vec::new();
        let mut indices = Vec::new();
        for axis in 0..3 {
            for sign in [-1.0f32, 1.0] {
                let mut n = [0.0; 3];
                n[axis] = sign;
                let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                let base = positions.len() as u16;
                for (a, b) in [(-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)] {
                    let mut p = [0.0; 3];
                    p[axis] = 0.5 * sign;
                    p[u] = a;
                    p[v] = b;
                    positions.push(p);
                    normals.push(n);
                }
                let quad = if sign > 0.0 {
                    [0, 1, 2, 0, 2, 3]
                } else {
                    [0, 2, 1, 0, 3, 2]
                };
                indices.extend(quad.iter().map(|&i| base + i));
            }
        }
        (positions, normals, indices)
    }

    /// Bytes of a valid `.glb` with `n` instances of one unit cube (12 triangles each), one
    /// node per instance translated on a square grid with spacing 2 in the XZ plane.
    pub fn cube_grid_glb(n: usize) -> Vec<u8> {
        let mut b = GltfBuilder::default();
        let mesh = b.cube_mesh([0.8, 0.7, 0.6, 1.0]);
        let side = (1..).find(|s| s * s >= n).unwrap_or(1);
        for i in 0..n {
            b.node(
                mesh,
                [(i % side) as f32 * 2.0, 0.0, (i / side) as f32 * 2.0],
            );
        }
        b.scene_nodes = Some((0..n).collect());
        b.glb()
    }

    /// Three triangles over two joints: the first bound to joint 0, the second to joint 1
    /// (a child of joint 0, with an inverse bind matrix), the third with one vertex shared
    /// half and half and two vertices without weight. `joints` is the JOINTS_0 of the
    /// vertices (four per vertex); the mesh's node (index 2) is translated by 100 in x.
    pub fn skinned_triangles(joints: &[u8; 36]) -> GltfBuilder {
        let mut b = GltfBuilder::default();
        let tri = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let raised = [[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]];
        let pos = b.vec3(&[tri, tri, raised].concat());
        let j = b.view(joints);
        let j = b.accessor(j, 5121, "VEC4", 9);
        let mut weights = Vec::new();
        for w in [[1.0f32, 0.0, 0.0, 0.0]; 6].into_iter().chain([
            [0.5, 0.5, 0.0, 0.0],
            [0.0; 4],
            [0.0; 4],
        ]) {
            weights.extend(w.iter().flat_map(|c| c.to_le_bytes()));
        }
        let w = b.view(&weights);
        let w = b.accessor(w, 5126, "VEC4", 9);
        let matrices: Vec<u8> = [
            glam::Mat4::IDENTITY,
            glam::Mat4::from_translation(glam::Vec3::new(-1.0, 0.0, 0.0)),
        ]
        .iter()
        .flat_map(|m| m.to_cols_array())
        .flat_map(|c| c.to_le_bytes())
        .collect();
        let ibm = b.view(&matrices);
        let ibm = b.accessor(ibm, 5126, "MAT4", 2);
        b.meshes.push(format!(
            r#"{{"primitives":[{{"attributes":{{"POSITION":{pos},"JOINTS_0":{j},"WEIGHTS_0":{w}}}}}]}}"#
        ));
        b.nodes
            .push(r#"{"translation":[10,0,0],"scale":[2,2,2],"children":[1]}"#.to_string());
        b.nodes.push(r#"{"translation":[0,5,0]}"#.to_string());
        b.nodes
            .push(r#"{"mesh":0,"skin":0,"translation":[100,0,0]}"#.to_string());
        b.scene_nodes = Some(vec![0, 2]);
        b.head = format!(r#""skins":[{{"joints":[0,1],"inverseBindMatrices":{ibm}}}],"#);
        b
    }

    /// A wall (node 0: a cube scaled to 6 x 3 x 0.5 at (0, 1.5, 0)) and the accessors of a
    /// red unit column: the JSON of its POSITION and NORMAL attributes, and of its indices
    /// and material, for the primitive its caller writes.
    fn wall_and_column() -> (GltfBuilder, String, String) {
        let mut b = GltfBuilder::default();
        let wall = b.cube_mesh([0.8, 0.8, 0.8, 1.0]);
        b.nodes.push(format!(
            r#"{{"mesh":{wall},"translation":[0,1.5,0],"scale":[6,3,0.5]}}"#
        ));
        let (positions, normals, indices) = cube();
        let pos = b.vec3(&positions);
        let nrm = b.vec3(&normals);
        let idx = b.indices_u16(&indices);
        b.materials
            .push(r#"{"pbrMetallicRoughness":{"baseColorFactor":[0.9,0.2,0.1,1]}}"#.to_string());
        let material = b.materials.len() - 1;
        (
            b,
            format!(r#""POSITION":{pos},"NORMAL":{nrm}"#),
            format!(r#""indices":{idx},"material":{material}"#),
        )
    }

    /// A wall (node 0: a cube scaled to 6 x 3 x 0.5 at (0, 1.5, 0)) and, 3 m behind it, a
    /// red unit column skinned to two joints: its bottom four corners to joint node 1 at (0,
    /// 0.5, -3), its top four to joint node 2, a child of node 1 that the first animation
    /// lifts by `lift` and back over 2 s (node 3 holds the mesh). In the default pose the column hides behind the wall; lifted by 4 its
    /// top shows above it from a camera at (0, 1.5, 8).
    pub fn skinned_column(lift: f32) -> GltfBuilder {
        let (mut b, attributes, rest) = wall_and_column();
        let positions = cube().0;
        let joints: Vec<u8> = positions
            .iter()
            .flat_map(|p| [u8::from(p[1] > 0.0), 0, 0, 0])
            .collect();
        let j = b.view(&joints);
        let j = b.accessor(j, 5121, "VEC4", positions.len());
        let weights: Vec<u8> = positions
            .iter()
            .flat_map(|_| [1.0f32, 0.0, 0.0, 0.0])
            .flat_map(f32::to_le_bytes)
            .collect();
        let w = b.view(&weights);
        let w = b.accessor(w, 5126, "VEC4", positions.len());
        b.meshes.push(format!(
            r#"{{"name":"column","primitives":[{{"attributes":{{{attributes},"JOINTS_0":{j},"WEIGHTS_0":{w}}},{rest}}}]}}"#
        ));
        let column = b.meshes.len() - 1;
        b.nodes
            .push(r#"{"translation":[0,0.5,-3],"children":[2]}"#.to_string());
        b.nodes.push(r#"{"translation":[0,0,0]}"#.to_string());
        b.nodes.push(format!(r#"{{"mesh":{column},"skin":0}}"#));
        b.scene_nodes = Some(vec![0, 1, 3]);
        let times = b.key_times(&[0.0, 1.0, 2.0]);
        let lifted = b.vec3(&[[0.0; 3], [0.0, lift, 0.0], [0.0; 3]]);
        b.head = format!(
            r#""skins":[{{"joints":[1,2]}}],"animations":[{{"samplers":[{{"input":{times},"output":{lifted}}}],"channels":[{{"sampler":0,"target":{{"node":2,"path":"translation"}}}}]}}],"#
        );
        b
    }

    /// The scene of [`skinned_column`] with the column morphed instead of skinned: one morph
    /// target moves its top four corners up by `lift`, and the first animation takes the
    /// target's weight from 0 to 1 and back over 2 s (node 1 holds the column at (0, 0.5, -3)).
    pub fn morphed_column(lift: f32) -> GltfBuilder {
        let (mut b, attributes, rest) = wall_and_column();
        let up: Vec<[f32; 3]> = cube()
            .0
            .iter()
            .map(|p| [0.0, if p[1] > 0.0 { lift } else { 0.0 }, 0.0])
            .collect();
        let up = b.vec3(&up);
        b.meshes.push(format!(
            r#"{{"name":"column","primitives":[{{"attributes":{{{attributes}}},"targets":[{{"POSITION":{up}}}],{rest}}}]}}"#
        ));
        let column = b.meshes.len() - 1;
        b.nodes
            .push(format!(r#"{{"mesh":{column},"translation":[0,0.5,-3]}}"#));
        b.scene_nodes = Some(vec![0, 1]);
        let times = b.key_times(&[0.0, 1.0, 2.0]);
        let w: Vec<u8> = [0.0f32, 1.0, 0.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let w = b.view(&w);
        let weights = b.accessor(w, 5126, "SCALAR", 3);
        b.head = format!(
            r#""animations":[{{"samplers":[{{"input":{times},"output":{weights}}}],"channels":[{{"sampler":0,"target":{{"node":1,"path":"weights"}}}}]}}],"#
        );
        b
    }

    /// Standard base64 with padding.
    pub fn base64(data: &[u8]) -> String {
        const ALPHABET: &[u8; 64] =
            b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
        let mut out = String::with_capacity(data.len().div_ceil(3) * 4);
        for chunk in data.chunks(3) {
            let b = [
                chunk[0],
                *chunk.get(1).unwrap_or(&0),
                *chunk.get(2).unwrap_or(&0),
            ];
            let v = (b[0] as u32) << 16 | (b[1] as u32) << 8 | b[2] as u32;
            for k in 0..4 {
                if k <= chunk.len() {
                    out.push(ALPHABET[(v >> (18 - 6 * k) & 63) as usize] as char);
                } else {
                    out.push('=');
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::testdata::{base64, cube_grid_glb, skinned_triangles, GltfBuilder};
    use super::*;
    use crate::testing::TempDir;
    use std::path::PathBuf;

    /// A fresh per-test directory under the system temp dir, removed when dropped.
    fn temp_dir(test: &str) -> TempDir {
        TempDir::new(&format!("gltf-{test}"))
    }

    fn write(dir: &Path, name: &str, bytes: impl AsRef<[u8]>) -> PathBuf {
        let path = dir.join(name);
        std::fs::write(&path, bytes).expect("write test file");
        path
    }

    /// Two instances of a cube mesh plus one node with a non-indexed single triangle.
    fn two_cubes_and_triangle() -> GltfBuilder {
        let mut b = GltfBuilder::default();
        let cube = b.cube_mesh([1.0, 0.0, 0.0, 1.0]);
        let pos = b.vec3(&[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
        b.meshes.push(format!(
            r#"{{"name":"tri","primitives":[{{"attributes":{{"POSITION":{pos}}}}}]}}"#
        ));
        let tri = b.meshes.len() - 1;
        b.node(cube, [-2.0, 0.0, 0.0]);
        b.node(cube, [2.0, 0.0, 0.0]);
        b.node(tri, [0.0, 5.0, 0.0]);
        b.scene_nodes = Some(vec![0, 1, 2]);
        b
    }

    fn triangles(scene: &Scene) -> u64 {
        scene.objects.iter().map(|o| o.triangle_count()).sum()
    }

    /// Every object's indices are in range, its bounds contain the transformed vertices its
    /// triangles use, and its normals have unit length.
    fn check_consistent(scene: &Scene) {
        for o in &scene.objects {
            let idx =
                &scene.indices[o.first_index as usize..(o.first_index + o.index_count) as usize];
            assert!(idx.iter().all(|&i| i < o.vertex_count));
            let verts = &scene.vertices
                [o.vertex_offset as usize..(o.vertex_offset + o.vertex_count) as usize];
            for v in verts {
                assert!((Vec3::from_array(v.normal).length() - 1.0).abs() < 1e-4);
            }
            for &i in idx {
                let v = verts[i as usize];
                let p = o.transform.transform_point3(Vec3::from_array(v.position));
                assert!(
                    o.bounds.enlarged(1e-4).contains(p),
                    "{p} outside {:?}",
                    o.bounds
                );
            }
        }
    }

    fn assert_scene_err(path: &Path, needle: &str) {
        let msg = match load_gltf(path) {
            Ok(_) => panic!("{} loaded but should fail", path.display()),
            Err(e) => e.to_string(),
        };
        let file = path
            .file_name()
            .and_then(|f| f.to_str())
            .unwrap_or_default();
        assert!(msg.contains(file), "message {msg:?} lacks the file name");
        assert!(msg.contains(needle), "message {msg:?} lacks {needle:?}");
        assert!(!msg.contains('\n'), "message {msg:?} is not one line");
        eprintln!("{msg}");
    }

    #[test]
    fn loads_gltf_with_external_bin() {
        let dir = temp_dir("external");
        let b = two_cubes_and_triangle();
        write(&dir, "scene.bin", &b.bin);
        let path = write(&dir, "scene.gltf", b.json(Some("scene.bin")));
        let (scene, warnings) = load_gltf(&path).expect("load");
        assert!(warnings.is_empty(), "{warnings:?}");
        assert_eq!(scene.name, "scene");
        assert_eq!(scene.objects.len(), 3);
        assert_eq!(triangles(&scene), 12 + 12 + 1);
        // The two cube instances share geometry but not transforms.
        let (a, c) = (&scene.objects[0], &scene.objects[1]);
        assert_eq!(
            (a.first_index, a.vertex_offset),
            (c.first_index, c.vertex_offset)
        );
        assert_eq!(a.bounds.min, Vec3::new(-2.5, -0.5, -0.5));
        assert_eq!(c.bounds.max, Vec3::new(2.5, 0.5, 0.5));
        assert_eq!(a.color, Vec4::new(1.0, 0.0, 0.0, 1.0));
        // No material: white; no normals: computed (+Z for this triangle).
        let t = &scene.objects[2];
        assert_eq!(t.color, Vec4::ONE);
        assert_eq!(
            scene.vertices[t.vertex_offset as usize].normal,
            [0.0, 0.0, 1.0]
        );
        assert_eq!(t.bounds.min, Vec3::new(0.0, 5.0, 0.0));
        check_consistent(&scene);
        assert_eq!(scene.paths.len(), 1);
        assert_eq!(scene.paths[0].name, "default");
        assert_eq!(scene.paths[0].keys.len(), 4);
        let bounds = scene.bounds();
        for k in &scene.paths[0].keys {
            assert!(!bounds.contains(k.eye));
            assert_eq!(k.target, bounds.center());
        }
        assert!((scene.sun_dir.length() - 1.0).abs() < 1e-6);
    }

    #[test]
    fn loads_gltf_with_data_uri_and_glb() {
        let dir = temp_dir("embedded");
        let b = two_cubes_and_triangle();
        let gltf = write(&dir, "embedded.gltf", b.gltf_embedded());
        let glb = write(&dir, "binary.glb", b.glb());
        for path in [gltf, glb] {
            let (scene, _) = load_gltf(&path).expect("load");
            assert_eq!(scene.objects.len(), 3);
            assert_eq!(triangles(&scene), 25);
            check_consistent(&scene);
        }
    }

    /// A cube node placed three times by `EXT_mesh_gpu_instancing` (rotations as normalized
    /// shorts, as gltfpack writes them), the extension required; `scale_count` SCALE elements.
    fn instanced_cubes(scale_count: usize) -> GltfBuilder {
        let mut b = GltfBuilder::default();
        let cube = b.cube_mesh([1.0, 1.0, 1.0, 1.0]);
        let t = b.vec3(&[[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [0.0, 5.0, 0.0]]);
        let h = (std::f32::consts::FRAC_1_SQRT_2 * 32767.0).round() as i16;
        let shorts: Vec<u8> = [[0, 0, 0, 32767], [0, h, 0, h], [0, 0, 0, 32767]]
            .iter()
            .flatten()
            .flat_map(|c: &i16| c.to_le_bytes())
            .collect();
        let view = b.view(&shorts);
        b.accessors.push(format!(
            r#"{{"bufferView":{view},"componentType":5122,"normalized":true,"type":"VEC4","count":3}}"#
        ));
        let r = b.accessors.len() - 1;
        let s = b.vec3(&[[1.0, 1.0, 1.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]][..scale_count]);
        b.nodes.push(format!(
            r#"{{"mesh":{cube},"translation":[0,0,10],"extensions":{{"EXT_mesh_gpu_instancing":{{"attributes":{{"TRANSLATION":{t},"ROTATION":{r},"SCALE":{s}}}}}}}}}"#
        ));
        b.scene_nodes = Some(vec![0]);
        b
    }

    #[test]
    fn gpu_instancing_places_one_object_per_instance() {
        let dir = temp_dir("instancing");
        let required = r#"{"extensionsUsed":["EXT_mesh_gpu_instancing"],"extensionsRequired":["EXT_mesh_gpu_instancing"],"#;
        let json = instanced_cubes(3)
            .gltf_embedded()
            .replacen('{', required, 1);
        let (scene, warnings) = load_gltf(&write(&dir, "instanced.gltf", json)).expect("load");
        assert!(warnings.is_empty(), "{warnings:?}");
        assert_eq!(scene.objects.len(), 3);
        check_consistent(&scene);
        let o = &scene.objects;
        let node = Mat4::from_translation(Vec3::new(0.0, 0.0, 10.0));
        let turn = Mat4::from_rotation_y(std::f32::consts::FRAC_PI_2);
        let want = [
            node,
            node * Mat4::from_translation(Vec3::new(5.0, 0.0, 0.0)) * turn,
            node * Mat4::from_translation(Vec3::new(0.0, 5.0, 0.0))
                * Mat4::from_scale(Vec3::splat(2.0)),
        ];
        for (i, (o, w)) in o.iter().zip(want).enumerate() {
            assert!(
                o.transform.abs_diff_eq(w, 1e-4),
                "instance {i}: {} against {w}",
                o.transform
            );
        }
        // The instances share the mesh's geometry; the scaled one's box is twice as wide.
        assert!(o.iter().all(|x| x.first_index == o[0].first_index));
        let size = |x: &Object| x.bounds.max - x.bounds.min;
        assert!((size(&o[2]) - 2.0 * size(&o[0])).abs().max_element() < 1e-4);

        let broken = write(&dir, "counts.gltf", instanced_cubes(2).gltf_embedded());
        assert_scene_err(
            &broken,
            "EXT_mesh_gpu_instancing: its accessors count [3, 3, 2] instances",
        );
    }

    #[test]
    fn the_orbit_frames_the_level_inside_its_sky_box() {
        let dir = temp_dir("sky-box");
        let mut b = GltfBuilder::default();
        let cube = b.cube_mesh([1.0, 1.0, 1.0, 1.0]);
        // A level of two blocks about (2, 0.5, 0) and a sky box 2 km wide around it.
        b.node(cube, [0.0, 0.0, 0.0]);
        b.node(cube, [4.0, 1.0, 0.0]);
        b.nodes
            .push(format!(r#"{{"mesh":{cube},"scale":[2000,2000,2000]}}"#));
        b.scene_nodes = Some(vec![0, 1, 2]);
        let path = write(&dir, "sky-box.glb", b.glb());
        let scene =
            crate::scene::Scene::load(path.to_str().expect("utf-8"), 1.0, 4096).expect("load");
        let found = crate::scene::backdrop::find(&scene).expect("the sky box is the backdrop");
        assert_eq!(found.sky, vec![2]);
        // The orbit stands 1.5 of the level's bounding radii from its centre, inside the sky.
        let level = Aabb {
            min: Vec3::new(-0.5, -0.5, -0.5),
            max: Vec3::new(4.5, 1.5, 0.5),
        };
        let radius = level.extent().length() * 0.5;
        let orbit = scene.default_path().expect("orbit");
        for k in &orbit.keys {
            assert!((k.target - level.center()).length() < 1e-4, "{k:?}");
            let d = k.eye.distance(level.center());
            assert!((d - 1.5 * radius).abs() < 1e-3, "{d} against {radius}");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_file_loaded_at_a_scale_is_magnified_about_the_origin() {
        let dir = temp_dir("magnified");
        let mut b = GltfBuilder::default();
        let cube = b.cube_mesh([1.0, 1.0, 1.0, 1.0]);
        b.node(cube, [0.0, 0.0, 0.0]);
        b.node(cube, [3.0, 1.0, -2.0]);
        b.scene_nodes = Some(vec![0, 1]);
        let path = write(&dir, "magnified.glb", b.glb());
        let name = path.to_str().expect("utf-8 path");
        let one = crate::scene::Scene::load(name, 1.0, 4096).expect("load at 1");
        let f = 2.5;
        let big = crate::scene::Scene::load(name, f, 4096).expect("load at 2.5");
        assert_eq!(one.objects.len(), big.objects.len());
        let close = |a: Vec3, b: Vec3| (a - b).length() <= 1e-4 * (1.0 + b.length());
        for (a, b) in one.objects.iter().zip(&big.objects) {
            assert!(close(b.bounds.min, a.bounds.min * f) && close(b.bounds.max, a.bounds.max * f));
            for i in 0..a.vertex_count {
                let v = Vec3::from_array(one.vertices[(a.vertex_offset + i) as usize].position);
                let w = Vec3::from_array(big.vertices[(b.vertex_offset + i) as usize].position);
                assert!(close(
                    b.transform.transform_point3(w),
                    a.transform.transform_point3(v) * f
                ));
            }
        }
        assert_eq!(one.paths.len(), big.paths.len());
        for (p, q) in one.paths.iter().zip(&big.paths) {
            for (k, l) in p.keys.iter().zip(&q.keys) {
                assert!(close(l.eye, k.eye * f) && close(l.target, k.target * f));
            }
        }
        // Made as small as a can, the orbit keeps two near planes off the model's bounding
        // sphere (scaled with it, it would stand inside the near plane's reach).
        let small = crate::scene::Scene::load(name, 0.01, 4096).expect("load at 0.01");
        let bounds = small.bounds();
        let radius = bounds.extent().length() * 0.5;
        let orbit = small.default_path().expect("orbit");
        for k in &orbit.keys {
            let off = k.eye.distance(bounds.center()) - radius;
            assert!(
                off >= 2.0 * crate::scene::camera::NEAR_PLANE - 1e-5,
                "{off}"
            );
            assert!(close(k.target, bounds.center()));
        }
        for bad in [0.0, -1.0, 1e4, f32::NAN] {
            let Err(e) = crate::scene::Scene::load(name, bad, 4096) else {
                panic!("scale {bad} loaded");
            };
            let e = e.to_string();
            assert!(e.contains("0.001 to 1000"), "{e}");
        }
    }

    /// A node that mirrors its mesh (negative determinant) keeps the mesh's fronts facing
    /// out, as glTF says: it draws a copy of the indices with the winding turned over, shared
    /// by every mirroring node of that mesh, and every triangle of every cube faces away from
    /// its centre in world space (counter-clockwise, the renderer's front).
    #[test]
    fn mirroring_nodes_keep_their_fronts_facing_out() {
        let dir = temp_dir("mirrored");
        let mut b = GltfBuilder::default();
        let cube = b.cube_mesh([1.0, 1.0, 1.0, 1.0]);
        b.node(cube, [0.0, 0.0, 0.0]);
        for (t, s) in [
            ([3.0, 0.0, 0.0], [-1.0, 1.0, 1.0]),
            ([6.0, 0.0, 0.0], [1.0, 2.0, -0.5]),
        ] {
            b.nodes.push(format!(
                r#"{{"mesh":{cube},"translation":[{},{},{}],"scale":[{},{},{}]}}"#,
                t[0], t[1], t[2], s[0], s[1], s[2]
            ));
        }
        // Mirrored twice: not mirrored.
        b.nodes.push(format!(
            r#"{{"mesh":{cube},"translation":[9,0,0],"scale":[-1,-1,1]}}"#
        ));
        b.scene_nodes = Some(vec![0, 1, 2, 3]);
        let path = write(&dir, "mirrored.glb", b.glb());
        let (scene, _) = load_gltf(&path).expect("load");
        check_consistent(&scene);
        for (k, o) in scene.objects.iter().enumerate() {
            let centre = o.bounds.center();
            let idx =
                &scene.indices[o.first_index as usize..(o.first_index + o.index_count) as usize];
            for t in idx.chunks_exact(3) {
                let p = [t[0], t[1], t[2]].map(|i| {
                    let v = scene.vertices[(o.vertex_offset + i) as usize].position;
                    o.transform.transform_point3(Vec3::from_array(v))
                });
                let n = (p[1] - p[0]).cross(p[2] - p[0]);
                let out = (p[0] + p[1] + p[2]) / 3.0 - centre;
                assert!(n.dot(out) > 0.0, "object {k}: a triangle faces in");
            }
        }
        let firsts: Vec<u32> = scene.objects.iter().map(|o| o.first_index).collect();
        assert_eq!(
            firsts[0], firsts[3],
            "a double mirror draws the mesh as it is"
        );
        assert_eq!(
            firsts[1], firsts[2],
            "mirroring nodes share one turned copy"
        );
        assert_ne!(firsts[0], firsts[1]);
    }

    #[test]
    fn cube_grid_glb_instances() {
        let dir = temp_dir("grid");
        let path = write(&dir, "grid.glb", cube_grid_glb(10));
        let (scene, warnings) = load_gltf(&path).expect("load");
        assert!(warnings.is_empty());
        assert_eq!(scene.objects.len(), 10);
        assert_eq!(triangles(&scene), 120);
        // Geometry is stored once.
        assert_eq!(scene.vertices.len(), 24);
        assert_eq!(scene.indices.len(), 36);
        check_consistent(&scene);
    }

    #[test]
    fn composes_node_hierarchy_without_scenes() {
        let dir = temp_dir("hierarchy");
        let mut b = GltfBuilder::default();
        let cube = b.cube_mesh([1.0; 4]);
        // Node 0: parent translated by x=10 and scaled by 2, child node 1 translated by y=1.
        b.nodes
            .push(r#"{"translation":[10,0,0],"scale":[2,2,2],"children":[1]}"#.to_string());
        b.node(cube, [0.0, 1.0, 0.0]);
        let path = write(&dir, "tree.gltf", b.gltf_embedded());
        let (scene, _) = load_gltf(&path).expect("load");
        assert_eq!(scene.objects.len(), 1);
        let bounds = scene.objects[0].bounds;
        assert!(
            (bounds.min - Vec3::new(9.0, 1.0, -1.0)).length() < 1e-5,
            "{bounds:?}"
        );
        assert!(
            (bounds.max - Vec3::new(11.0, 3.0, 1.0)).length() < 1e-5,
            "{bounds:?}"
        );
    }

    #[test]
    fn skips_non_triangle_modes_with_warning() {
        let dir = temp_dir("modes");
        let mut b = two_cubes_and_triangle();
        let pos = b.vec3(&[[0.0; 3], [1.0, 0.0, 0.0]]);
        b.meshes.push(format!(
            r#"{{"name":"wire","primitives":[{{"attributes":{{"POSITION":{pos}}},"mode":1}}]}}"#
        ));
        let wire = b.meshes.len() - 1;
        b.node(wire, [0.0; 3]);
        b.scene_nodes = Some(vec![0, 1, 2, 3]);
        let path = write(&dir, "modes.gltf", b.gltf_embedded());
        let (scene, warnings) = load_gltf(&path).expect("load");
        assert_eq!(scene.objects.len(), 3);
        assert_eq!(warnings.len(), 1);
        assert!(
            warnings[0].contains("wire") && warnings[0].contains("Lines"),
            "{warnings:?}"
        );
    }

    #[test]
    fn triangle_strips_and_fans_become_lists_in_the_specs_vertex_order() {
        // A strip of four triangles and an indexed fan of four, both in the XY plane and
        // counter-clockwise seen from +Z in glTF's vertex order.
        let dir = temp_dir("strips");
        let mut b = GltfBuilder::default();
        let strip = b.vec3(&[
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 2.0, 0.0],
            [1.0, 2.0, 0.0],
        ]);
        let fan = b.vec3(&[
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
            [-1.0, 1.0, 0.0],
            [-1.0, 0.0, 0.0],
        ]);
        let fan_idx = b.indices_u16(&[0, 1, 2, 3, 4, 5]);
        b.meshes.push(format!(
            r#"{{"name":"strip","primitives":[{{"attributes":{{"POSITION":{strip}}},"mode":5}}]}}"#
        ));
        b.meshes.push(format!(
            r#"{{"name":"fan","primitives":[{{"attributes":{{"POSITION":{fan}}},"indices":{fan_idx},"mode":6}}]}}"#
        ));
        b.node(0, [0.0; 3]);
        b.node(1, [5.0, 0.0, 0.0]);
        b.scene_nodes = Some(vec![0, 1]);
        let path = write(&dir, "strips.gltf", b.gltf_embedded());
        let (scene, warnings) = load_gltf(&path).expect("load");
        assert!(warnings.is_empty(), "{warnings:?}");
        assert_eq!(scene.objects.len(), 2);
        assert_eq!(scene.objects[0].triangle_count(), 4);
        assert_eq!(scene.objects[1].triangle_count(), 4);
        for o in &scene.objects {
            let idx =
                &scene.indices[o.first_index as usize..(o.first_index + o.index_count) as usize];
            let at =
                |i: u32| Vec3::from_array(scene.vertices[(o.vertex_offset + i) as usize].position);
            for t in idx.chunks_exact(3) {
                let n = (at(t[1]) - at(t[0])).cross(at(t[2]) - at(t[0]));
                assert!(n.z > 0.0, "triangle {t:?} of {o:?} faces away from +Z");
            }
        }
        check_consistent(&scene);
        assert_eq!(
            strip_or_fan_triangles(&[0, 1, 2, 3, 4], false),
            [0, 1, 2, 1, 3, 2, 2, 3, 4]
        );
        assert_eq!(
            strip_or_fan_triangles(&[7, 8, 9, 10], true),
            [8, 9, 7, 9, 10, 7]
        );
        // The two triangles with the repeated vertex are left out.
        assert_eq!(strip_or_fan_triangles(&[0, 1, 2, 2, 3], false), [0, 1, 2]);
        assert!(strip_or_fan_triangles(&[0, 1], false).is_empty());
    }

    /// A triangle mesh whose POSITION accessor is sparse: `base` (a float VEC3 view) or zeros,
    /// with `values` written at the u16 `indices`.
    fn sparse_triangle(
        base: Option<&[[f32; 3]]>,
        indices: &[u16],
        values: &[[f32; 3]],
    ) -> GltfBuilder {
        let mut b = GltfBuilder::default();
        let count = base.map_or(3, <[_]>::len);
        let base_view = base
            .map(|data| {
                let bytes: Vec<u8> = data
                    .iter()
                    .flatten()
                    .flat_map(|f| f.to_le_bytes())
                    .collect();
                format!(r#""bufferView":{},"#, b.view(&bytes))
            })
            .unwrap_or_default();
        let idx: Vec<u8> = indices.iter().flat_map(|i| i.to_le_bytes()).collect();
        let idx_view = b.view(&idx);
        let val: Vec<u8> = values
            .iter()
            .flatten()
            .flat_map(|f| f.to_le_bytes())
            .collect();
        let val_view = b.view(&val);
        b.accessors.push(format!(
            r#"{{{base_view}"componentType":5126,"type":"VEC3","count":{count},"sparse":{{"count":{},"indices":{{"bufferView":{idx_view},"componentType":5123}},"values":{{"bufferView":{val_view}}}}}}}"#,
            indices.len()
        ));
        let pos = b.accessors.len() - 1;
        b.meshes.push(format!(
            r#"{{"name":"sparse","primitives":[{{"attributes":{{"POSITION":{pos}}}}}]}}"#
        ));
        b.node(0, [0.0; 3]);
        b.scene_nodes = Some(vec![0]);
        b
    }

    #[test]
    fn sparse_accessors_write_their_values_over_the_base_or_zeros() {
        let dir = temp_dir("sparse");
        let base = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        // Over a base view: the third vertex moves up to y = 3.
        let b = sparse_triangle(Some(&base), &[2], &[[0.0, 3.0, 0.0]]);
        let path = write(&dir, "over_base.glb", b.glb());
        let (scene, warnings) = load_gltf(&path).expect("load");
        assert!(warnings.is_empty(), "{warnings:?}");
        assert_eq!(scene.objects.len(), 1);
        assert_eq!(scene.objects[0].bounds.max, Vec3::new(1.0, 3.0, 0.0));
        check_consistent(&scene);
        // No base view: zeros, with the second and third vertices given.
        let b = sparse_triangle(None, &[1, 2], &[[2.0, 0.0, 0.0], [0.0, 2.0, 0.0]]);
        let path = write(&dir, "over_zeros.glb", b.glb());
        let (scene, _) = load_gltf(&path).expect("load");
        let o = &scene.objects[0];
        assert_eq!(
            (o.bounds.min, o.bounds.max),
            (Vec3::ZERO, Vec3::new(2.0, 2.0, 0.0))
        );
        let first = scene.vertices[o.vertex_offset as usize];
        assert_eq!(first.position, [0.0; 3]);
        assert_eq!(first.normal, [0.0, 0.0, 1.0]);
        check_consistent(&scene);
        // Broken ones are one-line errors.
        let cases: [(&[u16], &str); 2] = [
            (&[3], "sparse index 3 out of range (element count 3)"),
            (&[2, 1], "sparse indices do not increase"),
        ];
        for (i, (indices, needle)) in cases.into_iter().enumerate() {
            let values = vec![[1.0; 3]; indices.len()];
            let b = sparse_triangle(Some(&base), indices, &values);
            assert_scene_err(&write(&dir, &format!("bad{i}.glb"), b.glb()), needle);
        }
        let mut b = sparse_triangle(Some(&base), &[0, 1], &[[1.0; 3]]);
        b.views.pop();
        b.views
            .push(r#"{"buffer":0,"byteOffset":0,"byteLength":12}"#.to_string());
        assert_scene_err(
            &write(&dir, "short.glb", b.glb()),
            "sparse values: 2 elements",
        );
    }

    #[test]
    fn bounds_hold_the_triangles_under_turned_nodes_and_shared_accessors_tightly() {
        // One triangle turned 45 degrees about Z: the box of its turned vertices reaches
        // y = 0.707; its local box turned would reach 1.414. Two primitives share one POSITION
        // accessor of six vertices, each using three of them.
        let dir = temp_dir("tight");
        let mut b = GltfBuilder::default();
        let pos = b.vec3(&[
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [10.0, 0.0, 0.0],
            [11.0, 0.0, 0.0],
            [10.0, 1.0, 0.0],
        ]);
        let first = b.indices_u16(&[0, 1, 2]);
        let second = b.indices_u16(&[3, 4, 5]);
        b.meshes.push(format!(
            r#"{{"primitives":[{{"attributes":{{"POSITION":{pos}}},"indices":{first}}}]}}"#
        ));
        b.meshes.push(format!(
            r#"{{"primitives":[{{"attributes":{{"POSITION":{pos}}},"indices":{first}}},{{"attributes":{{"POSITION":{pos}}},"indices":{second}}}]}}"#
        ));
        let h = std::f32::consts::FRAC_1_SQRT_2;
        b.nodes.push(format!(
            r#"{{"mesh":0,"rotation":[0,0,{},{}]}}"#,
            (std::f32::consts::FRAC_PI_8).sin(),
            (std::f32::consts::FRAC_PI_8).cos()
        ));
        b.node(1, [0.0, 5.0, 0.0]);
        b.scene_nodes = Some(vec![0, 1]);
        let path = write(&dir, "tight.gltf", b.gltf_embedded());
        let (scene, _) = load_gltf(&path).expect("load");
        check_consistent(&scene);
        let turned = scene.objects[0].bounds;
        let want = Aabb::new(Vec3::new(-h, 0.0, 0.0), Vec3::new(h, h, 0.0));
        assert!(
            (turned.min - want.min).abs().max_element() < 1e-5
                && (turned.max - want.max).abs().max_element() < 1e-5,
            "{turned:?}"
        );
        let [a, c] = [scene.objects[1].bounds, scene.objects[2].bounds];
        assert_eq!(
            (a.min, a.max),
            (Vec3::new(0.0, 5.0, 0.0), Vec3::new(1.0, 6.0, 0.0))
        );
        assert_eq!(
            (c.min, c.max),
            (Vec3::new(10.0, 5.0, 0.0), Vec3::new(11.0, 6.0, 0.0))
        );
    }

    /// The world positions of `o`'s triangles' vertices, in index order.
    fn world_positions(scene: &Scene, o: &Object) -> Vec<Vec3> {
        scene.indices[o.first_index as usize..(o.first_index + o.index_count) as usize]
            .iter()
            .map(|&i| {
                let v = scene.vertices[(o.vertex_offset + i) as usize];
                o.transform.transform_point3(Vec3::from_array(v.position))
            })
            .collect()
    }

    fn assert_near(got: &[Vec3], want: &[[f32; 3]]) {
        assert_eq!(got.len(), want.len(), "{got:?}");
        for (g, w) in got.iter().zip(want) {
            assert!(
                (*g - Vec3::from_array(*w)).abs().max_element() < 1e-4,
                "{got:?} != {want:?}"
            );
        }
    }

    #[test]
    fn skinned_meshes_are_drawn_in_their_joints_pose_not_at_their_node() {
        let dir = temp_dir("skin");
        let mut joints = [0u8; 36];
        for v in 3..6 {
            joints[4 * v] = 1;
        }
        joints[4 * 6 + 1] = 1;
        let path = write(
            &dir,
            "skin.gltf",
            skinned_triangles(&joints).gltf_embedded(),
        );
        let (scene, warnings) = load_gltf(&path).expect("load");
        assert!(warnings.is_empty(), "{warnings:?}");
        check_consistent(&scene);
        assert_eq!(scene.objects.len(), 1);
        // Joint 0: x -> (10, 0, 0) + 2x. Joint 1: its world (10, 10, 0) + 2x times its inverse
        // bind matrix (x - (1, 0, 0)). Vertex 6 half each; vertices 7 and 8 have no weight and
        // keep their node's transform (+100 in x), which the skinned vertices ignore.
        assert_near(
            &world_positions(&scene, &scene.objects[0]),
            &[
                [10.0, 0.0, 0.0],
                [12.0, 0.0, 0.0],
                [10.0, 2.0, 0.0],
                [8.0, 10.0, 0.0],
                [10.0, 10.0, 0.0],
                [8.0, 12.0, 0.0],
                [9.0, 5.0, 2.0],
                [101.0, 0.0, 1.0],
                [100.0, 1.0, 1.0],
            ],
        );

        // A joint that mirrors turns its triangles' winding over, so that their fronts (counter-
        // clockwise) still face +z as the unskinned triangle's do.
        let mut b = skinned_triangles(&joints);
        b.nodes[0] = b.nodes[0].replace("[2,2,2]", "[-2,2,2]");
        let path = write(&dir, "mirrored.gltf", b.gltf_embedded());
        let (scene, _) = load_gltf(&path).expect("load");
        let p = world_positions(&scene, &scene.objects[0]);
        assert_near(
            &p[..3],
            &[[10.0, 0.0, 0.0], [10.0, 2.0, 0.0], [8.0, 0.0, 0.0]],
        );
        assert!((p[1] - p[0]).cross(p[2] - p[0]).z > 0.0);

        joints[4 * 6 + 1] = 2;
        let path = write(&dir, "bad.gltf", skinned_triangles(&joints).gltf_embedded());
        assert_scene_err(&path, "vertex 6 names joint 2 of a skin with 2 joints");
    }

    #[test]
    fn morph_targets_move_vertices_by_the_nodes_or_the_meshs_weights() {
        let dir = temp_dir("morph");
        let mut b = GltfBuilder::default();
        let pos = b.vec3(&[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
        let nrm = b.vec3(&[[0.0, 0.0, 1.0]; 3]);
        let dp = b.vec3(&[[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 2.0]]);
        let dn = b.vec3(&[[2.0, 0.0, -2.0]; 3]);
        b.meshes.push(format!(
            r#"{{"weights":[0.5],"primitives":[{{"attributes":{{"POSITION":{pos},"NORMAL":{nrm}}},"targets":[{{"POSITION":{dp},"NORMAL":{dn}}}]}}]}}"#
        ));
        b.node(0, [0.0, 0.0, 0.0]);
        b.nodes.push(r#"{"mesh":0,"weights":[2.0]}"#.to_string());
        b.scene_nodes = Some(vec![0, 1]);
        let path = write(&dir, "morph.gltf", b.gltf_embedded());
        let (scene, warnings) = load_gltf(&path).expect("load");
        assert!(warnings.is_empty(), "{warnings:?}");
        check_consistent(&scene);
        assert_eq!(scene.objects.len(), 2);
        assert_near(
            &world_positions(&scene, &scene.objects[0]),
            &[[0.0, 0.0, 0.5], [1.0, 0.0, 0.5], [0.0, 1.0, 1.0]],
        );
        assert_near(
            &world_positions(&scene, &scene.objects[1]),
            &[[0.0, 0.0, 2.0], [1.0, 0.0, 2.0], [0.0, 1.0, 4.0]],
        );
        // The normal (0, 0, 1) plus half of (2, 0, -2) is (1, 0, 0); plus twice, (4, 0, -3).
        let normal = |o: &Object| Vec3::from_array(scene.vertices[o.vertex_offset as usize].normal);
        assert!((normal(&scene.objects[0]) - Vec3::X).length() < 1e-5);
        assert!((normal(&scene.objects[1]) - Vec3::new(0.8, 0.0, -0.6)).length() < 1e-5);
    }

    /// A static cube (node 0) and a cube (node 1) that the first animation moves along x from
    /// -5 to `far` (5) and back over 2 s, with a child cube (node 2) 2 up whose scale steps to 2
    /// at 0.5 s.
    fn animated_cubes(far: f32) -> GltfBuilder {
        let mut b = GltfBuilder::default();
        let cube = b.cube_mesh([0.5, 0.5, 0.5, 1.0]);
        b.node(cube, [0.0, 0.0, -1.0]);
        b.nodes.push(format!(
            r#"{{"mesh":{cube},"translation":[0,0,2],"children":[2]}}"#
        ));
        b.node(cube, [0.0, 2.0, 0.0]);
        b.scene_nodes = Some(vec![0, 1]);
        let times = b.key_times(&[0.0, 1.0, 2.0]);
        let steps = b.key_times(&[0.0, 0.5]);
        let moved = b.vec3(&[[-5.0, 0.0, 2.0], [far, 0.0, 2.0], [-5.0, 0.0, 2.0]]);
        let scaled = b.vec3(&[[1.0; 3], [2.0; 3]]);
        b.head = format!(
            r#""animations":[{{"samplers":[{{"input":{times},"output":{moved}}},{{"input":{steps},"output":{scaled},"interpolation":"STEP"}}],"channels":[{{"sampler":0,"target":{{"node":1,"path":"translation"}}}},{{"sampler":1,"target":{{"node":2,"path":"scale"}}}}]}}],"#
        );
        b
    }

    #[test]
    fn the_first_animation_moves_its_objects_as_movers() {
        let dir = temp_dir("animated");
        let path = write(&dir, "animated.gltf", animated_cubes(5.0).gltf_embedded());
        let (mut scene, warnings) = load_gltf(&path).expect("load");
        assert_eq!(
            warnings,
            [
                "animation 0 moves 2 object(s): they are movers, placed every frame (30 frames a \
              second, a loop of 2.00 s)"
            ]
        );
        assert_eq!(scene.objects.len(), 1, "only the static cube stands still");
        scene.magnify(2.0);
        let movers = crate::scene::movers::Movers::add(&mut scene, 0);
        assert_eq!((movers.len(), scene.objects.len()), (2, 3));
        let at = |i: usize, frame: u64| {
            let m = movers.transform_at(i, frame);
            (
                m.transform_point3(Vec3::ZERO),
                m.transform_vector3(Vec3::X).length(),
            )
        };
        // Frame 15 is 0.5 s: x = 0 (linear), the child's scale has stepped to 2; frame 45 is
        // 1.5 s, on the way back; frame 60 loops to the start. All twice as large (magnify).
        assert_eq!(at(0, 0), (Vec3::new(-10.0, 0.0, 4.0), 2.0));
        assert_eq!(at(0, 15), (Vec3::new(0.0, 0.0, 4.0), 2.0));
        assert_eq!(at(0, 45), (Vec3::new(0.0, 0.0, 4.0), 2.0));
        assert_eq!(at(0, 60), at(0, 0));
        assert_eq!(at(1, 0), (Vec3::new(-10.0, 4.0, 4.0), 2.0));
        assert_eq!(
            at(1, 14),
            (Vec3::new(-10.0 + 20.0 * 14.0 / 30.0, 4.0, 4.0), 2.0)
        );
        assert_eq!(at(1, 15), (Vec3::new(0.0, 4.0, 4.0), 4.0));
        // The objects start where the animation starts, boxes and all.
        let start = &scene.objects[1];
        assert_eq!(start.transform, movers.transform_at(0, 0));
        assert!(start.bounds.contains(Vec3::new(-10.0, 0.0, 4.0)));

        // An animation that takes an object past MAX_COORDINATE leaves it at its start there.
        let path = write(&dir, "far.gltf", animated_cubes(1.0e13).gltf_embedded());
        let (mut scene, _) = load_gltf(&path).expect("load far");
        let movers = crate::scene::movers::Movers::add(&mut scene, 0);
        assert_eq!(movers.transform_at(0, 30), movers.transform_at(0, 0));
        assert_ne!(movers.transform_at(0, 1), movers.transform_at(0, 0));
    }

    /// A skinned mesh whose joint the first animation moves is a mover: each frame its
    /// vertices are skinned again at the animation's time and its box is theirs.
    #[test]
    fn skinned_meshes_follow_the_joints_their_animation_moves() {
        use super::testdata::skinned_column;
        let dir = temp_dir("skin_anim");
        let path = write(&dir, "column.gltf", skinned_column(4.0).gltf_embedded());
        let (mut scene, warnings) = load_gltf(&path).expect("load");
        assert_eq!(
            warnings,
            [
                "animation 0 moves 1 object(s): they are movers, placed every frame (30 frames a \
              second, a loop of 2.00 s, 1 mesh(es) skinned or morphed on the CPU each frame)"
            ]
        );
        assert_eq!(scene.objects.len(), 1, "the wall stands still");
        scene.magnify(2.0);
        let movers = crate::scene::movers::Movers::add(&mut scene, 0);
        assert_eq!(movers.deformed_meshes(), 1);
        assert_eq!((movers.len(), scene.objects.len()), (1, 2));
        let column = &scene.objects[1];
        let range =
            column.vertex_offset as usize..(column.vertex_offset + column.vertex_count) as usize;
        let pose = |frame: u64| {
            let mut posed = Vec::new();
            movers
                .for_each_deformed(frame, |first, v| {
                    assert_eq!(first as usize, range.start);
                    posed = v.to_vec();
                    Ok(())
                })
                .unwrap();
            let mut placed = None;
            movers
                .for_each_at(frame, |object, bounds, transform| {
                    placed = Some((object, bounds, *transform));
                    Ok(())
                })
                .unwrap();
            (posed, placed.unwrap())
        };
        let top = |v: &[Vertex]| v.iter().map(|v| v.position[1]).fold(f32::MIN, f32::max);
        // Frame 0: the default pose (y 0..1, 3 m behind the wall); the scene's vertices hold it.
        let (v0, (object, b0, t0)) = pose(0);
        assert_eq!(object, 1);
        assert_eq!(v0.len(), range.len());
        assert_eq!(scene.vertices[range.clone()], v0[..]);
        assert_eq!(top(&v0), 1.0);
        // Frame 15 is 0.5 s: the top corners are lifted by 2, the bottom ones stay; frame 30
        // (1 s) lifts them by 4; frame 60 loops to the start. `--scale 2` is the transform.
        let (v15, (_, b15, _)) = pose(15);
        assert_eq!(top(&v15), 3.0);
        for (a, b) in v0.iter().zip(&v15) {
            let lifted = if a.position[1] > 0.5 { 2.0 } else { 0.0 };
            assert_eq!(b.position[1], a.position[1] + lifted);
            assert_eq!(
                (b.position[0], b.position[2]),
                (a.position[0], a.position[2])
            );
        }
        assert_eq!(top(&pose(30).0), 5.0);
        assert_eq!(pose(60).0, v0);
        assert_eq!(t0, glam::Mat4::from_scale(Vec3::splat(2.0)));
        // The boxes are the posed vertices' (twice as large): the default one is 0..2 high,
        // the one at 0.5 s 0..6.
        assert_eq!((b0.min.y, b0.max.y), (0.0, 2.0));
        assert_eq!((b15.min.y, b15.max.y), (0.0, 6.0));
        assert_eq!((b15.min.z, b15.max.z), (-7.0, -5.0));
        // Posing the same frame again gives the same vertices.
        assert_eq!(pose(15).0, v15);

        // A pose that takes the column past MAX_COORDINATE keeps its loaded vertices there.
        let path = write(&dir, "far.gltf", skinned_column(1.0e13).gltf_embedded());
        let (mut scene, _) = load_gltf(&path).expect("load far");
        let movers = crate::scene::movers::Movers::add(&mut scene, 0);
        let posed = |frame: u64| {
            let mut posed = Vec::new();
            movers
                .for_each_deformed(frame, |_, v| {
                    posed = v.to_vec();
                    Ok(())
                })
                .unwrap();
            posed
        };
        assert_eq!(posed(30), posed(0));
        assert_ne!(posed(1), posed(0));

        // Without the animation the column is posed once and stands still.
        let mut b = skinned_column(4.0);
        b.head = r#""skins":[{"joints":[1,2]}],"#.to_string();
        let path = write(&dir, "still.gltf", b.gltf_embedded());
        let (mut scene, warnings) = load_gltf(&path).expect("load still");
        assert!(warnings.is_empty(), "{warnings:?}");
        let movers = crate::scene::movers::Movers::add(&mut scene, 0);
        assert!(movers.deformed_meshes() == 0 && movers.is_empty());
        assert_eq!(scene.objects.len(), 2);
    }

    /// A mesh whose morph weights the first animation plays is a mover: each frame its
    /// vertices are morphed at the animation's weights (and its node's animated transform
    /// places it), its box is theirs.
    #[test]
    fn morph_weights_the_animation_plays_move_vertices_each_frame() {
        let mut b = GltfBuilder::default();
        let tri = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let pos = b.vec3(&tri);
        let up = b.vec3(&[[0.0, 0.0, 2.0]; 3]);
        let side = b.vec3(&[[4.0, 0.0, 0.0]; 3]);
        b.meshes.push(format!(
            r#"{{"weights":[0,1],"primitives":[{{"attributes":{{"POSITION":{pos}}},"targets":[{{"POSITION":{up}}},{{"POSITION":{side}}}]}}]}}"#
        ));
        let still = b.cube_mesh([0.5; 4]);
        b.node(still, [0.0, 0.0, -5.0]);
        // Node 1 (moved along x over 2 s) holds node 2, the morphed triangle.
        b.nodes
            .push(r#"{"translation":[0,0,0],"children":[2]}"#.to_string());
        b.nodes
            .push(r#"{"mesh":0,"translation":[0,3,0]}"#.to_string());
        b.scene_nodes = Some(vec![0, 1]);
        let times = b.key_times(&[0.0, 1.0, 2.0]);
        // Two weights per key: target 0 goes 0 -> 1 -> 0, target 1 stays 0.
        let w: Vec<u8> = [0.0f32, 0.0, 1.0, 0.0, 0.0, 0.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let w = b.view(&w);
        let weights = b.accessor(w, 5126, "SCALAR", 6);
        let moved = b.vec3(&[[0.0; 3], [10.0, 0.0, 0.0], [0.0; 3]]);
        b.head = format!(
            r#""animations":[{{"samplers":[{{"input":{times},"output":{weights}}},{{"input":{times},"output":{moved}}}],"channels":[{{"sampler":0,"target":{{"node":2,"path":"weights"}}}},{{"sampler":1,"target":{{"node":1,"path":"translation"}}}}]}}],"#
        );
        let dir = temp_dir("morph_anim");
        let path = write(&dir, "morph.gltf", b.gltf_embedded());
        let (mut scene, warnings) = load_gltf(&path).expect("load");
        assert_eq!(
            warnings,
            [
                "animation 0 moves 1 object(s): they are movers, placed every frame (30 frames a \
              second, a loop of 2.00 s, 1 mesh(es) skinned or morphed on the CPU each frame)"
            ]
        );
        let movers = crate::scene::movers::Movers::add(&mut scene, 0);
        assert_eq!((movers.deformed_meshes(), movers.len()), (1, 1));
        let pose = |frame: u64| {
            let mut posed = Vec::new();
            movers
                .for_each_deformed(frame, |_, v| {
                    posed = v.iter().map(|v| Vec3::from_array(v.position)).collect();
                    Ok(())
                })
                .unwrap();
            let mut placed = None;
            movers
                .for_each_at(frame, |_, bounds, t| {
                    placed = Some((bounds, *t));
                    Ok(())
                })
                .unwrap();
            (posed, placed.unwrap())
        };
        // The animation's weights replace the mesh's default ones ([0, 1]) from frame 0 on.
        let (v0, (b0, t0)) = pose(0);
        assert_eq!(v0, tri.map(Vec3::from_array));
        assert_eq!(t0, Mat4::from_translation(Vec3::new(0.0, 3.0, 0.0)));
        assert_eq!(
            (b0.min, b0.max),
            (Vec3::new(0.0, 3.0, 0.0), Vec3::new(1.0, 4.0, 0.0))
        );
        // 0.5 s: weight 0.5 lifts z by 1; the parent has moved 5 along x.
        let (v15, (b15, t15)) = pose(15);
        assert!(v15
            .iter()
            .zip(&v0)
            .all(|(a, b)| *a == *b + Vec3::new(0.0, 0.0, 1.0)));
        assert_eq!(t15, Mat4::from_translation(Vec3::new(5.0, 3.0, 0.0)));
        assert_eq!(
            (b15.min, b15.max),
            (Vec3::new(5.0, 3.0, 1.0), Vec3::new(6.0, 4.0, 1.0))
        );
        assert!(pose(30).0.iter().all(|p| p.z == 2.0));
        assert_eq!(pose(60).0, v0);
    }

    /// A BLEND material whose alpha is one everywhere on an object is drawn opaque there (and
    /// culled); alpha under one in the factor or in the vertex colors keeps it blended.
    #[test]
    fn blend_materials_without_alpha_under_one_are_drawn_opaque() {
        let dir = temp_dir("opaque-blend");
        let mut b = GltfBuilder::default();
        let opaque = b.cube_mesh([0.5, 0.5, 0.5, 1.0]);
        let half = b.cube_mesh([0.5, 0.5, 0.5, 0.5]);
        b.node(opaque, [0.0, 0.0, 0.0]);
        b.node(half, [2.0, 0.0, 0.0]);
        for m in &mut b.materials {
            *m = m.replacen('{', r#"{"alphaMode":"BLEND","#, 1);
        }
        let path = write(&dir, "blend.gltf", b.gltf_embedded());
        let (scene, warnings) = load_gltf(&path).expect("load");
        let blended: Vec<bool> = (0..2).map(|o| scene.is_blended(o)).collect();
        assert_eq!(blended, [false, true]);
        assert_eq!(
            scene.object_material(0).map(|m| m.alpha),
            Some(crate::scene::AlphaMode::Opaque)
        );
        assert_eq!(scene.hierarchy(1).live_objects(), 1);
        assert!(
            warnings
                .iter()
                .any(|w| w.starts_with("material 0: alpha mode BLEND with no alpha")),
            "{warnings:?}"
        );
        assert!(
            warnings
                .iter()
                .any(|w| w.starts_with("material 1: alpha mode BLEND, blended")),
            "{warnings:?}"
        );
    }

    /// A blended material on animated nodes: the static cube blends (out of the hierarchy),
    /// the moving copies are alpha-tested, in the hierarchy, where the culler draws them.
    #[test]
    fn moving_copies_of_blended_objects_are_alpha_tested_and_culled() {
        let dir = temp_dir("animated-blend");
        let mut b = animated_cubes(5.0);
        for m in &mut b.materials {
            assert!(m.contains("[0.5,0.5,0.5,1]"), "{m}");
            *m = m
                .replacen('{', r#"{"alphaMode":"BLEND","#, 1)
                .replace("[0.5,0.5,0.5,1]", "[0.5,0.5,0.5,0.5]");
        }
        let path = write(&dir, "animated.gltf", b.gltf_embedded());
        let (mut scene, _) = load_gltf(&path).expect("load");
        let movers = crate::scene::movers::Movers::add(&mut scene, 0);
        assert_eq!((movers.len(), scene.objects.len()), (2, 3));
        let blended: Vec<bool> = (0..3).map(|o| scene.is_blended(o)).collect();
        assert_eq!(blended, [true, false, false]);
        assert_eq!(
            scene.object_material(1).map(|m| m.alpha),
            scene.object_material(0).map(|m| m.alpha)
        );
        let mut bvh = scene.hierarchy(1);
        assert_eq!(bvh.live_objects(), 2);
        for o in 0..3u32 {
            let b = scene.objects[o as usize].bounds;
            assert_eq!(bvh.set_bounds(o, b).is_ok(), o > 0, "object {o} in a leaf");
        }
    }

    /// `--animation`: by name or index another animation is played (its objects the movers,
    /// the first's static), `none` plays none, and a choice the file lacks is an error that
    /// lists the animations.
    #[test]
    fn the_chosen_animation_is_played_and_the_others_are_not() {
        let dir = temp_dir("chosen");
        let mut b = animated_cubes(5.0);
        let times = b.key_times(&[0.0, 1.0]);
        let lifted = b.vec3(&[[0.0, 0.0, -1.0], [0.0, 3.0, -1.0]]);
        // Two animations: "slide" (animated_cubes's: nodes 1 and 2) and "lift" (node 0 up).
        let slide = b
            .head
            .replacen(r#""animations":[{"#, r#""animations":[{"name":"slide","#, 1);
        let slide = slide
            .strip_suffix("],")
            .expect("the animations list ends the head");
        b.head = format!(
            r#"{slide},{{"name":"lift","samplers":[{{"input":{times},"output":{lifted}}}],"channels":[{{"sampler":0,"target":{{"node":0,"path":"translation"}}}}]}}],"#
        );
        let path = write(&dir, "two.gltf", b.gltf_embedded());
        let load = |choice: &str| load_gltf_playing(&path, &choice.parse().unwrap());
        let (first, warnings) = load_gltf(&path).expect("load");
        assert_eq!(first.objects.len(), 1, "slide moves two of the three cubes");
        assert!(
            warnings[0].ends_with(
                r#"; 1 other animation(s) not played (1 "lift"; --animation picks one)"#
            ),
            "{warnings:?}"
        );
        for choice in ["lift", "1"] {
            let (mut scene, warnings) = load(choice).expect("lift");
            assert!(
                warnings[0].starts_with("animation 1 moves 1 object(s)"),
                "{warnings:?}"
            );
            assert!(warnings[0].ends_with(r#"(0 "slide"; --animation picks one)"#));
            assert_eq!(scene.objects.len(), 2, "the slid cubes stand still");
            let movers = crate::scene::movers::Movers::add(&mut scene, 0);
            assert_eq!(movers.len(), 1);
            assert_eq!(
                movers.animation_label(),
                Some(r#"1 "lift""#),
                "the reports name it"
            );
            let up = movers.transform_at(0, 15).w_axis.y - movers.transform_at(0, 0).w_axis.y;
            assert_eq!(up, 1.5, "lift raises node 0 by 1.5 in 0.5 s");
        }
        let (still, warnings) = load("none").expect("none");
        assert_eq!(still.objects.len(), 3);
        assert!(still.animation.is_none());
        assert_eq!(
            warnings,
            ["2 animation(s) not played (--animation none): the scene is drawn in its default pose"]
        );
        for (choice, what) in [
            ("jump", r#"no animation named "jump""#),
            ("2", "no animation 2"),
        ] {
            let e = load(choice).err().unwrap().to_string();
            assert_eq!(
                e,
                format!(
                    "{}: {what}: the file's animations are 0 \"slide\", 1 \"lift\"",
                    path.display()
                )
            );
        }
        // A built-in scene has no glTF animation to pick.
        let e = crate::scene::Scene::load_with("cornell", 1.0, 0, None, &AnimationChoice::Nothing)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("\"cornell\" is a built-in scene"), "{e}");
    }

    #[test]
    fn animations_that_move_no_mesh_are_not_played_and_say_so() {
        let dir = temp_dir("animation");
        let mut b = two_cubes_and_triangle();
        let times = b.key_times(&[0.0]);
        let moved = b.vec3(&[[0.0, 50.0, 0.0]]);
        // It moves a node without a mesh (a skeleton's joints are such nodes).
        b.nodes.push("{}".to_string());
        b.head = format!(
            r#""animations":[{{"samplers":[{{"input":{times},"output":{moved}}}],"channels":[{{"sampler":0,"target":{{"node":3,"path":"translation"}}}}]}}],"#
        );
        let path = write(&dir, "animated.gltf", b.gltf_embedded());
        let (scene, warnings) = load_gltf(&path).expect("load");
        assert_eq!(
            warnings,
            ["1 animation(s) not played: the scene is drawn in its default pose"]
        );
        assert_eq!(scene.objects[0].transform.w_axis.y, 0.0);
        // Picked by `--animation 0`, it is named.
        let (_, warnings) = load_gltf_playing(&path, &AnimationChoice::Index(0)).expect("load");
        assert_eq!(
            warnings,
            ["animation 0 moves no mesh: the scene is drawn in its default pose"]
        );
    }

    #[test]
    fn primitives_with_equal_vertices_share_one_vertex_range() {
        // A mesh of three primitives over one POSITION and NORMAL accessor (as multi-material
        // exports write): the first two read the same vertices and share one range; the third
        // has its texture coordinates moved by its material's KHR_texture_transform, so its
        // vertices differ and get their own.
        let dir = temp_dir("shared");
        let mut b = GltfBuilder::default();
        let (positions, normals, indices) = testdata::cube();
        let pos = b.vec3(&positions);
        let nrm = b.vec3(&normals);
        let uv: Vec<u8> = (0..positions.len())
            .flat_map(|i| [i as f32 * 0.1, 0.5])
            .flat_map(f32::to_le_bytes)
            .collect();
        let view = b.view(&uv);
        let uv = b.accessor(view, 5126, "VEC2", positions.len());
        let (front, back) = indices.split_at(6);
        let front = b.indices_u16(front);
        let back = b.indices_u16(back);
        b.materials = vec![
            r#"{"pbrMetallicRoughness":{"baseColorFactor":[1,0,0,1]}}"#.to_string(),
            r#"{"pbrMetallicRoughness":{"baseColorFactor":[0,1,0,1]}}"#.to_string(),
            r#"{"pbrMetallicRoughness":{"baseColorTexture":{"index":0,"extensions":{"KHR_texture_transform":{"scale":[2,2]}}}}}"#.to_string(),
        ];
        let attributes =
            format!(r#""attributes":{{"POSITION":{pos},"NORMAL":{nrm},"TEXCOORD_0":{uv}}}"#);
        b.meshes.push(format!(
            r#"{{"primitives":[{{{attributes},"indices":{front},"material":0}},{{{attributes},"indices":{back},"material":1}},{{{attributes},"indices":{back},"material":2}}]}}"#
        ));
        b.node(0, [0.0; 3]);
        b.scene_nodes = Some(vec![0]);
        // The texture's image is not decoded (a warning); its transform applies all the same.
        let json = b.gltf_embedded().replacen(
            '{',
            r#"{"images":[{"uri":"data:image/png;base64,AAAA"}],"textures":[{"source":0}],"extensionsUsed":["KHR_texture_transform"],"#,
            1,
        );
        let path = write(&dir, "shared.gltf", json);
        let (scene, _) = load_gltf(&path).expect("load");
        check_consistent(&scene);
        let o = &scene.objects;
        assert_eq!(o.len(), 3);
        assert_eq!(o[0].vertex_offset, o[1].vertex_offset);
        assert_ne!(o[1].vertex_offset, o[2].vertex_offset);
        assert_eq!(scene.vertices.len(), 2 * positions.len());
        assert_eq!((o[0].color.x, o[1].color.y), (1.0, 1.0));
        // Each keeps its own triangles and the box of its own half.
        assert_eq!((o[0].triangle_count(), o[1].triangle_count()), (2, 10));
        assert_eq!((o[0].bounds.max.x, o[1].bounds.max.x), (-0.5, 0.5));
    }

    /// The unit cube as a Draco stream (positions and normals, 24 points, 12 faces), and the
    /// unique ids of its two attributes.
    fn draco_cube() -> (Vec<u8>, u32, u32) {
        use draco_core::{
            DataType, EncoderBuffer, EncoderOptions, FaceIndex, GeometryAttributeType, Mesh,
            MeshEncoder, PointAttribute, PointIndex,
        };
        let (positions, normals, indices) = testdata::cube();
        let mut mesh = Mesh::new();
        mesh.set_num_points(positions.len());
        let mut ids = Vec::new();
        for (kind, values) in [
            (GeometryAttributeType::Position, &positions),
            (GeometryAttributeType::Normal, &normals),
        ] {
            let mut a = PointAttribute::new();
            a.init(kind, 3, DataType::Float32, false, values.len());
            for (i, v) in values.iter().enumerate() {
                let bytes: Vec<u8> = v.iter().flat_map(|c| c.to_le_bytes()).collect();
                a.buffer_mut().write(i * 12, &bytes);
            }
            let id = mesh.add_attribute(a);
            ids.push(mesh.attribute(id).unique_id());
        }
        mesh.set_num_faces(indices.len() / 3);
        for (f, t) in indices.chunks_exact(3).enumerate() {
            let p = |i: u16| PointIndex(u32::from(i));
            mesh.set_face(FaceIndex(f as u32), [p(t[0]), p(t[1]), p(t[2])]);
        }
        let mut encoder = MeshEncoder::new();
        encoder.set_mesh(mesh);
        let mut out = EncoderBuffer::new();
        encoder
            .encode(&EncoderOptions::new(), &mut out)
            .expect("encode");
        (out.data().to_vec(), ids[0], ids[1])
    }

    #[test]
    fn draco_compressed_primitives_are_decoded() {
        // The cube's geometry only in a Draco stream (its accessors have no buffer views), the
        // extension required, as `gltf-transform draco` writes.
        let dir = temp_dir("draco-cube");
        let (stream, pos_id, nrm_id) = draco_cube();
        let good = |stream: &[u8]| {
            let mut b = GltfBuilder::default();
            let view = b.view(stream);
            b.accessors
                .push(r#"{"componentType":5123,"type":"SCALAR","count":36}"#.to_string());
            b.accessors
                .push(r#"{"componentType":5126,"type":"VEC3","count":24}"#.to_string());
            b.accessors
                .push(r#"{"componentType":5126,"type":"VEC3","count":24}"#.to_string());
            b.meshes.push(format!(
                r#"{{"primitives":[{{"attributes":{{"POSITION":1,"NORMAL":2}},"indices":0,"extensions":{{"KHR_draco_mesh_compression":{{"bufferView":{view},"attributes":{{"POSITION":{pos_id},"NORMAL":{nrm_id}}}}}}}}}]}}"#
            ));
            b.node(0, [3.0, 0.0, 0.0]);
            b.scene_nodes = Some(vec![0]);
            b.head = r#""extensionsUsed":["KHR_draco_mesh_compression"],"extensionsRequired":["KHR_draco_mesh_compression"],"#.to_string();
            b.glb()
        };
        let path = write(&dir, "cube.glb", good(&stream));
        let (scene, warnings) = load_gltf(&path).expect("load");
        assert!(warnings.is_empty(), "{warnings:?}");
        check_consistent(&scene);
        assert_eq!(scene.objects.len(), 1);
        assert_eq!(scene.objects[0].triangle_count(), 12);
        let b = scene.objects[0].bounds;
        assert!(
            (b.min - Vec3::new(2.5, -0.5, -0.5)).abs().max_element() < 1e-3
                && (b.max - Vec3::new(3.5, 0.5, 0.5)).abs().max_element() < 1e-3,
            "{b:?}"
        );
        // Each vertex keeps its face's normal: the six directions, each on four vertices.
        let mut axes = std::collections::HashMap::new();
        for v in &scene.vertices {
            let n = Vec3::from_array(v.normal).round();
            *axes.entry(n.to_array().map(|c| c as i32)).or_insert(0) += 1;
        }
        assert_eq!(axes.len(), 6, "{axes:?}");
        assert!(axes.values().all(|&c| c == 4), "{axes:?}");
        // A damaged stream is a one-line error naming the extension.
        let mut damaged = stream.clone();
        damaged.truncate(damaged.len() / 2);
        let path = write(&dir, "damaged.glb", good(&damaged));
        assert_scene_err(&path, "KHR_draco_mesh_compression: cannot decode");
    }

    #[test]
    fn unsupported_required_extension_is_named_first_and_the_error_stays_short() {
        let dir = temp_dir("required");
        let mut b = GltfBuilder::default();
        // Forty accessors that refer to a missing buffer view: 40 errors besides the one
        // unsupported extension.
        let accessors: Vec<String> = (0..40)
            .map(|_| r#"{"bufferView":7,"componentType":5126,"count":3,"type":"VEC3"}"#.to_string())
            .collect();
        b.accessors.extend(accessors);
        b.meshes
            .push(r#"{"primitives":[{"attributes":{"POSITION":0}}]}"#.to_string());
        b.node(0, [0.0; 3]);
        let json = b.gltf_embedded().replacen(
            r#"{"asset":{"version":"2.0"},"#,
            r#"{"asset":{"version":"2.0"},"extensionsUsed":["EXT_structural_metadata"],"extensionsRequired":["EXT_structural_metadata"],"#,
            1,
        );
        let path = write(&dir, "metadata.gltf", json);
        assert_scene_err(&path, "does not support (EXT_structural_metadata)");
        let msg = load_gltf(&path).err().unwrap().to_string();
        assert!(msg.contains("and 36 more"), "{msg}");
        assert!(msg.len() < 600, "{} characters: {msg}", msg.len());
    }

    #[test]
    fn bad_normals_are_recomputed() {
        let dir = temp_dir("normals");
        let mut b = GltfBuilder::default();
        let pos = b.vec3(&[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
        let nrm = b.vec3(&[[0.0, 0.0, 0.0], [f32::NAN, 0.0, 0.0]]);
        b.meshes.push(format!(
            r#"{{"primitives":[{{"attributes":{{"POSITION":{pos},"NORMAL":{nrm}}}}}]}}"#
        ));
        b.node(0, [0.0; 3]);
        let path = write(&dir, "normals.gltf", b.gltf_embedded());
        let (scene, warnings) = load_gltf(&path).expect("load");
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        assert!(scene.vertices.iter().all(|v| v.normal == [0.0, 0.0, 1.0]));
    }

    #[test]
    fn err_missing_file() {
        let dir = temp_dir("missing");
        assert_scene_err(&dir.join("nothere.glb"), "cannot read file");
    }

    #[test]
    fn err_truncated_glb() {
        let dir = temp_dir("truncated");
        let bytes = two_cubes_and_triangle().glb();
        let path = write(&dir, "cut.glb", &bytes[..bytes.len() / 2]);
        assert_scene_err(&path, "invalid glTF");
        // Every cut point gives an error, never a panic or a bogus scene.
        for len in (0..bytes.len()).step_by(7) {
            std::fs::write(&path, &bytes[..len]).expect("write");
            assert!(load_gltf(&path).is_err(), "cut at {len} loaded");
        }
    }

    #[test]
    fn err_invalid_json() {
        let dir = temp_dir("json");
        let path = write(
            &dir,
            "broken.gltf",
            r#"{"asset":{"version":"2.0"},"nodes":[{"mesh":"#,
        );
        assert_scene_err(&path, "invalid glTF");
        let path = write(
            &dir,
            "badref.gltf",
            r#"{"asset":{"version":"2.0"},"nodes":[{"mesh":7}]}"#,
        );
        assert_scene_err(&path, "invalid glTF");
    }

    #[test]
    fn err_short_buffer() {
        let dir = temp_dir("shortbuf");
        let mut b = two_cubes_and_triangle();
        let declared = b.bin.len() + 64;
        b.buffer_length_override = Some(declared);
        let path = write(&dir, "short.gltf", b.gltf_embedded());
        assert_scene_err(&path, "buffer 0 is short");
    }

    #[test]
    fn err_missing_buffer_for_glb() {
        // A .glb whose JSON declares a BIN buffer but that has no binary chunk.
        let dir = temp_dir("noblob");
        let b = two_cubes_and_triangle();
        let mut json = b.json(None).into_bytes();
        while !json.len().is_multiple_of(4) {
            json.push(b' ');
        }
        let mut glb = Vec::new();
        glb.extend_from_slice(b"glTF");
        glb.extend_from_slice(&2u32.to_le_bytes());
        glb.extend_from_slice(&((20 + json.len()) as u32).to_le_bytes());
        glb.extend_from_slice(&(json.len() as u32).to_le_bytes());
        glb.extend_from_slice(b"JSON");
        glb.extend_from_slice(&json);
        let path = write(&dir, "noblob.glb", glb);
        assert_scene_err(&path, "cannot load buffer 0");
    }

    #[test]
    fn err_accessor_past_view() {
        let dir = temp_dir("accessor");
        let mut b = two_cubes_and_triangle();
        // The triangle's POSITION accessor claims 4 elements in a 3-element view.
        let view = b.view(&[0u8; 36]);
        let acc = b.accessor(view, 5126, "VEC3", 4);
        b.meshes[1] =
            format!(r#"{{"name":"tri","primitives":[{{"attributes":{{"POSITION":{acc}}}}}]}}"#);
        let path = write(&dir, "overrun.gltf", b.gltf_embedded());
        assert_scene_err(&path, "read past the end");
    }

    #[test]
    fn err_view_past_buffer() {
        let dir = temp_dir("view");
        let mut b = two_cubes_and_triangle();
        let len = b.bin.len();
        b.views.push(format!(
            r#"{{"buffer":0,"byteOffset":{},"byteLength":36}}"#,
            len - 12
        ));
        let acc = b.accessor(b.views.len() - 1, 5126, "VEC3", 3);
        b.meshes[1] =
            format!(r#"{{"name":"tri","primitives":[{{"attributes":{{"POSITION":{acc}}}}}]}}"#);
        let path = write(&dir, "viewrun.gltf", b.gltf_embedded());
        assert_scene_err(&path, "exceeds buffer");
    }

    #[test]
    fn err_missing_external_bin() {
        let dir = temp_dir("nobin");
        let b = two_cubes_and_triangle();
        let path = write(&dir, "lonely.gltf", b.json(Some("lonely.bin")));
        assert_scene_err(&path, "cannot load buffer 0 from 'lonely.bin'");
    }

    #[test]
    fn err_index_out_of_range() {
        let dir = temp_dir("index");
        let mut b = GltfBuilder::default();
        let pos = b.vec3(&[[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
        let idx = b.indices_u32(&[0, 1, 3]);
        b.meshes.push(format!(
            r#"{{"primitives":[{{"attributes":{{"POSITION":{pos}}},"indices":{idx}}}]}}"#
        ));
        b.node(0, [0.0; 3]);
        let path = write(&dir, "badindex.glb", b.glb());
        assert_scene_err(&path, "index 3 out of range");
    }

    #[test]
    fn err_non_finite_position() {
        let dir = temp_dir("nan");
        for (name, bad) in [("nan.gltf", f32::NAN), ("inf.gltf", f32::INFINITY)] {
            let mut b = GltfBuilder::default();
            let pos = b.vec3(&[[0.0; 3], [1.0, bad, 0.0], [0.0, 1.0, 0.0]]);
            b.meshes.push(format!(
                r#"{{"primitives":[{{"attributes":{{"POSITION":{pos}}}}}]}}"#
            ));
            b.node(0, [0.0; 3]);
            let path = write(&dir, name, b.gltf_embedded());
            assert_scene_err(&path, "non-finite position");
        }
    }

    #[test]
    fn err_index_count_not_multiple_of_three() {
        let dir = temp_dir("count");
        let mut b = GltfBuilder::default();
        let pos = b.vec3(&[[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
        let idx = b.indices_u16(&[0, 1, 2, 0, 1, 2, 0]);
        b.meshes.push(format!(
            r#"{{"primitives":[{{"attributes":{{"POSITION":{pos}}},"indices":{idx}}}]}}"#
        ));
        b.node(0, [0.0; 3]);
        let path = write(&dir, "seven.gltf", b.gltf_embedded());
        assert_scene_err(&path, "not a multiple of 3");
        // Non-indexed with 4 vertices.
        let mut b = GltfBuilder::default();
        let pos = b.vec3(&[[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0; 3]]);
        b.meshes.push(format!(
            r#"{{"primitives":[{{"attributes":{{"POSITION":{pos}}}}}]}}"#
        ));
        b.node(0, [0.0; 3]);
        let path = write(&dir, "four.gltf", b.gltf_embedded());
        assert_scene_err(&path, "not a multiple of 3");
    }

    #[test]
    fn err_no_triangles() {
        let dir = temp_dir("empty");
        let mut b = GltfBuilder::default();
        let pos = b.vec3(&[[0.0; 3], [1.0, 0.0, 0.0]]);
        b.meshes.push(format!(
            r#"{{"primitives":[{{"attributes":{{"POSITION":{pos}}},"mode":0}}]}}"#
        ));
        b.node(0, [0.0; 3]);
        let path = write(&dir, "points.gltf", b.gltf_embedded());
        assert_scene_err(&path, "no triangle geometry");
        let path = write(&dir, "nothing.glb", cube_grid_glb(0));
        assert_scene_err(&path, "no triangle geometry");
    }

    #[test]
    fn err_cyclic_hierarchy() {
        let dir = temp_dir("cycle");
        let mut b = GltfBuilder::default();
        b.cube_mesh([1.0; 4]);
        b.nodes.push(r#"{"mesh":0,"children":[1]}"#.to_string());
        b.nodes.push(r#"{"children":[0]}"#.to_string());
        b.scene_nodes = Some(vec![0]);
        let path = write(&dir, "cycle.gltf", b.gltf_embedded());
        assert_scene_err(&path, "cycle");
    }

    #[test]
    fn base64_matches_known_values() {
        assert_eq!(base64(b""), "");
        assert_eq!(base64(b"f"), "Zg==");
        assert_eq!(base64(b"fo"), "Zm8=");
        assert_eq!(base64(b"foo"), "Zm9v");
        assert_eq!(base64(b"foobar"), "Zm9vYmFy");
    }
}
