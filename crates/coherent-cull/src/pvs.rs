//! Potentially visible sets (preprocessing): the space the camera can occupy is cut into view
//! cells (cubes of a grid); each cell stores the objects seen from sample points inside it
//! (built by `app::pvs_build`, which renders ID buffers in six directions). At run time
//! the camera's cell's set is drawn, frustum-culled, with no queries. Sampled, so it can miss
//! objects (`walk --check` measures it); outside every cell it falls back to frustum culling.
//! Moving objects are unknown to it.
//!
//! The cache file: magic `COHPVS01`, the key (scene, scale, settings and object count) as a
//! length-prefixed string, the grid origin and cell size, the cells (grid coordinate and object
//! ids), then an FNV-1a 64 checksum of everything before it. A file that is truncated, corrupt,
//! or made for another key is refused with the reason, never trusted.

use std::collections::HashMap;
use std::sync::Arc;

use glam::Vec3;

use super::{CullStats, Culler, FrameInput, OcclusionBackend};
use crate::error::Result;
use crate::Aabb;

const MAGIC: &[u8; 8] = b"COHPVS01";

/// One view cell: its grid coordinate and the sorted ids of the objects seen from it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ViewCell {
    /// Grid coordinate (cell = origin + coord · cell_size ... + cell_size).
    pub coord: [i32; 3],
    /// Objects visible from the cell's samples, sorted, without repeats.
    pub objects: Vec<u32>,
}

/// The potentially visible sets of a scene.
#[derive(Clone, Debug, PartialEq)]
pub struct Pvs {
    /// What the sets were built for (scene, scale, settings, object count).
    pub key: String,
    /// Objects in the scene.
    pub objects: u32,
    /// Grid origin.
    pub origin: Vec3,
    /// Edge length of a cell.
    pub cell_size: f32,
    /// The view cells.
    pub cells: Vec<ViewCell>,
    lookup: HashMap<[i32; 3], u32>,
}

impl Pvs {
    /// Sets for `cells` of a grid at `origin` with `cell_size`.
    pub fn new(
        key: String,
        objects: u32,
        origin: Vec3,
        cell_size: f32,
        cells: Vec<ViewCell>,
    ) -> Pvs {
        let lookup = cells
            .iter()
            .enumerate()
            .map(|(i, c)| (c.coord, i as u32))
            .collect();
        Pvs {
            key,
            objects,
            origin,
            cell_size,
            cells,
            lookup,
        }
    }

    /// The grid coordinate of the cell containing `p`.
    pub fn coord_of(origin: Vec3, cell_size: f32, p: Vec3) -> [i32; 3] {
        let c = ((p - origin) / cell_size).floor();
        [c.x as i32, c.y as i32, c.z as i32]
    }

    /// The view cell containing `p`, if any.
    pub fn cell_at(&self, p: Vec3) -> Option<u32> {
        if !p.is_finite() {
            return None;
        }
        self.lookup
            .get(&Pvs::coord_of(self.origin, self.cell_size, p))
            .copied()
    }

    /// The box of the cell at `coord`.
    pub fn cell_bounds(origin: Vec3, cell_size: f32, coord: [i32; 3]) -> Aabb {
        let min = origin + Vec3::new(coord[0] as f32, coord[1] as f32, coord[2] as f32) * cell_size;
        Aabb::new(min, min + Vec3::splat(cell_size))
    }

    /// Mean and largest set size.
    pub fn set_sizes(&self) -> (f64, usize) {
        let max = self
            .cells
            .iter()
            .map(|c| c.objects.len())
            .max()
            .unwrap_or(0);
        let sum: usize = self.cells.iter().map(|c| c.objects.len()).sum();
        (sum as f64 / self.cells.len().max(1) as f64, max)
    }

    /// The file's bytes (see the module docs for the format).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::new();
        out.extend_from_slice(MAGIC);
        put_u32(&mut out, self.key.len() as u32);
        out.extend_from_slice(self.key.as_bytes());
        put_u32(&mut out, self.objects);
        for v in self.origin.to_array() {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&self.cell_size.to_le_bytes());
        put_u32(&mut out, self.cells.len() as u32);
        for c in &self.cells {
            for v in c.coord {
                out.extend_from_slice(&v.to_le_bytes());
            }
            put_u32(&mut out, c.objects.len() as u32);
            for &o in &c.objects {
                put_u32(&mut out, o);
            }
        }
        let sum = fnv1a(&out);
        out.extend_from_slice(&sum.to_le_bytes());
        out
    }

    /// Parses a file's bytes; `expected_key` must match the stored key.
    pub fn from_bytes(bytes: &[u8], expected_key: &str) -> std::result::Result<Pvs, String> {
        if bytes.len() < MAGIC.len() + 8 || &bytes[..8] != MAGIC {
            return Err("not a coherent PVS file (bad magic)".into());
        }
        let (body, sum) = bytes.split_at(bytes.len() - 8);
        let stored = u64::from_le_bytes(sum.try_into().map_err(|_| "truncated")?);
        if fnv1a(body) != stored {
            return Err("checksum mismatch (truncated or corrupt)".into());
        }
        let mut r = Reader {
            bytes: body,
            at: MAGIC.len(),
        };
        let key_len = r.u32()? as usize;
        let key = String::from_utf8(r.take(key_len)?.to_vec()).map_err(|_| "key is not UTF-8")?;
        if key != expected_key {
            // Debug-quoted: the stored key is the file's, and may hold line breaks.
            return Err(format!(
                "built for another scene or settings ({key:?}, expected {expected_key:?})"
            ));
        }
        let objects = r.u32()?;
        let origin = Vec3::new(r.f32()?, r.f32()?, r.f32()?);
        let cell_size = r.f32()?;
        if !(origin.is_finite() && cell_size.is_finite() && cell_size > 0.0) {
            return Err("bad grid".into());
        }
        let count = r.u32()? as usize;
        let mut cells = Vec::with_capacity(count.min(body.len() / 16));
        for _ in 0..count {
            let coord = [r.i32()?, r.i32()?, r.i32()?];
            let n = r.u32()? as usize;
            let mut ids = Vec::with_capacity(n.min(body.len() / 4));
            for _ in 0..n {
                let o = r.u32()?;
                if o >= objects {
                    return Err(format!("object {o} out of range ({objects} objects)"));
                }
                ids.push(o);
            }
            cells.push(ViewCell {
                coord,
                objects: ids,
            });
        }
        if r.at != body.len() {
            return Err("trailing bytes".into());
        }
        Ok(Pvs::new(key, objects, origin, cell_size, cells))
    }
}

