//! Checks a camera path before it is used (built-in, found or read from a file): rays cast
//! through a grid over the view of sampled frames say how much of the image is sky and how much
//! is back faces, and rays in all directions whether the camera stands inside geometry. A bad
//! path is reported in one line with its first bad frame and position, not silently rendered.
//!
//! Building the rays' scene is most of the check's time (about 1.3 s for the city, 5 s at
//! `--scale 4` and 16), so the commands keep its verdict in the cache directory
//! ([`warn_if_bad_cached`]): one small JSON file per scene and path,
//! `{"key": "path check v1;code=…;scene=…;path=…", "report": null}` or with the report's line,
//! keyed like the interior walk's files (the same code hash and scene hash, and a hash of the
//! path's keys).

use std::path::{Path, PathBuf};

use glam::Vec3;
use serde_json::{json, Value};

use super::interior::cache::{self, Source};
use super::interior::rays::{sphere_dirs, TriangleScene};
use super::{Aabb, CameraPath, CameraPose, Scene};

/// Vertical field of view the check assumes (the built-in camera's).
const FOV_Y_DEG: f32 = 60.0;
/// Aspect ratio the check assumes.
const ASPECT: f32 = 16.0 / 9.0;
/// Rays across and down the view.
pub const VIEW_RAYS: (usize, usize) = (32, 18);
/// Most frames checked along one path.
const MAX_SAMPLES: u32 = 120;
/// Share of the view above which a frame is "mostly" sky or back faces.
pub const MOSTLY: f32 = 0.5;
/// Share of back faces in all directions above which the camera is inside a solid.
const INSIDE_SOLID: f32 = 0.5;

/// What the camera of one frame sees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameView {
    /// Frame along the path (30 per key).
    pub frame: u32,
    /// The eye.
    pub eye: Vec3,
    /// Share of the view's rays that escape (sky).
    pub sky: f32,
    /// Share of the view's rays that hit back faces.
    pub back: f32,
    /// Share of rays in all directions that hit back faces.
    pub back_around: f32,
    /// Whether geometry is closer to the eye than the near plane (0.1).
    pub clips: bool,
    /// Share of the view in its most common colour: the sky, or one flat colour of the
    /// built-in renderer's (an untextured surface at one angle to the light); textured
    /// surfaces count as many colours. Not a problem by itself (a wall close ahead is one
    /// colour); the interior walk looks elsewhere when it can.
    pub one_colour: f32,
}

impl FrameView {
    /// The problem of this frame, if any: inside geometry, mostly back faces, or mostly sky
    /// (sky counts only for an interior, where it means the camera is outside).
    pub fn problem(&self, interior: bool) -> Option<String> {
        if self.back_around > INSIDE_SOLID || self.clips {
            Some(if self.clips {
                "stands inside geometry (closer than the near plane)".to_string()
            } else {
                format!(
                    "stands inside geometry ({:.0}% of rays around it hit back faces)",
                    100.0 * self.back_around
                )
            })
        } else if self.back > MOSTLY {
            Some(format!("sees {:.0}% back faces", 100.0 * self.back))
        } else if interior && self.sky > MOSTLY {
            Some(format!("sees {:.0}% sky from inside", 100.0 * self.sky))
        } else {
            None
        }
    }
}

/// Unit view directions of a pose through a grid of `nx` x `ny` rays over its image (the
/// built-in camera's field of view, 16:9).
pub fn view_grid(pose: &CameraPose, (nx, ny): (usize, usize)) -> Vec<Vec3> {
    let fwd = (pose.target - pose.eye).normalize_or(Vec3::NEG_Z);
    let right = fwd.cross(Vec3::Y).try_normalize().unwrap_or(Vec3::X);
    let up = right.cross(fwd);
    let h = (0.5 * FOV_Y_DEG.to_radians()).tan();
    let mut out = Vec::with_capacity(nx * ny);
    for j in 0..ny {
        for i in 0..nx {
            let u = ((i as f32 + 0.5) / nx as f32 * 2.0 - 1.0) * h * ASPECT;
            let v = (1.0 - (j as f32 + 0.5) / ny as f32 * 2.0) * h;
            out.push((fwd + right * u + up * v).normalize());
        }
    }
    out
}

