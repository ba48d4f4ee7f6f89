//! Splitting of large objects into spatially coherent chunks: real glTF files hold a few huge
//! meshes, which occlusion culling cannot cull piecewise, so every object over a triangle budget
//! is replaced by chunks from a recursive median split of its triangle centroids.

use std::collections::HashMap;

use glam::Vec3;

use super::{Aabb, Object, Scene, Vertex};

/// Geometry range of one chunk in the scene's shared buffers.
#[derive(Clone, Copy)]
struct ChunkRange {
    first_index: u32,
    index_count: u32,
    vertex_offset: u32,
    vertex_count: u32,
}

/// Replaces every object with more than `max_triangles` triangles by chunks of at most
/// `max_triangles` triangles each, in place of the original object (order is kept).
///
/// Chunks come from a recursive median split of triangle centroids along the longest axis of
/// their bounds. Each chunk gets its own compact vertex range appended to the shared buffers
/// (indices relative to its `vertex_offset`), the original transform and color, and tight world
/// bounds. Instances sharing one geometry range share the chunk geometry too. The original
/// ranges stay in the buffers unreferenced; objects within the budget are untouched.
/// Deterministic; `max_triangles == 0` means "don't split". Objects whose range is invalid, or
/// whose chunks would overflow 32-bit buffer offsets, are left as they are.
pub fn split_large_objects(scene: &mut Scene, max_triangles: u32) {
    if max_triangles == 0 {
        return;
    }
    let old = std::mem::take(&mut scene.objects);
    let mut objects = Vec::with_capacity(old.len());
    // Geometry range (first_index, index_count, vertex_offset, vertex_count) -> its chunks.
    let mut done: HashMap<(u32, u32, u32, u32), Option<Vec<ChunkRange>>> = HashMap::new();
    for obj in old {
        if obj.triangle_count() <= u64::from(max_triangles) {
            objects.push(obj);
            continue;
        }
        let key = (
            obj.first_index,
            obj.index_count,
            obj.vertex_offset,
            obj.vertex_count,
        );
        let chunks = done
            .entry(key)
            .or_insert_with(|| split_geometry(scene, &obj, max_triangles as usize));
        match chunks {
            Some(chunks) => {
                for c in chunks.iter() {
                    let start = c.vertex_offset as usize;
                    let verts = &scene.vertices[start..start + c.vertex_count as usize];
                    let mut bounds = Aabb::EMPTY;
                    for v in verts {
                        bounds.grow(obj.transform.transform_point3(Vec3::from_array(v.position)));
                    }
                    objects.push(Object {
                        first_index: c.first_index,
                        index_count: c.index_count,
                        vertex_offset: c.vertex_offset,
                        vertex_count: c.vertex_count,
                        transform: obj.transform,
                        color: obj.color,
                        bounds,
                        material: obj.material,
                    });
                }
            }
            None => objects.push(obj),
        }
    }
    scene.objects = objects;
}

/// Splits the geometry of `obj` into chunks appended to the scene buffers; `None` when the
/// object's range is invalid or the result would not fit 32-bit offsets (nothing is appended).
fn split_geometry(scene: &mut Scene, obj: &Object, max: usize) -> Option<Vec<ChunkRange>> {
    let first = obj.first_index as usize;
    let count = (obj.index_count as usize / 3) * 3;
    let base = obj.vertex_offset as usize;
    let vcount = obj.vertex_count as usize;
    let tris = scene.indices.get(first..first.checked_add(count)?)?;
    let verts = scene.vertices.get(base..base.checked_add(vcount)?)?;
    if tris.iter().any(|&i| i as usize >= vcount) {
        return None;
    }

    let centroids: Vec<Vec3> = tris
        .chunks_exact(3)
        .map(|t| {
            let p = |i: u32| Vec3::from_array(verts[i as usize].position);
            (p(t[0]) + p(t[1]) + p(t[2])) / 3.0
        })
        .collect();
    let mut order: Vec<u32> = (0..centroids.len() as u32).collect();
    let mut leaves = Vec::new();
    median_split(&mut order, &centroids, max, &mut leaves);

    // Build all chunks locally first so a failure leaves the scene untouched.
    let mut new_vertices: Vec<Vertex> = Vec::new();
    // Source vertex of each new vertex (their material attributes follow them).
    let mut sources: Vec<usize> = Vec::new();
    let mut new_indices: Vec<u32> = Vec::new();
    let mut ranges = Vec::with_capacity(leaves.len());
    let mut remap = vec![u32::MAX; vcount];
    let vertex_base = scene.vertices.len();
    let index_base = scene.indices.len();
    for (start, end) in leaves {
        let chunk_vertex_offset = new_vertices.len();
        let chunk_first_index = new_indices.len();
        let mut used = Vec::new();
        for &t in &order[start..end] {
            for &i in &tris[t as usize * 3..t as usize * 3 + 3] {
                let slot = &mut remap[i as usize];
                if *slot == u32::MAX {
                    *slot = (new_vertices.len() - chunk_vertex_offset) as u32;
                    new_vertices.push(verts[i as usize]);
                    sources.push(base + i as usize);
                    used.push(i);
                }
                new_indices.push(*slot);
            }
        }
        for i in used {
            remap[i as usize] = u32::MAX;
        }
        ranges.push(ChunkRange {
            first_index: u32::try_from(index_base + chunk_first_index).ok()?,
            index_count: u32::try_from(new_indices.len() - chunk_first_index).ok()?,
            vertex_offset: u32::try_from(vertex_base + chunk_vertex_offset).ok()?,
            vertex_count: u32::try_from(new_vertices.len() - chunk_vertex_offset).ok()?,
        });
    }
    u32::try_from(vertex_base + new_vertices.len()).ok()?;
    u32::try_from(index_base + new_indices.len()).ok()?;
    if scene.has_materials() {
        scene
            .attributes
            .resize(scene.vertices.len(), Default::default());
        let copied: Vec<_> = sources.iter().map(|&i| scene.attributes[i]).collect();
        scene.attributes.extend_from_slice(&copied);
    }
    scene.vertices.extend_from_slice(&new_vertices);
    scene.indices.extend_from_slice(&new_indices);
    Some(ranges)
}

