//! The automatic interior walk (`--path interior`): floors are surfaces whose front looks up
//! (either side for double-sided materials); a place at eye height over one is inside when the
//! rays from it hit front faces (few level rays escape to the sky, few rays hit back faces);
//! places of neighbouring cells join into a walkable graph (a step height, clearance at the eye
//! and the knees), and the walk tours waypoints spread over its largest connected part, looking
//! down the most open way ahead where the view is not filled by one colour (a bare floor, a
//! wall close ahead); the views between keys are judged every third frame, and a turn that
//! sweeps past such a view gets other looks at its keys. Also the light path that goes with
//! it. Deterministic for a given scene, so the command line keeps it in the cache directory
//! ([`cache`]) and finds it once per scene.

use glam::Vec3;

use super::{CameraPath, CameraPose, Scene};
use crate::Error;

pub mod cache;
pub mod places;
pub mod rays;
pub mod walk;

#[cfg(test)]
mod tests;

pub use cache::Outcome;
pub use places::{Place, Rejections, Scale};
pub use rays::{distance_to_triangle, Hit, Probe, TriangleScene};

/// Name of the interior walk among a scene's paths.
pub const PATH_NAME: &str = "interior";

/// Name of the light path found with the interior walk (see [`light_path`]).
pub const LIGHT_PATH_NAME: &str = "interior-light";

/// Fewest places of the walk's connected part for a model to count as having an inside.
const MIN_PLACES: usize = 4;
/// Least floor area of the walk's connected part, in square eye heights (about 12 m² for a
/// person): less is a pocket inside a prop (a hollow statue, the gap under a table), not a room.
const MIN_AREA: f32 = 4.0;

/// Settings of the interior walk; lengths in scene units, `None` = derived from the scene.
#[derive(Clone, Debug)]
pub struct InteriorParams {
    /// Eye height over the floor (default 1.7 where the floor-to-ceiling heights look like
    /// meters, capped at 60% of their 90th percentile; else 40% of it).
    pub eye_height: Option<f32>,
    /// Least distance from the eye to any geometry (default 15% of the eye height).
    pub margin: Option<f32>,
    /// Most grid cells along the longer horizontal side (cells are at least a fifth of the eye
    /// height).
    pub grid: usize,
    /// Most waypoints of the tour.
    pub waypoints: usize,
    /// Most share of one colour (the sky, or one flat colour of the built-in renderer's) a
    /// view of the walk may have before it looks another way where it can (default 0.3; 1
    /// turns the rule off). See [`walk::look_dirs`].
    pub one_colour_most: f32,
}

impl Default for InteriorParams {
    fn default() -> Self {
        InteriorParams {
            eye_height: None,
            margin: None,
            grid: 256,
            waypoints: 6,
            one_colour_most: 0.3,
        }
    }
}

/// A found walk: the path and what it was found from.
#[derive(Clone, Debug)]
pub struct InteriorWalk {
    /// The camera path.
    pub path: CameraPath,
    /// The lengths used.
    pub scale: Scale,
    /// Places found inside.
    pub places: usize,
    /// Places of the largest connected part (the one walked).
    pub part: usize,
    /// The waypoints' eyes, in tour order.
    pub waypoints: Vec<Vec3>,
}

/// Finds the interior walk over `rays`; `Err` says in one line why there is none.
pub fn find(rays: &TriangleScene, params: &InteriorParams) -> Result<InteriorWalk, String> {
    let scale = places::scale(rays, params.eye_height, params.margin, params.grid);
    find_at(rays, params, &scale).map_err(|why| match small_model_hint(rays, params, &scale) {
        Some(hint) => format!("{why}; {hint}"),
        None => why,
    })
}

/// Below this eye height (in scene units) a model is probably smaller than life size in
/// meters: the renderer's near plane (0.1) is then a large part of a storey.
const SMALL_EYE: f32 = 0.5;

/// Magnifications the hint of [`small_model_hint`] tries, smallest first.
const SCALE_TRIES: [f32; 16] = [
    2.0, 4.0, 5.0, 8.0, 10.0, 16.0, 20.0, 25.0, 32.0, 50.0, 64.0, 100.0, 128.0, 200.0, 500.0,
    1000.0,
];

