//! A scene's backdrop: a sky dome or sky box that a level (often one exported from an
//! online viewer) carries around itself, kilometres wide while the level is a few hundred
//! metres, or a ground plate as wide under it. It is real geometry, drawn and culled as any
//! object, but it is not what a user means by the level: framing the orbit around it shows a
//! dot inside a bowl or on a plain, and the interior walk's floor grid, sized by the bounds,
//! gets a few cells over the level.
//!
//! The objects taken for the backdrop are the fewest largest ones (a dome split into chunks
//! is several) that are each at least [`SIZE_RATIO`] times as large (box diagonal) as the box
//! of all the other objects (the moving ones included), and whose boxes together hold that
//! box's plan. Of them, those whose boxes reach over the rest's top are its **sky** when
//! they cover the sky seen from the rest's centre (rays towards [`SKY_RAYS`] directions above
//! the horizon meet them in at least [`SKY_SHARE`] of the directions); the others are its
//! **ground** (a plate or a terrain the level stands on; a dome that leaves the sky open is
//! ground too).
//!
//! What each changes:
//!
//! - the default orbit frames the rest;
//! - the interior walk searches the rest's plan (and a margin around it) for floors; the sky
//!   is left out of its rays (it is what a view of the sky shows), the ground is kept (it may
//!   be the level's floor);
//! - `gi` leaves the sky out (it is not a surface that bounces the spotlight's light).
//!
//! A model without such objects has no backdrop, and everything is as before.

use glam::Vec3;

use super::interior::TriangleScene;
use super::{Aabb, Scene};

/// How many times larger than the rest of the scene each backdrop object is, at least (box
/// diagonals).
pub const SIZE_RATIO: f32 = 8.0;

/// Directions above the horizon (elevations of about 6° to 84°) whose rays from the centre
/// of the rest of the scene must meet the sky.
pub const SKY_RAYS: usize = 64;

/// Share of [`SKY_RAYS`] that must meet the sky.
pub const SKY_SHARE: f32 = 0.9;

/// Most objects a backdrop is made of (the chunks of one dome or box).
const MOST_OBJECTS: usize = 64;

/// The margin around the rest's plan that the interior walk searches too, as a share of the
/// rest's diagonal (the streets around a house standing on a ground plate).
pub const SEARCH_MARGIN: f32 = 0.25;

/// A scene's backdrop, when it has one.
#[derive(Clone, Debug, PartialEq)]
pub struct Backdrop {
    /// Its sky objects (indices into `Scene::objects`), ascending; may be empty.
    pub sky: Vec<usize>,
    /// Its ground objects, ascending; may be empty.
    pub ground: Vec<usize>,
    /// The box of everything else: what the orbit frames.
    pub rest: Aabb,
    /// How many times the backdrop's box diagonal is the rest's.
    pub ratio: f32,
}

impl Backdrop {
    /// Whether object `i` is part of the backdrop's sky.
    pub fn is_sky(&self, i: usize) -> bool {
        self.sky.binary_search(&i).is_ok()
    }

    /// The part of the world the interior walk searches for floors: the rest's box grown by
    /// [`SEARCH_MARGIN`] of its diagonal on every side, within `bounds` (the world's).
    pub fn search_region(&self, bounds: &Aabb) -> Aabb {
        let grown = self
            .rest
            .enlarged(SEARCH_MARGIN * self.rest.extent().length());
        Aabb {
            min: grown.min.max(bounds.min),
            max: grown.max.min(bounds.max),
        }
    }

    /// What the loader says about it, for a scene named `name`.
    pub fn note(&self, name: &str) -> String {
        let what = match (self.sky.len(), self.ground.len()) {
            (s, 0) => format!("{s} object(s) enclose the rest like a sky dome or box"),
            (0, g) => format!("{g} object(s) lie under the rest like a ground"),
            (s, g) => format!(
                "{s} object(s) enclose the rest like a sky dome or box and {g} lie under it \
                 like a ground"
            ),
        };
        format!(
            "scene \"{name}\": {what} ({:.0}x its size): the orbit frames the rest, and the \
             interior walk looks for an inside in it",
            self.ratio
        )
    }
}

