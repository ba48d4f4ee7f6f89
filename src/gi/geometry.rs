//! The scene flattened to world-space triangles for GI: one list feeds the CPU ray caster
//! ([`RayScene`]) and, expanded to non-indexed vertices, the GPU passes (vertex pulling).

use std::collections::HashMap;

use glam::{Mat3, Mat4, Vec3};

use crate::gi::textures::{TriangleTextures, MAX_EDGE};
use crate::scene::interior::cache::Words;
use crate::scene::mask::{TriangleMask, TriangleMasks};
use crate::scene::material::surface_color;
use crate::scene::raycast::RayScene;
use crate::scene::{Aabb, SamplerDesc, Scene, TextureImage, VertexAttributes};

/// Mip chains of one scene's base color images that triangles are averaged over, made on
/// first use and shared by the objects that use an image (keyed by the image's address: one
/// value serves one scene, while it is borrowed).
#[derive(Default)]
pub(crate) struct TextureMips {
    chains: HashMap<usize, Vec<TextureImage>>,
}

impl TextureMips {
    /// The level of `image` at `lod` (0: the image itself; past the last, the last, 1x1).
    fn level<'a>(&'a mut self, image: &'a TextureImage, lod: u32) -> &'a TextureImage {
        // An image without texels is left to `TextureImage::sample`, which reads it as white.
        if lod == 0 || !image.has_texels() {
            return image;
        }
        let chain = self.chain(image);
        match chain.len() {
            0 => image,
            n => &chain[(lod as usize).min(n) - 1],
        }
    }

    /// The levels below `image`, made the first time.
    fn chain(&mut self, image: &TextureImage) -> &Vec<TextureImage> {
        (self.chains)
            .entry(image as *const TextureImage as usize)
            .or_insert_with(|| image.mip_chain())
    }

    /// The levels of `image` from `lod` (0: the image itself) down to 1x1, the chain made
    /// once and shared with [`material_albedo`]'s reads.
    fn chain_from(&mut self, image: &TextureImage, lod: u32) -> Vec<TextureImage> {
        let lod = lod as usize;
        let first = (lod == 0).then(|| image.clone());
        if !image.has_texels() {
            return first.into_iter().collect();
        }
        let chain = self.chain(image);
        let from = lod.saturating_sub(1).min(chain.len().saturating_sub(1));
        first
            .into_iter()
            .chain(chain.get(from..).unwrap_or_default().iter().cloned())
            .collect()
    }
}

/// The number of halvings that bring `image` to at most `edge` texels a side.
fn levels_above(image: &TextureImage, edge: u32) -> u32 {
    let largest = image.width.max(image.height).max(1);
    let mut lod = 0;
    while (largest >> lod) > edge.max(1) {
        lod += 1;
    }
    lod
}

/// One albedo for a triangle of a scene with materials: base color factor x vertex color x
/// base color texture, averaged over 16 points spread over it (the GI's G-buffer and the
/// ray caster's hit colors take one albedo per triangle). The texture is read at the mip level
/// where a texel covers a sixteenth to a quarter of the triangle's footprint, so a large
/// triangle over a tiled texture takes about the texture's mean rather than a few of its
/// texels (neighbouring triangles of one wall get about one albedo, not a patchwork), while
/// the points, kept off its sides, read little from beyond them (an atlas's other charts).
fn material_albedo(
    base: glam::Vec4,
    corners: &[VertexAttributes; 3],
    texture: Option<(&TextureImage, &SamplerDesc)>,
    mips: &mut TextureMips,
) -> Vec3 {
    // Without a texture the color is linear over the triangle: its centroid is its mean.
    let weights: &[Vec3] = match texture {
        Some(_) => &SUBTRIANGLE_CENTROIDS,
        None => &[Vec3::splat(1.0 / 3.0)],
    };
    let level = texture.map(|(image, sampler)| {
        let uv = corners.map(|c| glam::Vec2::from(c.uv));
        let texels = (uv[1] - uv[0]).perp_dot(uv[2] - uv[0]).abs()
            * 0.5
            * image.width as f32
            * image.height as f32;
        // A texel of level `lod` covers 4^lod texels of level 0: two levels finer than the
        // one whose texel is the whole footprint.
        let lod = if texels.is_finite() && texels > 1.0 {
            ((0.5 * texels.log2()).floor().min(31.0) as u32).saturating_sub(2)
        } else {
            0
        };
        // Minified, the level is read filtered; at level 0 as the sampler says.
        let filtered = SamplerDesc {
            mag_linear: sampler.mag_linear || lod > 0,
            ..*sampler
        };
        (mips.level(image, lod), filtered)
    });
    let texture = level.as_ref().map(|(image, sampler)| (*image, sampler));
    let sum: glam::Vec4 = weights
        .iter()
        .map(|&w| surface_color(base, corners, w, texture))
        .sum();
    (sum / weights.len() as f32).truncate()
}

/// Sides of a triangle cut into this many parts: `SUBTRIANGLES_PER_SIDE`² sub-triangles.
const SUBTRIANGLES_PER_SIDE: usize = 4;

