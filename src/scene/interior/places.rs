//! Where a camera may stand: floors (surfaces whose front looks up) under a grid of columns,
//! the scene's scale from the headroom over them, and eye-height places that are inside (rays
//! from them hit front faces: few level rays escape, few rays hit back faces) and clear of
//! geometry. Only level rays count for the sky: a roofless level (a block-out, a courtyard)
//! is inside where its walls surround the eye, whatever is above.

use glam::Vec3;

use super::rays::{ring_dirs, sphere_dirs, Hit, Probe, TriangleScene};

/// Least `normal.y` of a floor (about 45°: ramps and stairs' treads count, walls do not).
pub const FLOOR_MIN_UP: f32 = 0.7;
/// Most share of a place's level rays (around it, at most 12° up) that may escape the model
/// (sky): more is outside.
pub const MAX_ESCAPED: f32 = 0.25;
/// Most share of a place's rays that may hit back faces: more is inside a solid or outside a
/// shell that is only meant to be seen from within.
pub const MAX_BACK: f32 = 0.125;
/// Directions of the full probe of a candidate place (back faces).
const PROBE_RAYS: usize = 48;
/// Level directions of a candidate place (sky); every fourth is the quick first look.
const RING_RAYS: usize = 32;
/// Percentile of the floor-to-ceiling heights that sets the scale: high, so that low surfaces
/// (tables, shelves, the space under stairs) do not pull it down.
const HEIGHT_PERCENTILE: f32 = 0.9;
/// Least share of the floor columns under a ceiling for the ceilings to set the scale; fewer
/// is a roofless level, whose storey height the walls' tops give.
const ROOFED_SHARE: f32 = 0.25;
/// Standard eye height in meters.
pub(super) const EYE_METERS: f32 = 1.7;
/// Highest storey (the floor-to-ceiling percentile) taken for meters; above it the units are
/// smaller (centimetres, inches).
pub(super) const METERS_STOREY_MOST: f32 = 30.0;
/// The eye's height as a share of the storey where the storey is lower than an eye in
/// meters would need.
pub(super) const EYE_SHARE_METERS: f32 = 0.6;
/// Most surfaces followed down one column.
const MAX_LAYERS: usize = 64;

/// Lengths of the walk in scene units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scale {
    /// Eye height over the floor.
    pub eye_height: f32,
    /// Least distance from the eye (and the knees) to geometry.
    pub margin: f32,
    /// Side of a grid cell.
    pub cell: f32,
    /// Most height between the floors of neighbouring cells (stairs, ramps).
    pub step: f32,
    /// The camera's near plane ([`NEAR_PLANE`](crate::scene::camera::NEAR_PLANE) at the
    /// model's size): an eye closer than this to geometry sees through it.
    pub near: f32,
}

/// A floor under a grid column: its cell, height and the free height above it.
#[derive(Clone, Copy, Debug)]
pub struct Floor {
    /// Grid cell (x, z).
    pub cell: (i32, i32),
    /// The floor point.
    pub point: Vec3,
    /// Free height above the floor (infinite when nothing is above).
    pub headroom: f32,
    /// Whether what is above is a ceiling: a side meant to be seen from below.
    pub ceiling: bool,
}

/// Whether a downward ray's hit is a floor: a side that is meant to be seen, looking up.
pub fn is_floor(h: &Hit) -> bool {
    h.front && h.normal.y >= FLOOR_MIN_UP
}

/// Whether probes say their point is inside: few of the `level` rays escape, few of the
/// `around` rays hit back faces.
pub fn is_inside(level: &Probe, around: &Probe) -> bool {
    level.escaped_share() <= MAX_ESCAPED && around.back_share() <= MAX_BACK
}