fn put_u32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_le_bytes());
}

/// FNV-1a, 64 bits.
pub fn fnv1a(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take(&mut self, n: usize) -> std::result::Result<&[u8], String> {
        let end = self.at.checked_add(n).ok_or("truncated")?;
        let s = self.bytes.get(self.at..end).ok_or("truncated")?;
        self.at = end;
        Ok(s)
    }
    fn word(&mut self) -> std::result::Result<[u8; 4], String> {
        let s = self.take(4)?;
        Ok([s[0], s[1], s[2], s[3]])
    }
    fn u32(&mut self) -> std::result::Result<u32, String> {
        self.word().map(u32::from_le_bytes)
    }
    fn i32(&mut self) -> std::result::Result<i32, String> {
        self.word().map(i32::from_le_bytes)
    }
    fn f32(&mut self) -> std::result::Result<f32, String> {
        self.word().map(f32::from_le_bytes)
    }
}

/// The PVS at run time: the camera's cell's set, frustum-culled, no queries.
pub struct PvsCuller {
    pvs: Arc<Pvs>,
    /// Per object: in the current cell's set.
    in_set: Vec<bool>,
    /// The cell `in_set` was filled for (`None`: outside every cell, everything counts).
    current: Option<Option<u32>>,
    /// The frustum traversal and draw (vfc's, with the set as a filter).
    vfc: super::vfc::Vfc,
}

impl PvsCuller {
    /// A culler over `pvs`.
    pub fn new(pvs: Arc<Pvs>) -> PvsCuller {
        PvsCuller {
            in_set: vec![false; pvs.objects as usize],
            pvs,
            current: None,
            vfc: super::vfc::Vfc::default(),
        }
    }

    fn select_cell(&mut self, eye: Vec3) {
        let cell = self.pvs.cell_at(eye);
        if self.current == Some(cell) {
            return;
        }
        match cell {
            Some(c) => {
                self.in_set.fill(false);
                for &o in &self.pvs.cells[c as usize].objects {
                    self.in_set[o as usize] = true;
                }
            }
            None => self.in_set.fill(true),
        }
        self.current = Some(cell);
    }
}

impl Culler for PvsCuller {
    fn name(&self) -> &str {
        "pvs"
    }

    fn cull_frame(
        &mut self,
        input: &FrameInput,
        backend: &mut dyn OcclusionBackend,
    ) -> Result<CullStats> {
        self.select_cell(input.view.eye);
        let in_set = &self.in_set;
        self.vfc.draw_in_frustum(input, backend, |o| {
            in_set.get(o as usize).copied().unwrap_or(true)
        })
    }

    fn reset(&mut self) {
        self.current = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Pvs {
        Pvs::new(
            "scene=test".into(),
            10,
            Vec3::new(-5.0, 0.0, -5.0),
            2.5,
            vec![
                ViewCell {
                    coord: [0, 0, 0],
                    objects: vec![1, 2, 3],
                },
                ViewCell {
                    coord: [1, 0, 0],
                    objects: vec![],
                },
            ],
        )
    }

    #[test]
    fn round_trip_and_lookup() {
        let p = sample();
        let back = Pvs::from_bytes(&p.to_bytes(), "scene=test").unwrap();
        assert_eq!(back, p);
        assert_eq!(p.cell_at(Vec3::new(-4.0, 1.0, -4.0)), Some(0));
        assert_eq!(p.cell_at(Vec3::new(-1.0, 1.0, -4.0)), Some(1));
        assert_eq!(p.cell_at(Vec3::new(10.0, 1.0, -4.0)), None);
        assert_eq!(p.cell_at(Vec3::NAN), None);
        assert_eq!(p.set_sizes(), (1.5, 3));
    }

    #[test]
    fn truncated_corrupt_and_foreign_files_are_refused() {
        let bytes = sample().to_bytes();
        for n in [0, 7, 8, 20, bytes.len() - 1] {
            assert!(Pvs::from_bytes(&bytes[..n], "scene=test").is_err(), "{n}");
        }
        let mut flipped = bytes.clone();
        flipped[30] ^= 0x40;
        assert!(Pvs::from_bytes(&flipped, "scene=test")
            .unwrap_err()
            .contains("checksum"));
        assert!(Pvs::from_bytes(&bytes, "scene=other")
            .unwrap_err()
            .contains("another scene"));
        assert!(Pvs::from_bytes(b"{\"json\": true}..........", "scene=test").is_err());
    }
}