/// The barycentric centroids of a triangle's sub-triangles when its sides are cut into
/// [`SUBTRIANGLES_PER_SIDE`] parts: points spread evenly over it, each at least a twelfth of
/// the way in from every side, averaging to its centroid.
static SUBTRIANGLE_CENTROIDS: std::sync::LazyLock<Vec<Vec3>> = std::sync::LazyLock::new(|| {
    let k = SUBTRIANGLES_PER_SIDE;
    let point = |a: f32, b: f32| {
        let (a, b) = (a / k as f32, b / k as f32);
        Vec3::new(a, b, 1.0 - a - b)
    };
    let mut points = Vec::with_capacity(k * k);
    for i in 0..k {
        for j in 0..k - i {
            points.push(point(i as f32 + 1.0 / 3.0, j as f32 + 1.0 / 3.0));
            if i + j + 2 <= k {
                points.push(point(i as f32 + 2.0 / 3.0, j as f32 + 2.0 / 3.0));
            }
        }
    }
    points
});

/// Floats per GPU vertex: position (vec4), normal (vec4), albedo (vec4), std430 layout.
pub const VERTEX_FLOATS: usize = 12;

/// One piece of a tessellated triangle: its source triangle and its corners as barycentric
/// weights of the source's corners.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Piece {
    /// Index of the triangle the piece was split from.
    pub source: u32,
    /// Each corner of the piece as weights of the source's three corners.
    pub weights: [Vec3; 3],
}

/// World-space triangles of a scene with one albedo each.
#[derive(Clone, Debug)]
pub struct WorldGeometry {
    /// Triangle corners in world space.
    pub triangles: Vec<[Vec3; 3]>,
    /// Per-vertex normals in world space, parallel to `triangles`.
    pub normals: Vec<[Vec3; 3]>,
    /// Diffuse albedo per triangle.
    pub albedo: Vec<Vec3>,
    /// World bounds.
    pub bounds: Aabb,
    /// Alpha masks of the triangles (empty when none is masked).
    pub masks: TriangleMasks,
    /// Base color textures of the triangles, for the G-buffer (empty when none is textured).
    pub textures: TriangleTextures,
}

impl WorldGeometry {
    /// Applies every object's transform to its triangles.
    pub fn from_scene(scene: &Scene) -> WorldGeometry {
        Self::from_objects(scene, 0..scene.objects.len())
    }

    /// [`WorldGeometry::from_scene`] for the objects in `objects` only, in order.
    pub fn from_objects(scene: &Scene, objects: impl IntoIterator<Item = usize>) -> WorldGeometry {
        let mut out = WorldGeometry::empty();
        let mut mips = TextureMips::default();
        for index in objects {
            out.push_object(scene, index, &scene.objects[index].transform, &mut mips);
        }
        out
    }

    /// Object `index` of `scene` in its own space (its transform not applied); `mips` holds
    /// the texture levels made so far, for objects that share images.
    pub(crate) fn object_local(
        scene: &Scene,
        index: usize,
        mips: &mut TextureMips,
    ) -> WorldGeometry {
        let mut out = WorldGeometry::empty();
        out.push_object(scene, index, &Mat4::IDENTITY, mips);
        out
    }

    /// No triangles.
    pub fn empty() -> WorldGeometry {
        WorldGeometry {
            triangles: Vec::new(),
            normals: Vec::new(),
            albedo: Vec::new(),
            bounds: Aabb::EMPTY,
            masks: TriangleMasks::default(),
            textures: TriangleTextures::default(),
        }
    }

    /// Appends the triangles of object `index` of `scene`, placed by `transform`.
    fn push_object(
        &mut self,
        scene: &Scene,
        index: usize,
        transform: &Mat4,
        mips: &mut TextureMips,
    ) {
        let o = &scene.objects[index];
        let texture = scene
            .object_material(index)
            .and_then(|m| scene.material_texture(m));
        let normal_matrix = Mat3::from_mat4(transform.inverse().transpose());
        let color = o.color.truncate();
        let indices =
            &scene.indices[o.first_index as usize..(o.first_index + o.index_count) as usize];
        for tri in indices.chunks_exact(3) {
            let mut p = [Vec3::ZERO; 3];
            let mut n = [Vec3::ZERO; 3];
            for k in 0..3 {
                let v = &scene.vertices[(o.vertex_offset + tri[k]) as usize];
                p[k] = transform.transform_point3(Vec3::from(v.position));
                n[k] = (normal_matrix * Vec3::from(v.normal)).normalize_or_zero();
                self.bounds.grow(p[k]);
            }
            let corners = [0, 1, 2].map(|k| (o.vertex_offset + tri[k]) as usize);
            let mask = self.masks.for_triangle(scene, index, corners);
            self.masks.push(self.triangles.len(), mask);
            let textured = self.textures.for_triangle(scene, index, corners, |image| {
                mips.chain_from(image, levels_above(image, MAX_EDGE))
            });
            self.textures.push(self.triangles.len(), textured);
            self.triangles.push(p);
            self.normals.push(n);
            self.albedo.push(if scene.has_materials() {
                let corner = |k: usize| (o.vertex_offset + tri[k]) as usize;
                let a = [corner(0), corner(1), corner(2)]
                    .map(|i| scene.attributes.get(i).copied().unwrap_or_default());
                material_albedo(o.color, &a, texture, mips)
            } else {
                color
            });
        }
    }