/// The grid over the search region's horizontal extent with cells of side `cell`: (columns
/// along x, along z).
fn grid_size(rays: &TriangleScene, cell: f32) -> (i32, i32) {
    let e = rays.region.extent();
    (
        (e.x / cell).ceil().clamp(1.0, 4096.0) as i32,
        (e.z / cell).ceil().clamp(1.0, 4096.0) as i32,
    )
}

/// Every floor under the centers of a grid of `cell`-sized columns, top to bottom per column.
pub fn floors(rays: &TriangleScene, cell: f32) -> Vec<Floor> {
    let (b, r) = (rays.bounds, rays.region);
    let (nx, nz) = grid_size(rays, cell);
    let far = b.extent().length() + 1.0;
    let eps = 1e-5 * far;
    // Each row of columns on the machine's cores, the rows in order.
    let rows = crate::parallel::map(nz as usize, |iz| {
        let iz = iz as i32;
        let mut out = Vec::new();
        for ix in 0..nx {
            let x = r.min.x + (ix as f32 + 0.5) * cell;
            let z = r.min.z + (iz as f32 + 0.5) * cell;
            let mut origin = Vec3::new(x, b.max.y + 1.0, z);
            for _ in 0..MAX_LAYERS {
                let Some(h) = rays.hit(origin, Vec3::NEG_Y, far) else {
                    break;
                };
                let point = origin - Vec3::Y * h.t;
                origin = point - Vec3::Y * eps;
                if !is_floor(&h) {
                    continue;
                }
                let up = rays.hit(point + Vec3::Y * eps, Vec3::Y, far);
                out.push(Floor {
                    cell: (ix, iz),
                    point,
                    headroom: up.map_or(f32::INFINITY, |u| u.t),
                    ceiling: up.is_some_and(|u| u.front),
                });
            }
        }
        out
    });
    let out: Vec<Floor> = rows.into_iter().flatten().collect();
    out
}

/// The scene's scale. `h` is a high percentile of the floor-to-ceiling heights (under front
/// faces); where under a quarter of the floors have a ceiling and `h` is lower than an eye
/// height in meters, at least the median height of the scene's top over the floors (a
/// roofless house: the ceilings found are its tables). Where `h` says the units are meters (at
/// most 30) the eye is at 1.7, capped at 60% of `h`; in other units at 40% of `h`. `eye_height`
/// and `margin` override; `grid` is the most cells along the longer side.
pub fn scale(
    rays: &TriangleScene,
    eye_height: Option<f32>,
    margin: Option<f32>,
    grid: usize,
) -> Scale {
    let e = rays.region.extent();
    let side = e.x.max(e.z).max(1e-3);
    let eye = eye_height
        .filter(|h| h.is_finite() && *h > 0.0)
        .unwrap_or_else(|| {
            let found = floors(rays, side / 64.0);
            let mut heights: Vec<f32> = found
                .iter()
                .filter(|f| f.ceiling)
                .map(|f| f.headroom)
                .filter(|h| h.is_finite() && *h > 0.0)
                .collect();
            heights.sort_by(f32::total_cmp);
            let at = ((heights.len() as f32 * HEIGHT_PERCENTILE) as usize)
                .min(heights.len().saturating_sub(1));
            let mut h = heights.get(at).copied().unwrap_or(e.y.max(1e-3));
            if h < EYE_METERS && (heights.len() as f32) < ROOFED_SHARE * found.len() as f32 {
                // Roofless, and the few ceilings are lower than a person in meters: they are
                // the undersides of furniture (tables). The walls' tops above the floors tell
                // the storey.
                let mut tops: Vec<f32> = found
                    .iter()
                    .map(|f| rays.region.max.y - f.point.y)
                    .collect();
                tops.sort_by(f32::total_cmp);
                h = h.max(tops.get(tops.len() / 2).copied().unwrap_or(h));
            }
            if h <= METERS_STOREY_MOST {
                (EYE_SHARE_METERS * h).min(EYE_METERS)
            } else {
                0.4 * h
            }
        });
    let margin = margin
        .filter(|m| m.is_finite() && *m > 0.0)
        .unwrap_or(0.15 * eye)
        .min(0.45 * eye);
    let cell = (side / grid.max(4) as f32).max(0.2 * eye);
    Scale {
        eye_height: eye,
        margin,
        cell,
        step: 0.35 * eye,
        near: crate::scene::camera::NEAR_PLANE,
    }
}