/// For a level (its plan at least [`LEVEL_PLAN`] eye heights across) whose storeys are far
/// lower than a person in meters, what to do about it; a small object (a helmet) is not told.
/// Magnified by N, the search is the same but for the eye, which stands 1.7 units high where
/// the storeys look like meters (under 30 units): the hint names the smallest N of
/// [`SCALE_TRIES`] whose eye finds an inside here, if one does.
fn small_model_hint(
    rays: &TriangleScene,
    params: &InteriorParams,
    scale: &places::Scale,
) -> Option<String> {
    let e = rays.region.extent();
    let plan = e.x.max(e.z);
    let eye = scale.eye_height;
    if params.eye_height.is_some() || eye >= SMALL_EYE || plan < LEVEL_PLAN * eye {
        return None;
    }
    let said = format!(
        "the eye would stand {eye:.2} units over the floors ({} in a model in meters at life \
         size)",
        places::EYE_METERS
    );
    // Here the eye is 60% of the storeys' height h; magnified by N, the eye is 1.7 when
    // 0.6 h N >= 1.7 and the storeys look like meters while h N <= 30.
    let storey = eye / places::EYE_SHARE_METERS;
    let works = |n: f32| {
        let at = places::EYE_METERS / n;
        at < eye
            && storey * n <= places::METERS_STOREY_MOST
            && find_at(
                rays,
                params,
                &places::Scale {
                    // Magnified by n, the near plane stays 0.1: 0.1 / n here.
                    near: crate::scene::camera::NEAR_PLANE / n,
                    ..places::scale(rays, Some(at), params.margin, params.grid)
                },
            )
            .is_ok()
    };
    Some(match SCALE_TRIES.into_iter().find(|&n| works(n)) {
        Some(n) => format!(
            "{said}; if this is a level modelled smaller than life size, --scale {n} \
             multiplies a glTF file's coordinates by {n} and finds an inside (a prop's is its \
             hollow)"
        ),
        None => format!(
            "{said}; if this is a level modelled smaller than life size, --scale N \
             multiplies a glTF file's coordinates by N"
        ),
    })
}

/// Least width of a model's plan, in eye heights, for [`small_model_hint`] to take it for a
/// level rather than an object.
const LEVEL_PLAN: f32 = 8.0;

/// [`find`] at the scale found.
fn find_at(
    rays: &TriangleScene,
    params: &InteriorParams,
    scale: &places::Scale,
) -> Result<InteriorWalk, String> {
    let scale = *scale;
    let floors = places::floors(rays, scale.cell);
    if floors.is_empty() {
        return Err("no surface faces up".into());
    }
    let (found, why) = places::places(rays, &floors, &scale);
    if found.is_empty() {
        return Err(format!("no place is inside: {why}"));
    }
    let adj = walk::neighbours(rays, &found, &scale);
    let part = walk::largest_component(&adj);
    let area = part.len() as f32 * (scale.cell / scale.eye_height).powi(2);
    if part.len() < MIN_PLACES || area < MIN_AREA {
        return Err(format!(
            "the largest walkable part has {} places, {area:.1} square eye heights (of {} \
             inside; {why})",
            part.len(),
            found.len()
        ));
    }
    let chosen = walk::waypoints(&found, &adj, &part, params.waypoints, &scale);
    let route = walk::tour(&found, &adj, &chosen, scale.eye_height);
    let eyes: Vec<Vec3> = route.iter().map(|&i| found[i].eye).collect();
    let keys = walk::keys_through(rays, &eyes, &scale, params.one_colour_most);
    let waypoints = route
        .iter()
        .filter(|i| chosen.contains(i))
        .map(|&i| found[i].eye)
        .collect();
    Ok(InteriorWalk {
        path: CameraPath {
            name: PATH_NAME.to_string(),
            keys,
        },
        scale,
        places: found.len(),
        part: part.len(),
        waypoints,
    })
}

/// Computes the interior walk of `scene`; an error saying why when it has no inside.
pub fn interior_path(scene: &Scene, params: &InteriorParams) -> Result<CameraPath, Error> {
    let why = match TriangleScene::new(scene) {
        None => "it has no triangles".to_string(),
        Some(rays) => match find(&rays, params) {
            Ok(w) => return Ok(w.path),
            Err(why) => why,
        },
    };
    Err(no_inside(scene, &why))
}

/// [`interior_path`] with the default parameters, through the cache directory `dir` (see
/// [`default_if_enclosed_cached`]): what `--path interior` walks on a scene that does not
/// have the walk yet (a built-in one: the city's takes about 25 s to find).
pub fn interior_path_cached(scene: &Scene, dir: &std::path::Path) -> Result<CameraPath, Error> {
    match cached_outcome(scene, dir) {
        Some((Outcome::Walk { camera, .. }, _)) => Ok(camera),
        Some((Outcome::NoInside(why), _)) => Err(no_inside(scene, &why)),
        None => Err(no_inside(scene, "it has no triangles")),
    }
}

/// The error of a scene without an inside.
fn no_inside(scene: &Scene, why: &str) -> Error {
    Error::Input(format!(
        "scene \"{}\": no inside for an interior walk ({why})",
        scene.name
    ))
}