    /// A copy with only what lies inside `region`: a triangle inside it is kept, one outside
    /// it dropped, one across its faces cut to it (a polygon, fanned into triangles whose
    /// corners, normals and masks are interpolated from the source's). `gi` cuts a ground far
    /// larger than the level ([`Backdrop`](crate::scene::backdrop::Backdrop)) to the region
    /// the level stands in.
    pub fn clipped_to(&self, region: &Aabb) -> WorldGeometry {
        let mut out = self.empty_like();
        for (index, (t, n)) in self.triangles.iter().zip(&self.normals).enumerate() {
            let mut b = Aabb::EMPTY;
            t.iter().for_each(|&p| b.grow(p));
            if !b.overlaps(region) {
                continue;
            }
            let poly = clip_weights(t, region);
            for k in 1..poly.len().saturating_sub(1) {
                let w = [poly[0], poly[k], poly[k + 1]];
                let (p, m) = piece_of(t, n, w);
                if (p[1] - p[0]).cross(p[2] - p[0]).length_squared() <= 0.0 {
                    continue;
                }
                p.iter().for_each(|&q| out.bounds.grow(q));
                out.push_piece(self, index, p, m, w);
            }
        }
        out
    }

    /// No triangles, the masks' and textures' images of `self` (for pieces of its
    /// triangles).
    fn empty_like(&self) -> WorldGeometry {
        WorldGeometry {
            masks: TriangleMasks {
                triangles: Vec::new(),
                images: self.masks.images.clone(),
            },
            textures: TriangleTextures {
                triangles: Vec::new(),
                images: self.textures.images.clone(),
            },
            ..WorldGeometry::empty()
        }
    }

    /// Appends a piece of triangle `index` of `source`: corners `p`, normals `n`, the
    /// source's albedo, and its mask and texture over the piece, whose corners are the weights
    /// `w` of the source's corners.
    fn push_piece(
        &mut self,
        source: &WorldGeometry,
        index: usize,
        p: [Vec3; 3],
        n: [Vec3; 3],
        w: [Vec3; 3],
    ) {
        if source.masks.any() {
            let mask = source.masks.triangles.get(index).copied();
            self.masks
                .triangles
                .push(mask.unwrap_or(TriangleMask::OPAQUE).sub(w));
        }
        self.textures
            .push_piece(self.triangles.len(), &source.textures, index, w);
        self.triangles.push(p);
        self.normals.push(n);
        self.albedo.push(source.albedo[index]);
    }

    /// A copy whose triangles have no edge longer than `max_edge` (longest-edge bisection, at
    /// most 2^12 pieces per triangle). The paraboloid shadow maps interpolate straight edges in a
    /// non-linear projection, so long triangles cast visibly wrong shadows; short ones don't.
    pub fn tessellated(&self, max_edge: f32) -> WorldGeometry {
        self.tessellated_pieces(max_edge).0
    }

    /// [`WorldGeometry::tessellated`], and where each piece lies in the triangle it came
    /// from: the source triangle and the piece's corners as barycentric weights of the
    /// source's corners. [`WorldGeometry::reshaped`] places the same pieces on the source
    /// triangles' new corners (a deformed mesh keeps its split from pose to pose).
    pub fn tessellated_pieces(&self, max_edge: f32) -> (WorldGeometry, Vec<Piece>) {
        let mut pieces = Vec::with_capacity(self.triangles.len());
        let mut out = WorldGeometry {
            bounds: self.bounds,
            ..self.empty_like()
        };
        let max2 = max_edge * max_edge;
        let mut stack = Vec::new();
        for (index, (t, n)) in self.triangles.iter().zip(&self.normals).enumerate() {
            // Corners as barycentric weights of the original triangle (for its mask).
            stack.push((*t, *n, 0u32, [Vec3::X, Vec3::Y, Vec3::Z]));
            while let Some((p, m, depth, w)) = stack.pop() {
                let lens = [
                    p[0].distance_squared(p[1]),
                    p[1].distance_squared(p[2]),
                    p[2].distance_squared(p[0]),
                ];
                let (k, longest) =
                    lens.iter()
                        .copied()
                        .enumerate()
                        .fold(
                            (0, 0.0),
                            |best, (i, l)| if l > best.1 { (i, l) } else { best },
                        );
                if longest <= max2 || depth >= 12 || !longest.is_finite() {
                    out.push_piece(self, index, p, m, w);
                    pieces.push(Piece {
                        source: index as u32,
                        weights: w,
                    });
                    continue;
                }
                // Split edge (k, k+1) at its midpoint; the opposite corner is k+2.
                let (i, j) = (k, (k + 1) % 3);
                let mid = (p[i] + p[j]) * 0.5;
                let mid_n = (m[i] + m[j]).normalize_or(m[i]);
                let mid_w = (w[i] + w[j]) * 0.5;
                let mut first = (p, m, depth + 1, w);
                first.0[j] = mid;
                first.1[j] = mid_n;
                first.3[j] = mid_w;
                let mut second = (p, m, depth + 1, w);
                second.0[i] = mid;
                second.1[i] = mid_n;
                second.3[i] = mid_w;
                stack.push(first);
                stack.push(second);
            }
        }
        (out, pieces)
    }