/// `scene` without the sky of `backdrop` (its buffers, paths and materials kept).
pub fn without_sky(scene: &Scene, backdrop: &Backdrop) -> Scene {
    let mut out = scene.clone();
    let mut i = 0;
    out.objects.retain(|_| {
        i += 1;
        !backdrop.is_sky(i - 1)
    });
    out
}

/// The backdrop of `scene` (see the module docs), `None` when it has none.
pub fn find(scene: &Scene) -> Option<Backdrop> {
    let n = scene.objects.len();
    if n < 2 {
        return None;
    }
    let diag = |b: &Aabb| b.extent().length();
    if !scene.objects.iter().all(|o| o.bounds.is_valid()) {
        return None;
    }
    // Largest first; ties by index, so the result does not depend on the sort.
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| {
        diag(&scene.objects[b].bounds)
            .total_cmp(&diag(&scene.objects[a].bounds))
            .then(a.cmp(&b))
    });
    // The moving objects stand where they start; they are never part of the backdrop.
    let moving = scene.animation.iter().flat_map(|a| {
        (a.objects.iter().map(|m| m.object.bounds))
            .chain(a.deformed.iter().map(|m| m.object.bounds))
    });
    let moving = moving.fold(Aabb::EMPTY, |b, o| b.union(&o));
    // rest[k]: the box of every object after the largest k, and of the moving ones.
    let mut rest = vec![moving; n + 1];
    for k in (0..n).rev() {
        rest[k] = rest[k + 1].union(&scene.objects[order[k]].bounds);
    }
    let mut top = Aabb::EMPTY;
    for k in 1..=MOST_OBJECTS.min(n - 1) {
        let smallest = &scene.objects[order[k - 1]].bounds;
        top = top.union(smallest);
        let others = rest[k];
        let others_diag = diag(&others);
        if !others.is_valid() || diag(smallest) < SIZE_RATIO * others_diag.max(1e-6) {
            // Sorted largest first: a larger set only adds smaller objects, but its rest
            // is smaller too, so go on.
            continue;
        }
        let holds_plan = top.min.x <= others.min.x
            && top.min.z <= others.min.z
            && top.max.x >= others.max.x
            && top.max.z >= others.max.z;
        if !holds_plan {
            continue;
        }
        let (mut above, mut under): (Vec<usize>, Vec<usize>) = order[..k]
            .iter()
            .partition(|&&i| scene.objects[i].bounds.max.y >= others.max.y);
        above.sort_unstable();
        under.sort_unstable();
        let far = diag(&top);
        let (sky, ground) = if !above.is_empty() && covers_sky(scene, &above, others.center(), far)
        {
            (above, under)
        } else {
            let mut all = [above, under].concat();
            all.sort_unstable();
            (Vec::new(), all)
        };
        return Some(Backdrop {
            sky,
            ground,
            rest: others,
            ratio: far / others_diag.max(1e-6),
        });
    }
    None
}

/// Whether rays from `from` towards [`SKY_RAYS`] directions above the horizon meet the
/// objects `objects` (ascending) in at least [`SKY_SHARE`] of them; `far`: the longest ray.
fn covers_sky(scene: &Scene, objects: &[usize], from: Vec3, far: f32) -> bool {
    let Some(rays) = TriangleScene::of(scene, |i| objects.binary_search(&i).is_ok()) else {
        return false;
    };
    let far = 2.0 * far + 1.0;
    let met = sky_dirs()
        .filter(|&d| rays.hit(from, d, far).is_some())
        .count();
    met as f32 >= SKY_SHARE * SKY_RAYS as f32
}