/// One walkable place: a grid cell, its floor, the eye over it and how open it is.
#[derive(Clone, Copy, Debug)]
pub struct Place {
    /// Grid cell (x, z).
    pub cell: (i32, i32),
    /// The floor point under the eye.
    pub floor: Vec3,
    /// The eye.
    pub eye: Vec3,
    /// Mean distance of the level rays that hit a front face (escaping rays do not count).
    pub openness: f32,
    /// Distance of the nearest level hit: how far the closest wall is.
    pub nearest: f32,
}

/// Why floors were not places, for the line that says why a model has no inside.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Rejections {
    /// Floors seen (front faces looking up).
    pub floors: usize,
    /// Too little headroom for the eye.
    pub low: usize,
    /// Eye too close to geometry.
    pub cramped: usize,
    /// Too many rays escaped.
    pub sky: usize,
    /// Too many rays hit back faces.
    pub back: usize,
}

impl std::fmt::Display for Rejections {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} floor places: {} see sky (over {:.0}% of their level rays), {} see back faces \
             (over {:.1}%), {} lack headroom, {} are too close to geometry",
            self.floors,
            self.sky,
            100.0 * MAX_ESCAPED,
            self.back,
            100.0 * MAX_BACK,
            self.low,
            self.cramped
        )
    }
}

/// What [`places`] makes of one floor.
enum Verdict {
    Low,
    Cramped,
    Sky,
    Back,
    Place(Place),
}

/// The places over `floors`, and why the others were rejected.
pub fn places(rays: &TriangleScene, floors: &[Floor], s: &Scale) -> (Vec<Place>, Rejections) {
    let far = rays.bounds.extent().length() * 2.0 + 1.0;
    let dirs = sphere_dirs(PROBE_RAYS);
    let ring = ring_dirs(RING_RAYS);
    let quick: Vec<Vec3> = ring.iter().step_by(4).copied().collect();
    // Each floor is judged on its own, on the machine's cores.
    let verdicts = crate::parallel::map(floors.len(), |i| {
        let f = &floors[i];
        if f.headroom < s.eye_height + s.margin {
            return Verdict::Low;
        }
        let eye = f.point + Vec3::Y * s.eye_height;
        // Closer to geometry than the camera's near plane, the eye would see through it (the
        // inside of a small closed model, a can, is such a place everywhere).
        if rays.within(eye, s.margin.max(s.near)) {
            return Verdict::Cramped;
        }
        // A few level rays first: most outside places are told apart by them alone.
        let first = rays.probe(eye, &quick, far);
        if first.escaped * 2 >= first.rays {
            return Verdict::Sky;
        }
        let level = rays.probe(eye, &ring, far);
        if level.escaped_share() > MAX_ESCAPED {
            return Verdict::Sky;
        }
        let around = rays.probe(eye, &dirs, far);
        if !is_inside(&level, &around) {
            return Verdict::Back;
        }
        Verdict::Place(Place {
            cell: f.cell,
            floor: f.point,
            eye,
            openness: level.mean_front_distance,
            nearest: level.nearest,
        })
    });
    let mut why = Rejections {
        floors: floors.len(),
        ..Rejections::default()
    };
    let mut out = Vec::new();
    for v in verdicts {
        match v {
            Verdict::Low => why.low += 1,
            Verdict::Cramped => why.cramped += 1,
            Verdict::Sky => why.sky += 1,
            Verdict::Back => why.back += 1,
            Verdict::Place(p) => out.push(p),
        }
    }
    (out, why)
}