    /// The pieces `pieces` of this geometry's triangles (as [`WorldGeometry::tessellated_pieces`]
    /// gives them for this geometry, or for one with the same triangles placed or posed
    /// otherwise): corners and normals interpolated from their source's, and its albedo, mask
    /// and texture. Pieces whose source is not a triangle of this geometry are left out.
    pub fn pieces_of(&self, pieces: &[Piece]) -> WorldGeometry {
        let mut out = WorldGeometry {
            bounds: Aabb::EMPTY,
            ..self.empty_like()
        };
        for piece in pieces {
            let s = piece.source as usize;
            let (Some(t), Some(n)) = (self.triangles.get(s), self.normals.get(s)) else {
                continue;
            };
            let (p, m) = piece_of(t, n, piece.weights);
            p.iter().for_each(|&q| out.bounds.grow(q));
            out.push_piece(self, s, p, m, piece.weights);
        }
        out
    }

    /// The pieces `pieces` (from [`WorldGeometry::tessellated_pieces`] of a geometry with the
    /// same triangles) placed on `corners`, the source triangles' new corners, with
    /// normals interpolated from `normals` (theirs); albedo, masks and textures are taken
    /// from `self`, the tessellated geometry at rest. Pieces whose source is not in `corners`
    /// keep their place.
    pub fn reshaped(
        &self,
        pieces: &[Piece],
        corners: &[[Vec3; 3]],
        normals: &[[Vec3; 3]],
    ) -> WorldGeometry {
        let mut out = self.clone();
        out.bounds = Aabb::EMPTY;
        for (k, piece) in pieces.iter().enumerate() {
            let s = piece.source as usize;
            let (Some(p), Some(n), Some(t), Some(m)) = (
                corners.get(s),
                normals.get(s),
                out.triangles.get_mut(k),
                out.normals.get_mut(k),
            ) else {
                continue;
            };
            (*t, *m) = piece_of(p, n, piece.weights);
        }
        for t in &out.triangles {
            for &p in t {
                out.bounds.grow(p);
            }
        }
        out
    }

    /// Appends `other`'s triangles after this one's and grows the bounds.
    pub fn append(&mut self, other: &WorldGeometry) {
        self.masks
            .append(self.triangles.len(), &other.masks, other.triangles.len());
        self.textures
            .append(self.triangles.len(), &other.textures, other.triangles.len());
        self.triangles.extend_from_slice(&other.triangles);
        self.normals.extend_from_slice(&other.normals);
        self.albedo.extend_from_slice(&other.albedo);
        self.bounds = self.bounds.union(&other.bounds);
    }

    /// The CPU ray-casting scene (BVH over the same triangles).
    pub fn ray_scene(&self) -> RayScene {
        let rays = RayScene::new(self.triangles.clone(), self.albedo.clone());
        if self.masks.any() {
            rays.with_masks(self.masks.clone())
        } else {
            rays
        }
    }

    /// Non-indexed GPU vertices, [`VERTEX_FLOATS`] floats each.
    pub fn gpu_vertices(&self) -> Vec<f32> {
        let mut out = Vec::with_capacity(self.triangles.len() * 3 * VERTEX_FLOATS);
        for ((t, n), a) in self.triangles.iter().zip(&self.normals).zip(&self.albedo) {
            for k in 0..3 {
                out.extend_from_slice(&[t[k].x, t[k].y, t[k].z, 1.0]);
                out.extend_from_slice(&[n[k].x, n[k].y, n[k].z, 0.0]);
                out.extend_from_slice(&[a.x, a.y, a.z, 1.0]);
            }
        }
        out
    }

    /// Length of the bounds' diagonal (the scene's scale), at least 1e-3.
    pub fn diagonal(&self) -> f32 {
        if self.bounds.is_valid() {
            self.bounds.extent().length().max(1e-3)
        } else {
            1.0
        }
    }
}

/// For each vertex of `floats` (`stride` floats each), the index of the first vertex whose
/// first `K` floats have the same bits: the index buffer of an indexed draw over the same
/// vertices, where vertices that agree in those floats share an index (the shadow pass keys on
/// the position, the G-buffer on the whole vertex).
pub fn first_identical<const K: usize>(floats: &[f32], stride: usize) -> Vec<u32> {
    let mut indices = Vec::new();
    first_identical_from::<K>(floats, stride, 0, &KeyMap::default(), &mut indices);
    indices
}

/// A map from vertex keys (float bits, not chosen by an adversary), hashed eight bytes a
/// step by the interior cache's [`Words`]: SipHash made re-indexing the moving vertices most
/// of a GI frame's update.
type KeyMap<const K: usize> = HashMap<[u32; K], u32, std::hash::BuildHasherDefault<Words>>;

/// One vertex's key: the bits of its first `K` floats.
fn corner_key<const K: usize>(vertex: &[f32]) -> [u32; K] {
    std::array::from_fn(|k| vertex[k].to_bits())
}