/// A spot light's path inside, going with the interior walk `path`: it follows the walk a key
/// ahead of the camera, halfway between the eye and the ceiling (at least a third of the eye
/// height above the eye, below the ceiling by the margin) and looks down at the floor ahead.
pub fn light_path(rays: &TriangleScene, path: &CameraPath, scale: &Scale) -> CameraPath {
    let far = rays.bounds.extent().length() * 2.0 + 1.0;
    let n = path.keys.len();
    let keys = (0..n)
        .map(|i| {
            let k = path.keys[(i + 1).min(n.saturating_sub(1))];
            let up = rays
                .hit(k.eye, Vec3::Y, far)
                .map_or(scale.eye_height, |h| h.t);
            let lift = (0.5 * up)
                .max(scale.eye_height / 3.0)
                .min(up - scale.margin)
                .max(0.0);
            let eye = k.eye + Vec3::Y * lift;
            let ahead = (k.target - k.eye)
                .with_y(0.0)
                .try_normalize()
                .unwrap_or(Vec3::NEG_Z);
            let floor = k.eye - Vec3::Y * scale.eye_height;
            CameraPose {
                eye,
                target: floor + ahead * scale.eye_height,
            }
        })
        .collect();
    CameraPath {
        name: LIGHT_PATH_NAME.to_string(),
        keys,
    }
}

/// Makes the interior walk a glTF scene's first (default) path when it has an inside, with
/// the light path that goes with it (unless the file has its own light); the orbit stays
/// available as `default`. Without an inside, one line on stderr says why.
pub fn default_if_enclosed(scene: &mut Scene) {
    if let Some(rays) = TriangleScene::new(scene) {
        let outcome = outcome(&rays, &InteriorParams::default());
        apply(scene, outcome);
    }
}

/// [`default_if_enclosed`] through the cache directory `dir` (see [`cache`]): the walk is read
/// from there when a command found it before for the same scene and code, and kept there
/// when it is found now. `None` for a scene without triangles (nothing to find or keep).
pub fn default_if_enclosed_cached(
    scene: &mut Scene,
    dir: &std::path::Path,
) -> Option<cache::Source> {
    let (outcome, source) = cached_outcome(scene, dir)?;
    apply(scene, outcome);
    Some(source)
}

/// The walk of `scene` with the default parameters and where it came from: read from its file
/// in `dir`, or found now and kept there (a note before the search and one after it say so);
/// `None` for a scene without triangles.
fn cached_outcome(scene: &Scene, dir: &std::path::Path) -> Option<(Outcome, cache::Source)> {
    let params = InteriorParams::default();
    let key = cache::key(scene, &params);
    let mut took = None;
    let found = cache::kept_or_made(
        cache::file(dir, &key),
        |file| cache::load(file, &key),
        || {
            let rays = TriangleScene::new(scene)?;
            eprintln!(
                "note: scene \"{}\": looking for an inside to walk (once: the result is kept in {})",
                scene.name,
                dir.display()
            );
            let start = std::time::Instant::now();
            let outcome = outcome(&rays, &params);
            took = Some(start.elapsed());
            Some(outcome)
        },
        |file, outcome| cache::save(file, &key, outcome),
        ("the interior walk", "finding the interior walk again"),
    );
    if let (Some(took), Some((Outcome::Walk { .. }, cache::Source::Found(kept)))) = (took, &found) {
        eprintln!(
            "note: scene \"{}\": interior walk found in {:.1} s{}",
            scene.name,
            took.as_secs_f32(),
            kept.as_ref()
                .map(|f| format!(", kept in {}", f.display()))
                .unwrap_or_default()
        );
    }
    found
}

/// The walk through `rays` and its light path, or why there is none.
fn outcome(rays: &TriangleScene, params: &InteriorParams) -> Outcome {
    match find(rays, params) {
        Ok(w) => Outcome::Walk {
            light: light_path(rays, &w.path, &w.scale),
            camera: w.path,
        },
        Err(why) => Outcome::NoInside(why),
    }
}

/// Puts the walk first among `scene`'s paths and its light path after them (unless the scene
/// has its own light), or says why there is none.
fn apply(scene: &mut Scene, outcome: Outcome) {
    match outcome {
        Outcome::Walk { camera, light } => {
            if scene.path(super::gltf_ext::LIGHT_PATH).is_err() {
                scene.paths.push(light);
            }
            scene.paths.insert(0, camera);
        }
        Outcome::NoInside(why) => eprintln!(
            "note: scene \"{}\": no inside found ({why}); the default path is the orbit",
            scene.name
        ),
    }
}