/// [`SKY_RAYS`] directions spread over the sky: a golden-angle spiral over heights 0.1 to
/// 0.995 (elevations of about 6° to 84°).
fn sky_dirs() -> impl Iterator<Item = Vec3> {
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    (0..SKY_RAYS).map(move |i| {
        let y = 0.1 + 0.895 * (i as f32 + 0.5) / SKY_RAYS as f32;
        let r = (1.0 - y * y).max(0.0).sqrt();
        let a = golden * i as f32;
        Vec3::new(r * a.cos(), y, r * a.sin())
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::scene::mesh::{Mesh, SceneBuilder};

    /// A scene of one object per list of triangles.
    fn scene_of(objects: &[Vec<[Vec3; 3]>]) -> Scene {
        let mut b = SceneBuilder::new("backdrop-test");
        for tris in objects {
            b.add(&Mesh::from_triangles(tris), Vec3::ONE);
        }
        b.finish()
    }

    /// A closed box with fronts facing out, or in (`inward`).
    fn cuboid(min: Vec3, max: Vec3, inward: bool) -> Vec<[Vec3; 3]> {
        let c = |x: usize, y: usize, z: usize| {
            Vec3::new([min.x, max.x][x], [min.y, max.y][y], [min.z, max.z][z])
        };
        // Each face as a quad, counter-clockwise seen from outside.
        let quads = [
            [c(0, 0, 0), c(0, 0, 1), c(0, 1, 1), c(0, 1, 0)],
            [c(1, 0, 0), c(1, 1, 0), c(1, 1, 1), c(1, 0, 1)],
            [c(0, 0, 0), c(1, 0, 0), c(1, 0, 1), c(0, 0, 1)],
            [c(0, 1, 0), c(0, 1, 1), c(1, 1, 1), c(1, 1, 0)],
            [c(0, 0, 0), c(0, 1, 0), c(1, 1, 0), c(1, 0, 0)],
            [c(0, 0, 1), c(1, 0, 1), c(1, 1, 1), c(0, 1, 1)],
        ];
        quads
            .iter()
            .flat_map(|q| {
                let (a, b) = ([q[0], q[1], q[2]], [q[0], q[2], q[3]]);
                if inward {
                    [[a[0], a[2], a[1]], [b[0], b[2], b[1]]]
                } else {
                    [a, b]
                }
            })
            .collect()
    }

    /// A hemisphere of radius `r` about the origin, fronts facing in, in `rings` x `sides`.
    pub(crate) fn dome(r: f32, rings: usize, sides: usize) -> Vec<[Vec3; 3]> {
        let p = |i: usize, j: usize| {
            let e = std::f32::consts::FRAC_PI_2 * i as f32 / rings as f32;
            let a = std::f32::consts::TAU * j as f32 / sides as f32;
            Vec3::new(r * e.cos() * a.cos(), r * e.sin(), r * e.cos() * a.sin())
        };
        let mut out = Vec::new();
        for i in 0..rings {
            for j in 0..sides {
                let (a, b, c, d) = (p(i, j), p(i, j + 1), p(i + 1, j + 1), p(i + 1, j));
                out.push([a, c, b]);
                out.push([a, d, c]);
            }
        }
        out
    }

    /// A small level: a floor and four walls, 20 x 3 x 20 about the origin.
    fn level() -> Vec<Vec<[Vec3; 3]>> {
        vec![
            cuboid(
                Vec3::new(-10.0, -0.2, -10.0),
                Vec3::new(10.0, 0.0, 10.0),
                false,
            ),
            cuboid(
                Vec3::new(-10.0, 0.0, -10.0),
                Vec3::new(10.0, 3.0, -9.5),
                false,
            ),
            cuboid(
                Vec3::new(-10.0, 0.0, 9.5),
                Vec3::new(10.0, 3.0, 10.0),
                false,
            ),
            cuboid(
                Vec3::new(-10.0, 0.0, -9.5),
                Vec3::new(-9.5, 3.0, 9.5),
                false,
            ),
            cuboid(Vec3::new(9.5, 0.0, -9.5), Vec3::new(10.0, 3.0, 9.5), false),
        ]
    }

    #[test]
    fn a_sky_dome_around_a_level_is_its_backdrop() {
        let mut objects = level();
        objects.insert(2, dome(1000.0, 8, 24));
        let scene = scene_of(&objects);
        let found = find(&scene).expect("a backdrop");
        assert_eq!((found.sky.clone(), found.ground.clone()), (vec![2], vec![]));
        assert!(found.ratio > 50.0, "{}", found.ratio);
        assert!((found.rest.max.x - 10.0).abs() < 1e-4 && found.rest.max.y <= 3.0 + 1e-4);
        assert!(found.is_sky(2) && !found.is_sky(0));
        let rest = without_sky(&scene, &found);
        assert_eq!(rest.objects.len(), 5);
        assert_eq!(rest.objects[2].bounds, scene.objects[3].bounds);
        assert_eq!(find(&rest), None);
    }

    #[test]
    fn a_sky_box_split_into_chunks_is_one_backdrop() {
        let mut objects = level();
        let sky = cuboid(Vec3::splat(-800.0), Vec3::splat(800.0), true);
        // Its six sides as three objects of two sides each.
        for pair in sky.chunks(4) {
            objects.push(pair.to_vec());
        }
        let scene = scene_of(&objects);
        let found = find(&scene).expect("a backdrop");
        assert_eq!(found.sky, vec![5, 6, 7]);
        assert!(found.ground.is_empty());
    }

    #[test]
    fn the_built_in_scenes_have_none() {
        for name in crate::scene::procedural::SCENES {
            let scene = crate::scene::procedural::build(name, 1.0).expect("built-in scene");
            assert_eq!(find(&scene), None, "{name}");
        }
    }

    #[test]
    fn a_ground_under_a_level_is_its_ground_and_a_small_dome_is_no_backdrop() {
        // A ground plate 2 km wide under the level: it holds the level's plan, not its sky.
        let mut objects = level();
        objects.push(cuboid(
            Vec3::new(-1000.0, -60.0, -1000.0),
            Vec3::new(1000.0, -0.2, 1000.0),
            false,
        ));
        let found = find(&scene_of(&objects)).expect("a ground");
        assert_eq!((found.sky.clone(), found.ground.clone()), (vec![], vec![5]));
        // The walk searches the level's plan and a quarter of its diagonal around it.
        let bounds = found
            .rest
            .union(&Mesh::from_triangles(&objects[5]).bounds());
        let region = found.search_region(&bounds);
        let grow = SEARCH_MARGIN * found.rest.extent().length();
        assert!((region.max.x - (10.0 + grow)).abs() < 1e-3, "{region:?}");
        assert!((region.min.y - (-0.2 - grow)).abs() < 1e-3, "{region:?}");
        // A ground plate that rises above the level's walls all around (a valley): its box
        // reaches over the level's top, but the sky over the level is open: ground too.
        let mut objects = level();
        objects.push(
            cuboid(
                Vec3::new(-1000.0, -60.0, -1000.0),
                Vec3::new(1000.0, 40.0, 1000.0),
                false,
            )
            .into_iter()
            .filter(|t| t.iter().any(|p| p.y < 0.0))
            .collect(),
        );
        let found = find(&scene_of(&objects)).expect("a ground");
        assert_eq!((found.sky.clone(), found.ground.clone()), (vec![], vec![5]));
        // A sky dome and a ground plate: each for what it is.
        let mut objects = level();
        objects.push(dome(4000.0, 8, 24));
        objects.push(cuboid(
            Vec3::new(-1000.0, -60.0, -1000.0),
            Vec3::new(1000.0, -0.2, 1000.0),
            false,
        ));
        let found = find(&scene_of(&objects)).expect("a backdrop");
        assert_eq!(
            (found.sky.clone(), found.ground.clone()),
            (vec![5], vec![6])
        );
        // A dome only seven times as large as the level (a hall's vault): part of the level.
        let mut objects = level();
        objects.push(dome(70.0, 8, 24));
        assert_eq!(find(&scene_of(&objects)), None);
        // A level alone.
        assert_eq!(find(&scene_of(&level())), None);
    }
}