/// [`first_identical`] for the vertices from `first` on, given `prefix`: the key of every
/// vertex before `first`, mapped to the first vertex with that key. `indices` keeps its
/// entries before `first` and gets the rest.
fn first_identical_from<const K: usize>(
    floats: &[f32],
    stride: usize,
    first: usize,
    prefix: &KeyMap<K>,
    indices: &mut Vec<u32>,
) {
    let stride = stride.max(K).max(1);
    let count = floats.len() / stride;
    indices.truncate(first);
    let mut tail =
        KeyMap::<K>::with_capacity_and_hasher(count.saturating_sub(first), Default::default());
    for (i, v) in floats.chunks_exact(stride).enumerate().skip(first) {
        let key = corner_key::<K>(v);
        let index = match prefix.get(&key) {
            Some(&j) => j,
            None => *tail.entry(key).or_insert(i as u32),
        };
        indices.push(index);
    }
}

/// [`first_identical`] kept up to date while vertices from some point on change (the renderer's
/// moving tail): the keys of the unchanged vertices before that point are hashed once, the
/// first time a tail changes, so a change re-hashes only the tail. Until then nothing but the
/// indices is kept (a scene without movers pays no map).
pub(crate) struct CornerIndex<const K: usize> {
    /// Floats per vertex, at least `K` (as [`first_identical`] reads it).
    stride: usize,
    indices: Vec<u32>,
    /// Key of every vertex before `hashed`, to the first vertex with that key.
    prefix: KeyMap<K>,
    hashed: usize,
}

impl<const K: usize> CornerIndex<K> {
    /// The indices of `floats` (`stride` floats per vertex).
    pub(crate) fn new(floats: &[f32], stride: usize) -> Self {
        CornerIndex {
            stride: stride.max(K).max(1),
            indices: first_identical::<K>(floats, stride),
            prefix: KeyMap::default(),
            hashed: 0,
        }
    }

    /// The indices, one per vertex.
    pub(crate) fn indices(&self) -> &[u32] {
        &self.indices
    }

    /// Updates the indices after the vertices from `first` on changed (`floats` is the whole
    /// buffer, the same vertex count as before); returns `first`, the first index that may
    /// have changed: an index depends only on the vertices up to its own.
    pub(crate) fn update(&mut self, floats: &[f32], first: usize) -> usize {
        let stride = self.stride;
        let first = first.min(floats.len() / stride);
        if first < self.hashed {
            // Keys first seen at `first` or later are not in the new prefix.
            self.prefix.retain(|_, &mut i| (i as usize) < first);
        } else {
            for (i, v) in floats
                .chunks_exact(stride)
                .enumerate()
                .take(first)
                .skip(self.hashed)
            {
                self.prefix.entry(corner_key::<K>(v)).or_insert(i as u32);
            }
        }
        self.hashed = first;
        first_identical_from::<K>(floats, stride, first, &self.prefix, &mut self.indices);
        first
    }
}

/// The index buffer of an indexed pass over the GI vertex buffer ([`VERTEX_FLOATS`] floats per
/// vertex): one u32 per corner, pointing at the first vertex whose first `K` floats are
/// bit-identical ([`first_identical`]). The shadow pass keys on the position (`K` = 3), the
/// G-buffer on the whole vertex.
pub(crate) struct SharedCorners<const K: usize> {
    indices: crate::gpu::Buffer,
    corners: CornerIndex<K>,
}

impl<const K: usize> SharedCorners<K> {
    /// A host-visible index buffer for `vertex_floats`' vertices, filled.
    pub(crate) fn new(
        ctx: &std::sync::Arc<crate::gpu::GpuContext>,
        name: &str,
        vertex_floats: &[f32],
    ) -> crate::error::Result<Self> {
        let mut indices = crate::gpu::Buffer::new(
            ctx,
            name,
            (vertex_floats.len() / VERTEX_FLOATS * 4).max(16) as u64,
            ash::vk::BufferUsageFlags::INDEX_BUFFER,
            gpu_allocator::MemoryLocation::CpuToGpu,
        )?;
        let corners = CornerIndex::new(vertex_floats, VERTEX_FLOATS);
        indices.write(0, &crate::gpu::as_bytes(corners.indices()))?;
        Ok(SharedCorners { indices, corners })
    }

    /// Rewrites the indices after the vertices from `first_vertex` on changed (the buffer's
    /// new contents, the same vertex count), e.g. after objects at the buffer's tail moved:
    /// only the indices from `first_vertex` on are recomputed and written.
    pub(crate) fn rewrite(
        &mut self,
        vertex_floats: &[f32],
        first_vertex: usize,
    ) -> crate::error::Result<()> {
        let from = self.corners.update(vertex_floats, first_vertex);
        let changed = &self.corners.indices()[from..];
        self.indices.write(from * 4, &crate::gpu::as_bytes(changed))
    }

    /// The index buffer to bind.
    pub(crate) fn buffer(&self) -> &crate::gpu::Buffer {
        &self.indices
    }
}

