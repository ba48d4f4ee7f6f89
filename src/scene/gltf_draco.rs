//! `KHR_draco_mesh_compression`: a primitive whose geometry is a Draco stream in a buffer view
//! (what `gltf-transform draco` and other web pipelines write), decoded with the pure-Rust
//! `draco-core` crate under ceilings on what one stream may decode to. The attributes the
//! extension names come from the decoded points, the triangles from its faces; any other
//! attribute of the primitive is read from its accessor as usual.

use ::gltf::buffer::Data;
use ::gltf::{Document, Primitive};
use draco_core::decode_limits::DecodeLimits;
use draco_core::decoder_buffer::DecoderBuffer;
use draco_core::draco_types::DataType;
use draco_core::geometry_indices::FaceIndex;
use draco_core::mesh::Mesh;
use draco_core::mesh_decoder::MeshDecoder;

/// The extension's name.
pub const DRACO: &str = "KHR_draco_mesh_compression";
/// Most points one primitive's stream may decode to (the scene's buffers are 32-bit indexed).
const MAX_POINTS: u64 = 1 << 26;
/// Most triangles one primitive's stream may decode to.
const MAX_FACES: u64 = 1 << 26;
/// Most attribute bytes one primitive's stream may decode to.
const MAX_DECODED_BYTES: u64 = 1 << 30;

/// A primitive's decoded Draco geometry.
pub(super) struct DracoPrimitive {
    /// The triangles, three point indices each.
    pub indices: Vec<u32>,
    /// The number of points (the primitive's vertex count).
    pub points: usize,
    /// Per attribute the extension names (`"POSITION"`, `"TEXCOORD_0"`, ...): one value per
    /// point, up to four components (the rest 0), normalized integers mapped to [0, 1] or
    /// [-1, 1].
    attributes: Vec<(String, Vec<[f32; 4]>)>,
}

impl DracoPrimitive {
    /// The decoded values of the attribute `name`, when the extension names it.
    pub fn attribute(&self, name: &str) -> Option<&[[f32; 4]]> {
        self.attributes
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_slice())
    }
}

/// Decodes the primitive's Draco stream: `Ok(None)` when the primitive has no
/// `KHR_draco_mesh_compression`, an error (without the primitive's label) when its stream,
/// buffer view or attribute ids are unusable.
pub(super) fn decode(
    prim: &Primitive<'_>,
    doc: &Document,
    buffers: &[Data],
) -> Result<Option<DracoPrimitive>, String> {
    let Some(ext) = prim.extension_value(DRACO) else {
        return Ok(None);
    };
    let fail = |what: String| format!("{DRACO}: {what}");
    let view = ext
        .get("bufferView")
        .and_then(serde_json::Value::as_u64)
        .and_then(|i| doc.views().nth(usize::try_from(i).ok()?))
        .ok_or_else(|| fail("its bufferView is not a buffer view of the file".to_string()))?;
    let bytes = super::gltf::view_bytes(&view, buffers).map_err(fail)?;
    let limits = DecodeLimits::default()
        .with_max_points(MAX_POINTS)
        .with_max_faces(MAX_FACES)
        .with_max_decoded_bytes(MAX_DECODED_BYTES);
    let mut stream = DecoderBuffer::new(bytes).with_limits(limits);
    let mut mesh = Mesh::new();
    MeshDecoder::new()
        .decode(&mut stream, &mut mesh)
        .map_err(|e| fail(format!("cannot decode buffer view {}: {e}", view.index())))?;
    let points = mesh.num_points();
    let mut indices = Vec::with_capacity(mesh.num_faces() * 3);
    for f in 0..mesh.num_faces() {
        let face = mesh.face(FaceIndex(f as u32));
        for p in face {
            if p.0 as usize >= points {
                return Err(fail(format!("face {f} uses point {} of {points}", p.0)));
            }
            indices.push(p.0);
        }
    }
    let names = ext
        .get("attributes")
        .and_then(serde_json::Value::as_object)
        .ok_or_else(|| fail("it has no attributes".to_string()))?;
    let mut attributes = Vec::with_capacity(names.len());
    for (name, id) in names {
        let attribute = id
            .as_u64()
            .and_then(|id| u32::try_from(id).ok())
            .and_then(|id| mesh.attribute_by_unique_id(id))
            .ok_or_else(|| fail(format!("{name}'s attribute id {id} is not in the stream")))?;
        let components = usize::from(attribute.num_components()).min(4);
        let scale = match attribute.data_type() {
            _ if !attribute.normalized() => 1.0,
            DataType::Uint8 => 1.0 / 255.0,
            DataType::Int8 => 1.0 / 127.0,
            DataType::Uint16 => 1.0 / 65535.0,
            DataType::Int16 => 1.0 / 32767.0,
            _ => 1.0,
        };
        if components == 0 {
            return Err(fail(format!("{name} has no components")));
        }
        let values = attribute
            .read_f32s(points, components)
            .chunks_exact(components)
            .map(|c| {
                let mut v = [0.0; 4];
                for (o, &x) in v.iter_mut().zip(c) {
                    *o = if scale == 1.0 {
                        x
                    } else {
                        (x * scale).max(-1.0)
                    };
                }
                v
            })
            .collect();
        attributes.push((name.clone(), values));
    }
    Ok(Some(DracoPrimitive {
        indices,
        points,
        attributes,
    }))
}