/// Recursively median-splits `order` (triangle ids, reordered in place) along the longest axis
/// of the centroid bounds until every part has at most `max` triangles; pushes the parts as
/// `(start, end)` ranges of the top-level `order` in spatial order.
fn median_split(
    order: &mut [u32],
    centroids: &[Vec3],
    max: usize,
    leaves: &mut Vec<(usize, usize)>,
) {
    // Explicit stack of (start, end); the right half is pushed first so leaves come out in order.
    let mut stack = vec![(0usize, order.len())];
    while let Some((start, end)) = stack.pop() {
        if end - start <= max {
            leaves.push((start, end));
            continue;
        }
        let part = &mut order[start..end];
        let mut bounds = Aabb::EMPTY;
        for &t in part.iter() {
            bounds.grow(centroids[t as usize]);
        }
        let e = bounds.extent();
        let axis = if e.x >= e.y && e.x >= e.z {
            0
        } else if e.y >= e.z {
            1
        } else {
            2
        };
        let mid = part.len() / 2;
        // Ties (and NaNs via total_cmp) are broken by triangle id: a total order, so the
        // result is deterministic and both halves are non-empty.
        part.select_nth_unstable_by(mid, |&a, &b| {
            centroids[a as usize][axis]
                .total_cmp(&centroids[b as usize][axis])
                .then(a.cmp(&b))
        });
        stack.push((start + mid, end));
        stack.push((start, start + mid));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Mat4, Vec4};

    /// A scene with one `n` x `n` grid of quads (2 n^2 triangles) in the XZ plane, placed by
    /// `transform`, preceded by one small triangle object.
    fn grid_scene(n: u32, transform: Mat4) -> Scene {
        let mut vertices = vec![
            Vertex {
                position: [0.0; 3],
                normal: [0.0, 1.0, 0.0]
            };
            3
        ];
        vertices[1].position = [1.0, 0.0, 0.0];
        vertices[2].position = [0.0, 0.0, 1.0];
        let mut indices = vec![0, 2, 1];
        let small = Object {
            first_index: 0,
            index_count: 3,
            vertex_offset: 0,
            vertex_count: 3,
            transform: Mat4::IDENTITY,
            color: Vec4::ONE,
            bounds: Aabb::new(Vec3::ZERO, Vec3::new(1.0, 0.0, 1.0)),
            material: None,
        };
        let vertex_offset = vertices.len() as u32;
        let first_index = indices.len() as u32;
        for z in 0..=n {
            for x in 0..=n {
                let position = [x as f32, ((x * 7 + z * 3) % 5) as f32 * 0.1, z as f32];
                vertices.push(Vertex {
                    position,
                    normal: [0.0, 1.0, 0.0],
                });
            }
        }
        for z in 0..n {
            for x in 0..n {
                let i = z * (n + 1) + x;
                indices.extend_from_slice(&[i, i + n + 1, i + 1, i + 1, i + n + 1, i + n + 2]);
            }
        }
        let vertex_count = (n + 1) * (n + 1);
        let mut local = Aabb::EMPTY;
        for v in &vertices[vertex_offset as usize..] {
            local.grow(Vec3::from_array(v.position));
        }
        let big = Object {
            first_index,
            index_count: indices.len() as u32 - first_index,
            vertex_offset,
            vertex_count,
            transform,
            color: Vec4::new(0.5, 0.25, 1.0, 1.0),
            bounds: local.transformed(&transform),
            material: None,
        };
        Scene {
            name: "grid".into(),
            vertices,
            indices,
            objects: vec![small, big],
            paths: Vec::new(),
            sun_dir: Vec3::Y,
            attributes: Vec::new(),
            materials: Vec::new(),
            images: Vec::new(),
            textures: Vec::new(),
            animation: None,
        }
    }

    /// World-space triangles of all objects, sorted, for comparing geometry before and after.
    fn world_triangles(scene: &Scene) -> Vec<[[i64; 3]; 3]> {
        let mut out = Vec::new();
        for o in &scene.objects {
            let idx =
                &scene.indices[o.first_index as usize..(o.first_index + o.index_count) as usize];
            for t in idx.chunks_exact(3) {
                let mut tri = [[0i64; 3]; 3];
                for (k, &i) in t.iter().enumerate() {
                    assert!(i < o.vertex_count, "index out of the object's vertex range");
                    let v = scene.vertices[(o.vertex_offset + i) as usize];
                    let p = o.transform.transform_point3(Vec3::from_array(v.position));
                    tri[k] = [
                        (p.x * 1000.0).round() as i64,
                        (p.y * 1000.0).round() as i64,
                        (p.z * 1000.0).round() as i64,
                    ];
                }
                out.push(tri);
            }
        }
        out.sort();
        out
    }

    #[test]
    fn splits_grid_into_bounded_chunks() {
        let transform =
            Mat4::from_translation(Vec3::new(5.0, 1.0, -3.0)) * Mat4::from_rotation_y(0.7);
        let mut scene = grid_scene(71, transform); // 10082 triangles
        let before = world_triangles(&scene);
        split_large_objects(&mut scene, 1000);
        assert_eq!(world_triangles(&scene), before, "geometry changed");
        let small = &scene.objects[0];
        assert_eq!(
            (small.first_index, small.index_count, small.vertex_offset),
            (0, 3, 0)
        );
        let chunks = &scene.objects[1..];
        assert!(chunks.len() >= 11, "{} chunks", chunks.len());
        let mut total = 0;
        for c in chunks {
            assert!(c.triangle_count() <= 1000 && c.triangle_count() > 0);
            total += c.triangle_count();
            assert_eq!(c.transform, transform);
            assert_eq!(c.color, Vec4::new(0.5, 0.25, 1.0, 1.0));
            // Compact vertex range: every vertex is referenced.
            let idx =
                &scene.indices[c.first_index as usize..(c.first_index + c.index_count) as usize];
            let mut used = vec![false; c.vertex_count as usize];
            for &i in idx {
                used[i as usize] = true;
            }
            assert!(used.iter().all(|&u| u));
            // Bounds cover all of the chunk's vertices.
            for v in &scene.vertices
                [c.vertex_offset as usize..(c.vertex_offset + c.vertex_count) as usize]
            {
                let p = transform.transform_point3(Vec3::from_array(v.position));
                assert!(c.bounds.enlarged(1e-4).contains(p));
            }
        }
        assert_eq!(total, 2 * 71 * 71);
        // Spatial coherence: chunk bounds are much smaller than the whole grid.
        let whole = chunks.iter().fold(Aabb::EMPTY, |b, c| b.union(&c.bounds));
        for c in chunks {
            assert!(c.bounds.surface_area() < whole.surface_area() * 0.3);
        }
    }

    #[test]
    fn deterministic_and_shares_instances() {
        let mut a = grid_scene(40, Mat4::IDENTITY);
        let mut second = a.objects[1].clone();
        second.transform = Mat4::from_translation(Vec3::new(100.0, 0.0, 0.0));
        second.bounds = a.objects[1].bounds.transformed(&second.transform);
        a.objects.push(second);
        let mut b = a.clone();
        split_large_objects(&mut a, 500);
        split_large_objects(&mut b, 500);
        assert_eq!(a.vertices, b.vertices);
        assert_eq!(a.indices, b.indices);
        let n = (a.objects.len() - 1) / 2;
        assert!(n >= 7);
        // The second instance reuses the first instance's chunk geometry.
        for k in 0..n {
            let (p, q) = (&a.objects[1 + k], &a.objects[1 + n + k]);
            assert_eq!(
                (p.first_index, p.vertex_offset),
                (q.first_index, q.vertex_offset)
            );
            assert!(q.bounds.min.x >= 100.0 - 1e-3);
        }
    }

    #[test]
    fn zero_limit_and_small_objects_untouched() {
        let mut scene = grid_scene(10, Mat4::IDENTITY);
        let (vertices, indices) = (scene.vertices.len(), scene.indices.len());
        split_large_objects(&mut scene, 0);
        split_large_objects(&mut scene, 200);
        assert_eq!(scene.objects.len(), 2);
        assert_eq!(
            (scene.vertices.len(), scene.indices.len()),
            (vertices, indices)
        );
    }

    #[test]
    fn degenerate_geometry_still_splits() {
        // All triangles share one centroid: the split falls back to triangle order.
        let mut scene = grid_scene(1, Mat4::IDENTITY);
        let big = scene.objects[1].clone();
        let tri = scene.indices[big.first_index as usize..big.first_index as usize + 3].to_vec();
        let first_index = scene.indices.len() as u32;
        for _ in 0..100 {
            scene.indices.extend_from_slice(&tri);
        }
        scene.objects[1].first_index = first_index;
        scene.objects[1].index_count = 300;
        split_large_objects(&mut scene, 7);
        let chunks = &scene.objects[1..];
        assert_eq!(chunks.iter().map(|c| c.triangle_count()).sum::<u64>(), 100);
        assert!(chunks
            .iter()
            .all(|c| c.triangle_count() <= 7 && c.vertex_count == 3));
    }
}