/// The point of triangle `t` with barycentric weights `w` of its corners.
fn at_weights(t: &[Vec3; 3], w: Vec3) -> Vec3 {
    t[0] * w.x + t[1] * w.y + t[2] * w.z
}

/// The corners and unit normals of the piece of a triangle (corners `t`, normals `n`) whose
/// corners are the weights `w` of the triangle's (a normal that interpolates to zero takes the
/// first corner's).
fn piece_of(t: &[Vec3; 3], n: &[Vec3; 3], w: [Vec3; 3]) -> ([Vec3; 3], [Vec3; 3]) {
    let p = w.map(|w| at_weights(t, w));
    let m = w.map(|w| at_weights(n, w).normalize_or(n[0]));
    (p, m)
}

/// Triangle `t` cut to `region`, as a convex polygon of barycentric weights of its corners
/// (Sutherland-Hodgman against the box's six planes); empty when nothing is left.
fn clip_weights(t: &[Vec3; 3], region: &Aabb) -> Vec<Vec3> {
    let mut poly = vec![Vec3::X, Vec3::Y, Vec3::Z];
    let at = |w: Vec3| at_weights(t, w);
    for axis in 0..3 {
        for (bound, keep_below) in [(region.min[axis], false), (region.max[axis], true)] {
            // Signed distance inside the plane: >= 0 keeps.
            let inside = |w: Vec3| {
                let d = at(w)[axis] - bound;
                if keep_below {
                    -d
                } else {
                    d
                }
            };
            let mut next = Vec::with_capacity(poly.len() + 1);
            for i in 0..poly.len() {
                let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
                let (da, db) = (inside(a), inside(b));
                if da >= 0.0 {
                    next.push(a);
                }
                if (da >= 0.0) != (db >= 0.0) {
                    next.push(a + (b - a) * (da / (da - db)));
                }
            }
            poly = next;
            if poly.is_empty() {
                return poly;
            }
        }
    }
    poly
}

#[cfg(test)]
mod material_tests {
    use glam::{Mat4, Vec3, Vec4};

    use super::WorldGeometry;
    use crate::scene::{
        Aabb, Material, Object, SamplerDesc, Scene, Texture, TextureImage, Vertex, VertexAttributes,
    };

    fn scene(textured: bool) -> Scene {
        let v = |x: f32, y: f32| Vertex {
            position: [x, y, 0.0],
            normal: [0.0, 0.0, 1.0],
        };
        Scene {
            name: "tri".into(),
            vertices: vec![v(0.0, 0.0), v(1.0, 0.0), v(0.0, 1.0)],
            indices: vec![0, 1, 2],
            objects: vec![Object {
                first_index: 0,
                index_count: 3,
                vertex_offset: 0,
                vertex_count: 3,
                transform: Mat4::IDENTITY,
                color: Vec4::new(1.0, 1.0, 0.5, 1.0),
                bounds: Aabb::new(Vec3::ZERO, Vec3::new(1.0, 1.0, 0.0)),
                material: textured.then_some(0),
            }],
            paths: Vec::new(),
            sun_dir: Vec3::Y,
            attributes: vec![
                VertexAttributes {
                    uv: [0.0, 0.0],
                    color: [255, 128, 255, 255],
                };
                3
            ],
            materials: vec![Material {
                base_color_texture: Some(0),
                ..Default::default()
            }],
            // 2x1: linear red 1.0 and 0.0 (sRGB 255 and 0), sampled nearest at u = 0.25.
            images: vec![TextureImage {
                width: 2,
                height: 1,
                rgba: vec![255, 255, 255, 255, 0, 0, 0, 255],
            }],
            textures: vec![Texture {
                image: 0,
                sampler: SamplerDesc {
                    mag_linear: false,
                    ..SamplerDesc::default()
                },
            }],
            animation: None,
        }
    }

    #[test]
    fn albedo_is_factor_times_vertex_color_times_texture() {
        let mut s = scene(true);
        for a in &mut s.attributes {
            a.uv = [0.25, 0.5];
        }
        let g = WorldGeometry::from_scene(&s);
        let green = 128.0 / 255.0;
        assert!(
            (g.albedo[0] - Vec3::new(1.0, green, 0.5))
                .abs()
                .max_element()
                < 1e-5
        );
        // The texture's black texel.
        for a in &mut s.attributes {
            a.uv = [0.75, 0.5];
        }
        assert_eq!(WorldGeometry::from_scene(&s).albedo[0], Vec3::ZERO);
        // No material: factor x vertex color.
        let g = WorldGeometry::from_scene(&scene(false));
        assert!(
            (g.albedo[0] - Vec3::new(1.0, green, 0.5))
                .abs()
                .max_element()
                < 1e-5
        );
    }

    /// `scene(true)` with a 64x64 checker of white and black texels (sampled nearest) and
    /// its triangle's corners at `uv`.
    fn checker(uv: [[f32; 2]; 3]) -> Scene {
        let mut s = scene(true);
        for (a, uv) in s.attributes.iter_mut().zip(uv) {
            a.uv = uv;
        }
        let rgba = (0..64 * 64)
            .flat_map(|i| {
                let c = if (i % 64 + i / 64) % 2 == 0 { 255 } else { 0 };
                [c, c, c, 255]
            })
            .collect();
        s.images = vec![TextureImage {
            width: 64,
            height: 64,
            rgba,
        }];
        s
    }