/// Ray length that reaches all of `rays` from `eye`.
fn far_from(rays: &TriangleScene, eye: Vec3) -> f32 {
    rays.bounds.extent().length() * 2.0 + (eye - rays.bounds.center()).length()
}

/// Share of the view at `pose` in its most common colour (see [`FrameView::one_colour`]),
/// through a grid of `grid` rays.
pub fn one_colour_at(rays: &TriangleScene, pose: &CameraPose, grid: (usize, usize)) -> f32 {
    one_colour_and_back_at(rays, pose, grid).0
}

/// [`one_colour_at`] and the share of the view that shows back faces.
pub fn one_colour_and_back_at(
    rays: &TriangleScene,
    pose: &CameraPose,
    grid: (usize, usize),
) -> (f32, f32) {
    rays.one_colour_and_back(pose.eye, &view_grid(pose, grid), far_from(rays, pose.eye))
}

/// What the camera at `pose` (frame `frame`) sees.
pub fn view_at(rays: &TriangleScene, pose: &CameraPose, frame: u32) -> FrameView {
    let far = far_from(rays, pose.eye);
    let view = view_grid(pose, VIEW_RAYS);
    let seen = rays.probe(pose.eye, &view, far);
    let around = rays.probe(pose.eye, &sphere_dirs(48), far);
    FrameView {
        frame,
        eye: pose.eye,
        sky: seen.escaped_share(),
        back: seen.back_share(),
        back_around: around.back_share(),
        clips: rays.within(pose.eye, crate::scene::camera::NEAR_PLANE),
        one_colour: rays.one_colour_share(pose.eye, &view, far),
    }
}

/// The views of frames spread over `path` (every frame up to `MAX_SAMPLES` of them).
pub fn views(rays: &TriangleScene, path: &CameraPath) -> Vec<FrameView> {
    let frames = path.natural_frames();
    let samples = (frames + 1).min(MAX_SAMPLES);
    (0..samples)
        .map(|i| {
            let f = if samples <= 1 {
                0
            } else {
                (i as u64 * frames as u64 / (samples - 1) as u64) as u32
            };
            view_at(rays, &path.pose_at(f as f32), f)
        })
        .collect()
}

/// The one-line report of `path`'s bad frames, `None` when none is bad. `interior`: the camera
/// is meant to be inside (sky then counts as a problem).
pub fn report(path: &CameraPath, views: &[FrameView], interior: bool) -> Option<String> {
    let bad: Vec<(&FrameView, String)> = views
        .iter()
        .filter_map(|v| v.problem(interior).map(|p| (v, p)))
        .collect();
    let (first, what) = bad.first()?;
    Some(format!(
        "path \"{}\": {} of {} checked frames look wrong; frame {} at ({:.2}, {:.2}, {:.2}) {}",
        path.name,
        bad.len(),
        views.len(),
        first.frame,
        first.eye.x,
        first.eye.y,
        first.eye.z,
        what
    ))
}

/// Scenes with more triangles than this are checked against the geometry near the path only
/// ([`warn_if_bad`]).
pub const LOCAL_CHECK_TRIANGLES: u64 = 4_000_000;

/// The region a path is checked in on a large scene: the box of its keys' eyes and targets,
/// grown on every side by its own diagonal (at least 1).
pub fn local_region(path: &CameraPath) -> Aabb {
    let mut b = Aabb::EMPTY;
    for k in &path.keys {
        b.grow(k.eye);
        b.grow(k.target);
    }
    b.enlarged(b.extent().length().max(1.0))
}