    #[test]
    fn a_triangle_over_many_texels_takes_their_mean() {
        // The triangle covers half of the checker once, or of 8x8 repeats of it: its albedo
        // is the checker's mean (linear 0.5), where its corners and centroid read nearest
        // at level 0 gave 0.75 (three white texels and a black one).
        let (o, t) = (0.3 / 64.0, 0.7 / 64.0);
        for scale in [1.0, 8.0] {
            let uv = [[o, t], [o + scale, t], [o, t + scale]];
            let g = WorldGeometry::from_scene(&checker(uv));
            let red = g.albedo[0].x;
            assert!((red - 0.5).abs() < 0.02, "uv x{scale}: {red}");
        }
    }

    #[test]
    fn the_sample_points_cover_the_triangle_evenly() {
        let points = &*super::SUBTRIANGLE_CENTROIDS;
        assert_eq!(points.len(), 16);
        let mean = points.iter().sum::<Vec3>() / points.len() as f32;
        assert!(
            (mean - Vec3::splat(1.0 / 3.0)).abs().max_element() < 1e-6,
            "{mean}"
        );
        for p in points {
            assert!(p.min_element() >= 1.0 / 12.0 - 1e-6, "{p}");
            assert!((p.element_sum() - 1.0).abs() < 1e-6, "{p}");
        }
    }

    #[test]
    fn a_triangle_in_one_chart_of_an_atlas_takes_its_color() {
        // Left half white, right half black; the triangle lies in the left half, its
        // longest side near the middle: its albedo is white, not mixed with the black half
        // (its corners and centroid read at the level of its whole footprint, 4x4, gave
        // 0.685).
        let mut s = checker([[0.02, 0.02], [0.48, 0.02], [0.02, 0.98]]);
        s.images[0].rgba = (0..64 * 64)
            .flat_map(|i| {
                let c = if i % 64 < 32 { 255 } else { 0 };
                [c, c, c, 255]
            })
            .collect();
        let red = WorldGeometry::from_scene(&s).albedo[0].x;
        assert!(red > 0.99, "{red}");
    }

    #[test]
    fn an_image_without_texels_reads_as_white() {
        for (width, height, rgba) in [(0, 5, vec![]), (4, 4, vec![255; 8])] {
            let mut s = checker([[0.0, 0.0], [8.0, 0.0], [0.0, 8.0]]);
            s.images[0] = TextureImage {
                width,
                height,
                rgba,
            };
            let red = WorldGeometry::from_scene(&s).albedo[0].x;
            assert_eq!(red, 1.0, "{width}x{height}");
        }
    }

    #[test]
    fn a_triangle_within_a_texel_takes_that_texel() {
        // A footprint under one texel reads level 0 as the sampler says: nearest, white or
        // black, nothing between.
        let (o, t) = (0.3 / 64.0, 0.7 / 64.0);
        let g = WorldGeometry::from_scene(&checker([[o, t], [o + 0.001, t], [o, t + 0.001]]));
        let red = g.albedo[0].x;
        assert!(red == 1.0 || red == 0.0, "{red}");
    }
}

#[cfg(test)]
mod index_tests {
    use super::{first_identical, CornerIndex, VERTEX_FLOATS};

    #[test]
    fn corners_at_one_position_share_an_index() {
        // Two triangles sharing an edge, and a third apart (positions only).
        let corners = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
            [5.0, 5.0, 5.0],
            [6.0, 5.0, 5.0],
            [5.0, 6.0, 5.0],
        ];
        let floats: Vec<f32> = corners.iter().flatten().copied().collect();
        assert_eq!(
            first_identical::<3>(&floats, 3),
            [0, 1, 2, 1, 4, 2, 6, 7, 8]
        );
        assert!(first_identical::<3>(&[], 3).is_empty());
    }

    #[test]
    fn only_the_key_floats_decide() {
        let mut floats = Vec::new();
        for v in [0.0, 1.0, 0.0, 2.0, 1.0] {
            floats.extend(std::iter::repeat_n(v, VERTEX_FLOATS));
        }
        // The same position with another normal: another vertex by the whole vertex, the
        // same by the position.
        floats[VERTEX_FLOATS * 2 + 4] = 9.0;
        assert_eq!(
            first_identical::<VERTEX_FLOATS>(&floats, VERTEX_FLOATS),
            [0, 1, 2, 3, 1]
        );
        assert_eq!(
            first_identical::<3>(&floats, VERTEX_FLOATS),
            [0, 1, 0, 3, 1]
        );
    }

    #[test]
    fn tail_updates_equal_a_full_rebuild() {
        // 64 vertices of 3 floats drawn from 6 values each, so many keys repeat; then tails
        // from changing points (later, earlier, the same, the end) are overwritten.
        let mut seed = 0x2545_f491_u32;
        let mut next = move || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            seed >> 16
        };
        let mut floats: Vec<f32> = (0..64 * 3).map(|_| (next() % 6) as f32).collect();
        let mut index = CornerIndex::<3>::new(&floats, 3);
        assert_eq!(index.indices(), first_identical::<3>(&floats, 3));
        for first in [40usize, 40, 50, 10, 30, 64, 0, 63] {
            for f in &mut floats[first * 3..] {
                *f = (next() % 6) as f32;
            }
            let before = index.indices()[..first].to_vec();
            assert_eq!(index.update(&floats, first), first);
            assert_eq!(
                index.indices(),
                first_identical::<3>(&floats, 3),
                "tail from {first}"
            );
            assert_eq!(
                index.indices()[..first],
                before[..],
                "prefix before {first} kept"
            );
        }
    }
}

#[cfg(test)]
mod clip_tests {
    use glam::Vec3;

    use super::WorldGeometry;
    use crate::scene::mask::{TriangleMask, TriangleMasks};
    use crate::scene::Aabb;

    /// Twice the area of the triangles of `g`.
    fn area2(g: &WorldGeometry) -> f32 {
        (g.triangles.iter())
            .map(|t| (t[1] - t[0]).cross(t[2] - t[0]).length())
            .sum()
    }

    #[test]
    fn triangles_are_cut_to_the_region_with_their_normals_masks_and_textures() {
        // A ground square 200 wide (two triangles), a small triangle inside the region and
        // one far outside it; the region is 20 wide about the origin.
        let corner = |x: f32, z: f32| Vec3::new(x, 0.0, z);
        let (a, b, c, d) = (
            corner(-100.0, -100.0),
            corner(100.0, -100.0),
            corner(100.0, 100.0),
            corner(-100.0, 100.0),
        );
        let inside = [corner(1.0, 1.0), corner(3.0, 1.0), corner(1.0, 3.0)];
        let outside = [corner(50.0, 50.0), corner(60.0, 50.0), corner(50.0, 60.0)];
        let triangles = vec![[a, c, b], [a, d, c], inside, outside];
        let up = [Vec3::Y; 3];
        let mut g = WorldGeometry {
            normals: vec![up; 4],
            albedo: vec![Vec3::ONE, Vec3::ONE, Vec3::X, Vec3::Z],
            triangles,
            bounds: Aabb::EMPTY,
            masks: TriangleMasks::default(),
            textures: Default::default(),
        };
        for t in g.triangles.clone() {
            t.iter().for_each(|&p| g.bounds.grow(p));
        }
        // The first triangle masked (alpha 0.5 at its corners).
        g.masks.triangles = vec![TriangleMask::OPAQUE; 4];
        g.masks.triangles[0].alpha = [0.5; 3];
        // The second textured, u = x / 200 + 0.5 and v = z / 200 + 0.5 at its corners.
        let uv = |p: Vec3| glam::Vec2::new(p.x / 200.0 + 0.5, p.z / 200.0 + 0.5);
        g.textures.push(0, None);
        g.textures.push(
            1,
            Some(crate::gi::textures::TexturedTriangle {
                image: 0,
                uv: [a, d, c].map(uv),
                ..crate::gi::textures::TexturedTriangle::NONE
            }),
        );
        let region = Aabb {
            min: Vec3::new(-10.0, -5.0, -10.0),
            max: Vec3::new(10.0, 5.0, 10.0),
        };
        let cut = g.clipped_to(&region);
        // The square's 20 x 20 part and the small triangle (area 2), nothing of the far one.
        assert!(
            (area2(&cut) - (2.0 * 400.0 + 4.0)).abs() < 1e-2,
            "{}",
            area2(&cut)
        );
        for t in &cut.triangles {
            for p in t {
                assert!(p.x.abs() <= 10.0 + 1e-4 && p.z.abs() <= 10.0 + 1e-4, "{p}");
            }
        }
        assert!(!cut.albedo.contains(&Vec3::Z));
        assert_eq!(cut.albedo.iter().filter(|&&a| a == Vec3::X).count(), 1);
        assert!(cut
            .normals
            .iter()
            .flatten()
            .all(|n| (*n - Vec3::Y).length() < 1e-6));
        assert_eq!(cut.masks.triangles.len(), cut.triangles.len());
        // The pieces of the masked triangle keep its alpha.
        let half = cut
            .masks
            .triangles
            .iter()
            .filter(|m| m.alpha == [0.5; 3])
            .count();
        assert!(half >= 1, "{:?}", cut.masks.triangles);
        // The pieces of the textured triangle keep its coordinates where they are.
        assert_eq!(cut.textures.triangles.len(), cut.triangles.len());
        let mut textured = 0;
        for (t, tex) in cut.triangles.iter().zip(&cut.textures.triangles) {
            if tex.is_none() {
                continue;
            }
            textured += 1;
            for (p, q) in t.iter().zip(tex.uv) {
                assert!((uv(*p) - q).length() < 1e-5, "{p} {q}");
            }
        }
        assert!(textured >= 1);
        assert!(cut.bounds.min.x >= -10.0 - 1e-4 && cut.bounds.max.z <= 10.0 + 1e-4);
        // A region holding everything keeps every triangle as it is.
        let all = g.clipped_to(&g.bounds);
        assert_eq!(all.triangles, g.triangles);
    }
}