/// Checks `path` on `scene` and prints the one-line report as a warning when frames are bad.
/// Sky counts as a problem on the interior walk only. On a scene of more than
/// [`LOCAL_CHECK_TRIANGLES`] triangles (the city at `--scale 16` has 49 million) the rays meet
/// only the objects in [`local_region`]: geometry farther away counts as sky, so the check then
/// sees more sky and fewer distant back faces than there are, and building the ray scene takes
/// seconds instead of a minute and gigabytes.
pub fn warn_if_bad(scene: &Scene, path: &CameraPath) {
    if let Some(line) = check(scene, path) {
        eprintln!("warning: {line}");
    }
}

/// The one-line report of `path` on `scene` ([`report`]), `None` when no checked frame is bad
/// or the scene has no triangles.
pub fn check(scene: &Scene, path: &CameraPath) -> Option<String> {
    let region = (scene.triangle_count() > LOCAL_CHECK_TRIANGLES).then(|| local_region(path));
    let rays = TriangleScene::shape(scene, region.as_ref())?;
    let interior = path.name == super::interior::PATH_NAME;
    report(path, &views(&rays, path), interior)
}

/// [`warn_if_bad`], with the verdict read from (or kept in) the cache directory `dir`: the
/// same warning, if any, without building the rays' scene again. A cache file that cannot be
/// used is replaced, with one line on stderr saying why; a directory that cannot be written
/// costs only the time. Returns where the verdict came from.
pub fn warn_if_bad_cached(scene: &Scene, path: &CameraPath, dir: &Path) -> Source {
    let key = cache_key(scene, path);
    let (report, source) = cache::kept_or_made(
        cache_file(dir, &key),
        |file| load_verdict(file, &key),
        || Some(check(scene, path)),
        |file, report| save_verdict(file, &key, report.as_deref()),
        ("the path check", "checking the path again"),
    )
    .expect("a check always has a verdict");
    if let Some(line) = report {
        eprintln!("warning: {line}");
    }
    source
}

/// Longest report a cache file may hold.
const MAX_REPORT: usize = 4096;

/// The cache key of the check of `path` on `scene`: the code, the scene and the path.
pub fn cache_key(scene: &Scene, path: &CameraPath) -> String {
    use cache::{path_hash, scene_hash, CODE_HASH};
    format!(
        "path check v1;code={CODE_HASH:016x};scene={:016x};path={:016x}",
        scene_hash(scene),
        path_hash(path)
    )
}

/// The cache file of `key` in `dir`.
pub fn cache_file(dir: &Path, key: &str) -> PathBuf {
    dir.join(format!(
        "pathcheck-{:016x}.json",
        crate::culling::pvs::fnv1a(key.as_bytes())
    ))
}

/// The verdict kept for `key` in `file`: `Ok(None)` when there is no file, `Ok(Some(report))`
/// (the report's line, or `None` for a good path) when there is one made for `key`, an error
/// saying why when it exists but cannot be used.
pub fn load_verdict(file: &Path, key: &str) -> crate::Result<Option<Option<String>>> {
    cache::load_with(file, key, parse_verdict)
}

/// The verdict in a cache file's `text`, made for `key`.
pub fn parse_verdict(text: &str, key: &str) -> Result<Option<String>, String> {
    let v: Value = serde_json::from_str(text).map_err(|e| format!("not JSON: {e}"))?;
    match v.get("key").and_then(Value::as_str) {
        Some(k) if k == key => {}
        Some(_) => return Err("made for another scene, path or version".into()),
        None => return Err("no \"key\" string".into()),
    }
    match v.get("report") {
        Some(Value::Null) => Ok(None),
        Some(Value::String(line)) if line.len() <= MAX_REPORT && !line.contains('\n') => {
            Ok(Some(line.clone()))
        }
        Some(_) => Err("\"report\" is neither null nor one short line".into()),
        None => Err("no \"report\"".into()),
    }
}

/// Writes the verdict `report` for `key` to `file` (through a temporary file).
pub fn save_verdict(file: &Path, key: &str, report: Option<&str>) -> std::io::Result<()> {
    cache::write_whole(file, &verdict_json(key, report))
}

/// The text of the cache file of the verdict `report` for `key`.
pub fn verdict_json(key: &str, report: Option<&str>) -> String {
    json!({ "key": key, "report": report }).to_string()
}
