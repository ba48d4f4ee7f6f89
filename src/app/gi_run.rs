//! A GI run: the spotlight moves along a path, each mode (incremental, full recompute) renders
//! every frame, a full recompute with 4x the VPLs is the reference on a few frames, and the
//! results become PNGs, a light-path strip and `summary.json`.

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use glam::Vec3;
use serde::Serialize;

use crate::error::{Error, Result};
use crate::gi::geometry::WorldGeometry;
use crate::gi::ism::IsmOptions;
use crate::gi::light::Spotlight;
use crate::gi::movers::{self, GiMovers, Move};
use crate::gi::renderer::{GiFrame, GiOptions, GiRenderer, MAX_EDGE_FRACTION};
use crate::gi::vpl::VplSet;
use crate::gpu::GpuContext;
use crate::scene::camera::Camera;
use crate::scene::movers::Movers;
use crate::scene::raycast::RayScene;
use crate::scene::{CameraPath, CameraPose, Scene};

/// How VPLs are maintained from frame to frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GiMode {
    /// Incremental instant radiosity: at most B new VPLs (and shadow maps) per frame.
    Incremental,
    /// Keller's instant radiosity: all N VPLs and shadow maps every frame.
    Full,
    /// Imperfect shadow maps (Ritschel et al. 2008): all N VPLs every frame, their maps splatted
    /// from surface points and hole-filled, all rebuilt every frame.
    Ism,
}

impl GiMode {
    /// The mode's name in reports.
    pub fn name(self) -> &'static str {
        match self {
            GiMode::Incremental => "incremental",
            GiMode::Full => "full",
            GiMode::Ism => "ism",
        }
    }

    /// Parses `incremental`, `full`, `ism`, `both` (incremental and full) or `all`.
    pub fn parse_list(s: &str) -> Result<Vec<GiMode>> {
        match s {
            "incremental" => Ok(vec![GiMode::Incremental]),
            "full" => Ok(vec![GiMode::Full]),
            "ism" => Ok(vec![GiMode::Ism]),
            "both" => Ok(vec![GiMode::Incremental, GiMode::Full]),
            "all" => Ok(vec![GiMode::Incremental, GiMode::Full, GiMode::Ism]),
            other => Err(Error::Input(format!(
                "unknown GI mode \"{other}\" (incremental, full, ism, both, all)"
            ))),
        }
    }
}

/// The spotlight's path over a run: an eased sweep between two placements, or keyframes
/// (a light path file, a glTF spot light) when `keys` is set.
#[derive(Clone, Debug)]
pub struct LightPath {
    /// Placement at the first frame.
    pub start: Spotlight,
    /// Placement at the last frame.
    pub end: Spotlight,
    /// Keyframes (eye = light position, target = a point on its axis), played over the run
    /// with `start`'s power; `None` for the sweep.
    pub keys: Option<CameraPath>,
}

impl LightPath {
    /// The light at `t` in 0..=1 (smooth start and stop).
    pub fn at(&self, t: f32) -> Spotlight {
        if let Some(keys) = &self.keys {
            let pose = keys.pose_at(t.clamp(0.0, 1.0) * keys.natural_frames() as f32);
            return Spotlight::new(pose.eye, pose.target - pose.eye, self.start.power);
        }
        let s = 0.5 - 0.5 * (std::f32::consts::PI * t.clamp(0.0, 1.0)).cos();
        Spotlight::new(
            self.start.position.lerp(self.end.position, s),
            self.start
                .direction
                .lerp(self.end.direction, s)
                .normalize_or(Vec3::NEG_Y),
            self.start.power.lerp(self.end.power, s),
        )
    }

    /// The default path of a scene: `cornell` swings a light under the ceiling, `hall` moves one
    /// along the nave looking down and forward, anything else sweeps over its longest
    /// horizontal axis. Power is set so the lit floor is well exposed (about 25 d² for the
    /// distance d the light looks across).
    pub fn for_scene(name: &str, geometry: &WorldGeometry, rays: &RayScene) -> LightPath {
        let b = geometry.bounds;
        let (c, e) = if b.is_valid() {
            (b.center(), b.extent())
        } else {
            (Vec3::ZERO, Vec3::ONE)
        };
        let (p0, d0, p1, d1) = match name {
            "cornell" => (
                Vec3::new(1.4, 5.25, 2.2),
                Vec3::new(-0.45, -1.0, 0.15),
                Vec3::new(4.1, 5.25, 3.2),
                Vec3::new(0.45, -1.0, 0.25),
            ),
            "hall" => (
                Vec3::new(-2.0, 9.0, 4.0),
                Vec3::new(0.1, -1.0, 0.5),
                Vec3::new(2.0, 9.0, 44.0),
                Vec3::new(-0.1, -1.0, 0.5),
            ),
            _ => {
                let axis = if e.x >= e.z {
                    Vec3::X * e.x
                } else {
                    Vec3::Z * e.z
                };
                let mut top = c + Vec3::Y * (0.3 * e.y);
                if rays.inside_solid(top, geometry.diagonal()) {
                    // A closed model (an object, not a room): above it, looking down at it.
                    top = Vec3::new(c.x, b.max.y + 0.5 * e.x.max(e.z), c.z);
                }
                (
                    top - 0.3 * axis,
                    Vec3::NEG_Y + 0.3 * axis.normalize(),
                    top + 0.3 * axis,
                    Vec3::NEG_Y + 0.3 * axis.normalize(),
                )
            }
        };
        let d0 = d0.normalize();
        let reach = rays
            .intersect(p0, d0, f32::INFINITY)
            .map(|h| h.t)
            .unwrap_or(geometry.diagonal() * 0.5);
        let power = Vec3::splat(25.0 * reach * reach);
        LightPath {
            start: Spotlight::new(p0, d0, power),
            end: Spotlight::new(p1, d1.normalize(), power),
            keys: None,
        }
    }

    /// A light moving along keyframes (eye = position, target = a point on the axis), with
    /// the power rule of [`LightPath::for_scene`] at its first key.
    pub fn from_keys(keys: CameraPath, geometry: &WorldGeometry, rays: &RayScene) -> LightPath {
        let first = keys.pose_at(0.0);
        let last = keys.pose_at(keys.natural_frames() as f32);
        let d0 = (first.target - first.eye).normalize_or(Vec3::NEG_Y);
        let reach = rays
            .intersect(first.eye, d0, f32::INFINITY)
            .map(|h| h.t)
            .unwrap_or(geometry.diagonal() * 0.5);
        let power = Vec3::splat(25.0 * reach * reach);
        LightPath {
            start: Spotlight::new(first.eye, d0, power),
            end: Spotlight::new(last.eye, last.target - last.eye, power),
            keys: Some(keys),
        }
    }
}

/// What a run may take from the user instead of the scene's defaults.
#[derive(Clone, Debug, Default)]
pub struct GiSetup {
    /// The camera (default: [`default_camera`]).
    pub camera: Option<CameraPose>,
    /// Light keyframes (default: [`LightPath::for_scene`]).
    pub light_keys: Option<CameraPath>,
    /// Built-in moving objects added to the scene (`--movers N`; 0: none).
    pub movers: usize,
}

/// The camera of a GI run: the scene's first path pose (or a view of the bounds).
pub fn default_camera(scene: &Scene, geometry: &WorldGeometry, aspect: f32) -> Camera {
    let b = geometry.bounds;
    let pose = match scene.default_path() {
        Ok(p) => p.pose_at(0.0),
        Err(_) => {
            let (c, e) = if b.is_valid() {
                (b.center(), b.extent())
            } else {
                (Vec3::ZERO, Vec3::ONE)
            };
            CameraPose {
                eye: c + Vec3::new(0.0, 0.1 * e.y, -0.45 * e.z),
                target: c + Vec3::Z * e.z * 0.2,
            }
        }
    };
    let far = geometry.diagonal() * 2.0 + (pose.eye - b.center()).length();
    Camera::from_pose(pose, aspect, far.max(10.0))
}

/// The path the GI camera walks over a run, in step with the light, when it walks: with no
/// camera and no light keys of the user's, on a scene whose light path was found with its
/// interior walk (an enclosed glTF without a spot light), the camera walks that interior walk
/// and the light goes a key ahead of it. `None`: the camera stands at one pose.
pub fn walking_path<'a>(scene: &'a Scene, setup: &GiSetup) -> Option<&'a CameraPath> {
    if setup.camera.is_some() || setup.light_keys.is_some() {
        return None;
    }
    scene.path(crate::scene::interior::LIGHT_PATH_NAME).ok()?;
    scene.path(crate::scene::interior::PATH_NAME).ok()
}

/// The GI camera over a run: at one pose, or walking a path (see [`walking_path`]).
#[derive(Clone, Debug)]
struct CameraTrack {
    camera: Camera,
    walk: Option<CameraPath>,
}

impl CameraTrack {
    /// The camera at `t` in 0..=1 of the run (the light's `t`).
    fn at(&self, t: f32) -> Camera {
        let mut camera = self.camera;
        if let Some(path) = &self.walk {
            let pose = path.pose_at(t.clamp(0.0, 1.0) * path.natural_frames() as f32);
            (camera.eye, camera.target) = (pose.eye, pose.target);
        }
        camera
    }
}

/// Settings of a run.
#[derive(Clone, Debug)]
pub struct GiRunOptions {
    /// VPLs (N).
    pub vpls: usize,
    /// New VPLs per frame (B).
    pub budget: usize,
    /// Frames per mode.
    pub frames: u32,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Modes to run, in order.
    pub modes: Vec<GiMode>,
    /// Shadow-map resolution.
    pub shadow_size: u32,
    /// Frames compared with the reference (and shown in the strip), spread over the frames
    /// after the first.
    pub sample_frames: u32,
    /// Imperfect shadow map sizes (ism mode).
    pub ism: IsmOptions,
}

/// One mode's summary, in `summary.json`.
#[derive(Clone, Debug, Serialize)]
pub struct ModeSummary {
    /// Median frame time (VPL update + GPU frame), ms.
    pub frame_ms_median: f64,
    /// 95th percentile frame time, ms.
    pub frame_ms_p95: f64,
    /// Median of the VPL update alone, ms.
    pub update_ms_median: f64,
    /// Median VPL shadow maps rendered per frame (imperfect ones in ism mode).
    pub shadow_maps_rendered_median: f64,
    /// Median GPU time of the shadow-map passes, ms (timestamps; in ism mode the spotlight's
    /// map, the splats and the pull-push).
    pub shadow_ms_median: f64,
    /// Median GPU time of the gather, ms (timestamps).
    pub gather_ms_median: f64,
    /// Median GPU time of the half-resolution blur of the gathered light, ms.
    pub blur_ms_median: f64,
    /// Median GPU time of the resolve (upsample, direct light, tone mapping), ms.
    pub resolve_ms_median: f64,
    /// Median GPU time of the G-buffer pass, ms.
    pub gbuffer_ms_median: f64,
    /// N.
    pub vpls: usize,
    /// B.
    pub budget: usize,
    /// Mean RMSE (tone-mapped RGB in 0..1) against the 4N-VPL full-recompute reference over
    /// the summary's `rmse_frames` (frames after the first, where the modes differ); `None`
    /// when no frame was compared (`--samples 0`).
    pub rmse_vs_reference: Option<f64>,
    /// The RMSE at each of `rmse_frames`, in order.
    pub rmse_per_frame: Vec<f64>,
}

/// The report of a run.
#[derive(Clone, Debug, Serialize)]
pub struct GiSummary {
    /// Scene name.
    pub scene: String,
    /// Objects in the scene.
    pub objects: usize,
    /// Triangles in the scene.
    pub triangles: u64,
    /// Device name.
    pub device: String,
    /// "WxH".
    pub size: String,
    /// Frames per mode.
    pub frames: u32,
    /// Moving objects (`--movers`, and those the glTF file's animation moves).
    pub movers: usize,
    /// The glTF file's animation they play (`1 "Walk"`), if any.
    pub animation: Option<String>,
    /// The frames compared with the reference (all after the first, evenly spaced).
    pub rmse_frames: Vec<u32>,
    /// Per mode, in run order.
    #[serde(serialize_with = "ordered")]
    pub algorithms: Vec<(String, ModeSummary)>,
}

fn ordered<S: serde::Serializer>(
    pairs: &[(String, ModeSummary)],
    s: S,
) -> std::result::Result<S::Ok, S::Error> {
    use serde::ser::SerializeMap;
    let mut map = s.serialize_map(Some(pairs.len()))?;
    for (k, v) in pairs {
        map.serialize_entry(k, v)?;
    }
    map.end()
}

impl GiSummary {
    /// A short table for the terminal.
    pub fn table(&self) -> String {
        let animation = match &self.animation {
            Some(a) => format!(", {} movers (glTF animation {a})", self.movers),
            None => String::new(),
        };
        let mut out = format!(
            "{} ({} objects, {} triangles{animation}) on {}, {}, {} frames\n{:<12} {:>10} {:>10} {:>10} {:>10} {:>10} {:>8} {:>6} {:>6} {:>8}\n",
            self.scene,
            self.objects,
            self.triangles,
            self.device,
            self.size,
            self.frames,
            "mode",
            "median ms",
            "p95 ms",
            "update ms",
            "shadow ms",
            "gather ms",
            "maps",
            "N",
            "B",
            "rmse"
        );
        for (name, m) in &self.algorithms {
            out += &format!(
                "{:<12} {:>10.2} {:>10.2} {:>10.2} {:>10.2} {:>10.2} {:>8.1} {:>6} {:>6} {:>8}\n",
                name,
                m.frame_ms_median,
                m.frame_ms_p95,
                m.update_ms_median,
                m.shadow_ms_median,
                m.gather_ms_median,
                m.shadow_maps_rendered_median,
                m.vpls,
                m.budget,
                m.rmse_vs_reference
                    .map_or_else(|| "-".to_string(), |e| format!("{e:.4}"))
            );
        }
        out += &match self.rmse_frames.as_slice() {
            [] => "rmse: no frame compared with the reference (--samples 0)\n".to_string(),
            frames => format!("rmse: mean over frames {frames:?} (frame 0 excluded)\n"),
        };
        out
    }
}

/// Frames sampled for the reference and the strip: `n` evenly spaced over the frames after the
/// first (frame 0 is the same image in every mode, so it would flatter the comparison), the last
/// frame included. A one-frame run samples frame 0.
pub fn sample_frames(frames: u32, n: u32) -> Vec<u32> {
    if frames == 0 || n == 0 {
        return Vec::new();
    }
    if frames == 1 {
        return vec![0];
    }
    let n = n.min(frames - 1);
    let mut v: Vec<u32> = (1..=n)
        .map(|k| 1 + ((k as u64 * (frames - 2) as u64) / n as u64) as u32)
        .collect();
    v.dedup();
    v
}

/// RMSE of two RGBA8 images over RGB in 0..1.
pub fn rmse(a: &[u8], b: &[u8]) -> f64 {
    let mut sum = 0.0;
    let mut n = 0usize;
    for (pa, pb) in a.chunks_exact(4).zip(b.chunks_exact(4)) {
        for k in 0..3 {
            let d = (pa[k] as f64 - pb[k] as f64) / 255.0;
            sum += d * d;
            n += 1;
        }
    }
    if n == 0 {
        0.0
    } else {
        (sum / n as f64).sqrt()
    }
}

/// Percentile `p` in `[0, 1]` of `values` (the report's, interpolated between ranks).
fn percentile(values: &[f64], p: f64) -> f64 {
    crate::app::report::percentile(&mut values.to_vec(), p * 100.0)
}

/// Renders the full-recompute reference with `4 * vpls` VPLs on `frames`.
fn reference_images(
    ctx: &Arc<GpuContext>,
    world: &mut World,
    path: &LightPath,
    camera: &CameraTrack,
    opts: &GiRunOptions,
    frames: &[u32],
    progress: &mut Progress<'_>,
) -> Result<Vec<Vec<u8>>> {
    let n = opts.vpls * 4;
    // The reference renders its VPLs in chunks of what one layered pass may hold.
    let limit = ctx
        .info
        .max_image_array_layers
        .min(ctx.info.max_framebuffer_layers);
    let layers = (n as u32).min(limit.saturating_sub(1)).max(1);
    let mut renderer = world.renderer(
        ctx,
        GiOptions {
            width: opts.width,
            height: opts.height,
            vpl_layers: layers,
            max_vpls: n as u32,
            shadow_size: opts.shadow_size,
        },
        None,
    )?;
    let mut set = VplSet::new(n, n);
    let mut out = Vec::new();
    let mut movers = world.movers.clone();
    for &f in frames {
        let t = f as f32 / (opts.frames.max(2) - 1) as f32;
        let light = path.at(t);
        world.place(movers.as_mut(), f, &mut renderer)?;
        let stats = set.recompute_all(&light, &world.rays);
        renderer.frame(&light, set.vpls(), &stats.new_layers, &camera.at(t))?;
        out.push(renderer.read_output()?);
        progress.step();
    }
    Ok(out)
}

/// The scene as GI sees it: triangles for the renderer, the ray-casting scene, and the movers
/// (their triangles last, from `first_mover` on) when there are any.
struct World {
    geometry: WorldGeometry,
    rays: RayScene,
    /// The movers at frame 0 (each mode and the reference move a copy).
    movers: Option<GiMovers>,
    first_mover: u32,
    /// The scene's objects and triangles, the movers included.
    objects: usize,
    triangles: u64,
}

/// A ground far larger than the level (see [`crate::scene::backdrop`]): its objects and the
/// region `gi` keeps of them.
struct Ground {
    /// Object indices, ascending.
    objects: Vec<usize>,
    region: crate::scene::Aabb,
}

/// The geometry of `scene`'s objects `0..statics`, those of `ground` cut to its region.
fn static_geometry(scene: &Scene, statics: usize, ground: Option<&Ground>) -> WorldGeometry {
    let Some(g) = ground else {
        return WorldGeometry::from_objects(scene, 0..statics);
    };
    let is_ground = |i: &usize| g.objects.binary_search(i).is_ok();
    let mut out = WorldGeometry::from_objects(scene, (0..statics).filter(|i| !is_ground(i)));
    let cut = WorldGeometry::from_objects(scene, (0..statics).filter(is_ground));
    out.append(&cut.clipped_to(&g.region));
    out
}

/// What `gi` takes of `scene` when it has a [backdrop](crate::scene::backdrop): a sky dome or
/// box is sky here, not a surface that bounces the spotlight's light, so it is left out; a
/// ground far larger than the level is cut to the region around it. Left whole, their size
/// would set the shadow maps' range and the splitting of long triangles. A note on stderr
/// says what was done.
fn without_backdrop(scene: &Scene) -> (std::borrow::Cow<'_, Scene>, Option<Ground>) {
    let Some(b) = crate::scene::backdrop::find(scene) else {
        return (std::borrow::Cow::Borrowed(scene), None);
    };
    let scene = if b.sky.is_empty() {
        std::borrow::Cow::Borrowed(scene)
    } else {
        eprintln!(
            "note: scene \"{}\": gi leaves out the {} object(s) that enclose the rest like a \
             sky dome or box",
            scene.name,
            b.sky.len()
        );
        std::borrow::Cow::Owned(crate::scene::backdrop::without_sky(scene, &b))
    };
    let ground = (!b.ground.is_empty()).then(|| {
        eprintln!(
            "note: scene \"{}\": gi cuts the {} object(s) under the rest like a ground to the \
             region around it",
            scene.name,
            b.ground.len()
        );
        Ground {
            // Indices in `scene`, the sky taken out.
            objects: (b.ground.iter())
                .map(|&g| g - b.sky.partition_point(|&s| s < g))
                .collect(),
            region: b.search_region(&scene.bounds()),
        }
    });
    (scene, ground)
}

impl World {
    /// `scene`'s triangles (`ground`'s cut to its region); with `movers` > 0 or objects its
    /// glTF animation moves, the movers are added: the static triangles are split here (as
    /// the renderer would) and the movers' follow, so that they are the last ones in the
    /// renderer's vertex buffer.
    fn new(scene: &Scene, movers: usize, ground: Option<&Ground>) -> World {
        if movers == 0 && scene.animation.is_none() {
            let geometry = static_geometry(scene, scene.objects.len(), ground);
            let rays = geometry.ray_scene();
            return World {
                geometry,
                rays,
                movers: None,
                first_mover: 0,
                objects: scene.objects.len(),
                triangles: scene.triangle_count(),
            };
        }
        let mut scene = scene.clone();
        let statics = scene.objects.len();
        let added = Movers::add(&mut scene, movers);
        let (objects, triangles) = (scene.objects.len(), scene.triangle_count());
        let fixed = static_geometry(&scene, statics, ground);
        let moving = WorldGeometry::from_objects(&scene, statics..scene.objects.len());
        let mut bounds = fixed.bounds.union(&moving.bounds);
        let diagonal = WorldGeometry {
            bounds,
            ..WorldGeometry::empty()
        }
        .diagonal();
        let max_edge = diagonal * MAX_EDGE_FRACTION;
        let gi_movers = GiMovers::new(&scene, added, max_edge);
        let placed = gi_movers.geometry();
        bounds = bounds.union(&placed.bounds);
        let mut rays = fixed.ray_scene();
        rays.set_movers(placed.triangles.clone(), placed.albedo.clone());
        let mut geometry = fixed.tessellated(max_edge);
        geometry.bounds = bounds;
        let first_mover = geometry.triangles.len() as u32;
        geometry.append(&placed);
        World {
            geometry,
            rays,
            movers: Some(gi_movers),
            first_mover,
            objects,
            triangles,
        }
    }

    /// A renderer of this world (with imperfect shadow maps if `ism`), its movers at frame 0.
    fn renderer(
        &mut self,
        ctx: &Arc<GpuContext>,
        options: GiOptions,
        ism: Option<IsmOptions>,
    ) -> Result<GiRenderer> {
        let renderer = match ism {
            Some(o) => GiRenderer::with_ism(ctx, &self.geometry, options, o)?,
            None => GiRenderer::new(ctx, &self.geometry, options)?,
        };
        if let Some(m) = &self.movers {
            if renderer.triangle_count() as usize != self.geometry.triangles.len() {
                return Err(Error::Input(format!(
                    "the renderer split the movers' triangles again ({} triangles of {})",
                    renderer.triangle_count(),
                    self.geometry.triangles.len()
                )));
            }
            let placed = m.geometry();
            self.rays
                .set_movers(placed.triangles.clone(), placed.albedo.clone());
        }
        Ok(renderer)
    }

    /// Puts `movers` at their places of `frame` (the ray scene and `renderer`'s triangles);
    /// returns what moved.
    fn place(
        &mut self,
        movers: Option<&mut GiMovers>,
        frame: u32,
        renderer: &mut GiRenderer,
    ) -> Result<Vec<Move>> {
        let Some(movers) = movers else {
            return Ok(Vec::new());
        };
        let moves = movers.advance(u64::from(frame))?;
        if !moves.is_empty() {
            let placed = movers.geometry();
            renderer.move_triangles(self.first_mover, &placed)?;
            self.rays.set_movers(placed.triangles, placed.albedo);
        }
        Ok(moves)
    }

    /// One frame's VPL update of `mode`; returns the layers whose shadow maps must be
    /// rendered. Incremental: VPLs on moved objects are deleted first, and the maps of kept
    /// VPLs that see a moved object's old or new box are rendered again.
    fn update_vpls(
        &self,
        set: &mut VplSet,
        mode: GiMode,
        light: &Spotlight,
        moves: &[Move],
    ) -> Vec<u32> {
        if mode != GiMode::Incremental {
            return set.recompute_all(light, &self.rays).new_layers;
        }
        let eps = 1e-4 * self.geometry.diagonal();
        if !moves.is_empty() {
            set.remove_where(|v| movers::on_moved_object(v, moves, 10.0 * eps));
        }
        let mut layers = set.update(light, &self.rays).new_layers;
        let stale = movers::stale_layers(set.vpls(), moves, &layers, eps);
        layers.extend(stale);
        layers
    }
}

/// Frames rendered so far out of all a run renders, reported after each.
struct Progress<'a> {
    done: u64,
    total: u64,
    report: &'a mut dyn FnMut(u64, u64),
}

impl Progress<'_> {
    fn step(&mut self) {
        self.done += 1;
        (self.report)(self.done, self.total);
    }
}

/// What a mode produced.
pub struct ModeRun {
    /// The mode.
    pub mode: GiMode,
    /// Per-frame GPU results.
    pub frames: Vec<GiFrame>,
    /// Per-frame VPL update times, ms.
    pub update_ms: Vec<f64>,
    /// The sampled frames' images (RGBA8).
    pub samples: Vec<Vec<u8>>,
    /// The last frame's image.
    pub last: Vec<u8>,
}

/// Runs one mode over all frames.
#[allow(clippy::too_many_arguments)]
fn run_mode(
    ctx: &Arc<GpuContext>,
    world: &mut World,
    path: &LightPath,
    camera: &CameraTrack,
    opts: &GiRunOptions,
    mode: GiMode,
    sampled: &[u32],
    progress: &mut Progress<'_>,
) -> Result<ModeRun> {
    let options = GiOptions {
        width: opts.width,
        height: opts.height,
        vpl_layers: opts.vpls as u32,
        max_vpls: opts.vpls as u32,
        shadow_size: opts.shadow_size,
    };
    let ism = (mode == GiMode::Ism).then_some(opts.ism);
    let mut renderer = world.renderer(ctx, options, ism)?;
    let mut movers = world.movers.clone();
    let mut set = VplSet::new(opts.vpls, opts.budget);
    let mut run = ModeRun {
        mode,
        frames: Vec::new(),
        update_ms: Vec::new(),
        samples: Vec::new(),
        last: Vec::new(),
    };
    for f in 0..opts.frames {
        let t = f as f32 / (opts.frames.max(2) - 1) as f32;
        let light = path.at(t);
        let camera = camera.at(t);
        let start = Instant::now();
        let moves = world.place(movers.as_mut(), f, &mut renderer)?;
        let layers = world.update_vpls(&mut set, mode, &light, &moves);
        let update = start.elapsed().as_secs_f64() * 1e3;
        let frame = renderer.frame(&light, set.vpls(), &layers, &camera)?;
        run.update_ms.push(update);
        run.frames.push(frame);
        let is_last = f + 1 == opts.frames;
        if sampled.contains(&f) || is_last {
            let img = renderer.read_output()?;
            if sampled.contains(&f) {
                run.samples.push(img.clone());
            }
            if is_last {
                run.last = img;
            }
        }
        progress.step();
    }
    Ok(run)
}

/// Runs every mode of `opts` on `scene`, writing PNGs and `summary.json` to `out` if given.
pub fn run(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    opts: &GiRunOptions,
    out: Option<&Path>,
) -> Result<GiSummary> {
    run_with(ctx, scene, opts, out, &GiSetup::default())
}

/// [`run`] with the user's camera and light path where `setup` has them.
pub fn run_with(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    opts: &GiRunOptions,
    out: Option<&Path>,
    setup: &GiSetup,
) -> Result<GiSummary> {
    run_reporting(ctx, scene, opts, out, setup, |_, _| {})
}

/// [`run_with`], calling `progress(done, total)` after each frame rendered: the reference's
/// sampled frames, then every mode's frames.
pub fn run_reporting(
    ctx: &Arc<GpuContext>,
    scene: &Scene,
    opts: &GiRunOptions,
    out: Option<&Path>,
    setup: &GiSetup,
    mut progress: impl FnMut(u64, u64),
) -> Result<GiSummary> {
    if opts.vpls == 0 || opts.frames == 0 {
        return Err(Error::Input(
            "gi needs at least one VPL and one frame".into(),
        ));
    }
    let (scene, ground) = without_backdrop(scene);
    let scene = scene.as_ref();
    let mut world = World::new(scene, setup.movers, ground.as_ref());
    // The user's keys, else the light path found with the interior walk, else the default.
    let found = scene.path(crate::scene::interior::LIGHT_PATH_NAME).ok();
    let path = match setup.light_keys.as_ref().or(found) {
        Some(keys) => LightPath::from_keys(keys.clone(), &world.geometry, &world.rays),
        None => LightPath::for_scene(&scene.name, &world.geometry, &world.rays),
    };
    let aspect = opts.width as f32 / opts.height as f32;
    let mut camera = default_camera(scene, &world.geometry, aspect);
    if let Some(pose) = setup.camera {
        (camera.eye, camera.target) = (pose.eye, pose.target);
    }
    let camera = CameraTrack {
        camera,
        walk: walking_path(scene, setup).cloned(),
    };
    let sampled = sample_frames(opts.frames, opts.sample_frames);
    let total = sampled.len() as u64 + opts.modes.len() as u64 * u64::from(opts.frames);
    let mut progress = Progress {
        done: 0,
        total,
        report: &mut progress,
    };
    let reference = reference_images(
        ctx,
        &mut world,
        &path,
        &camera,
        opts,
        &sampled,
        &mut progress,
    )?;
    if let Some(dir) = out {
        std::fs::create_dir_all(dir)?;
        save_strip(
            &dir.join("reference_strip.png"),
            opts.width,
            opts.height,
            &reference,
        )?;
    }
    let mut summary = GiSummary {
        scene: scene.name.clone(),
        objects: world.objects,
        triangles: world.triangles,
        device: ctx.info.name.clone(),
        size: format!("{}x{}", opts.width, opts.height),
        frames: opts.frames,
        movers: world.movers.as_ref().map_or(0, GiMovers::len),
        animation: world
            .movers
            .as_ref()
            .and_then(GiMovers::animation_label)
            .map(String::from),
        rmse_frames: sampled.clone(),
        algorithms: Vec::new(),
    };
    // The last sampled frame of the reference and of every mode, side by side.
    let mut side_by_side: Vec<Vec<u8>> = reference.last().cloned().into_iter().collect();
    for &mode in &opts.modes {
        let r = run_mode(
            ctx,
            &mut world,
            &path,
            &camera,
            opts,
            mode,
            &sampled,
            &mut progress,
        )?;
        let m = summarize_mode(&r, &reference, opts);
        if let Some(dir) = out {
            save_mode_images(dir, opts, &r)?;
        }
        side_by_side.extend(r.samples.last().cloned());
        summary.algorithms.push((mode.name().to_string(), m));
    }
    if let Some(dir) = out {
        let (w, h) = (opts.width, opts.height);
        save_strip(&dir.join("modes_strip.png"), w, h, &side_by_side)?;
        plot_rmse(&dir.join("rmse.png"), &summary)?;
        let json = serde_json::to_string_pretty(&summary)
            .map_err(|e| Error::Input(format!("summary.json: {e}")))?;
        std::fs::write(dir.join("summary.json"), json)?;
    }
    Ok(summary)
}

/// A mode's medians (frame time with its VPL update, shadow maps per frame) and its mean
/// RMSE against the reference images.
fn summarize_mode(r: &ModeRun, reference: &[Vec<u8>], opts: &GiRunOptions) -> ModeSummary {
    let totals: Vec<f64> = r
        .frames
        .iter()
        .zip(&r.update_ms)
        .map(|(f, u)| f.frame_ms + u)
        .collect();
    let maps: Vec<f64> = r
        .frames
        .iter()
        .map(|f| (f.shadow_maps_rendered + f.ism_maps) as f64)
        .collect();
    let errors: Vec<f64> = r
        .samples
        .iter()
        .zip(reference)
        .map(|(a, b)| rmse(a, b))
        .collect();
    let median_of = |f: fn(&GiFrame) -> f64| {
        let v: Vec<f64> = r.frames.iter().map(f).collect();
        percentile(&v, 0.5)
    };
    ModeSummary {
        frame_ms_median: percentile(&totals, 0.5),
        frame_ms_p95: percentile(&totals, 0.95),
        update_ms_median: percentile(&r.update_ms, 0.5),
        shadow_maps_rendered_median: percentile(&maps, 0.5),
        shadow_ms_median: median_of(|f| f.shadow_ms),
        gather_ms_median: median_of(|f| f.gather_ms),
        blur_ms_median: median_of(|f| f.blur_ms),
        resolve_ms_median: median_of(|f| f.resolve_ms),
        gbuffer_ms_median: median_of(|f| f.gbuffer_ms),
        vpls: opts.vpls,
        budget: if r.mode == GiMode::Incremental {
            opts.budget
        } else {
            opts.vpls
        },
        rmse_vs_reference: (!errors.is_empty())
            .then(|| errors.iter().sum::<f64>() / errors.len() as f64),
        rmse_per_frame: errors,
    }
}

/// `rmse.png`: each mode's RMSE against the reference at the sampled frames.
fn plot_rmse(path: &Path, summary: &GiSummary) -> Result<()> {
    let series: Vec<(String, Vec<(u32, f64)>)> = summary
        .algorithms
        .iter()
        .map(|(name, m)| {
            let pts = summary
                .rmse_frames
                .iter()
                .copied()
                .zip(m.rmse_per_frame.iter().copied())
                .collect();
            (name.clone(), pts)
        })
        .collect();
    let title = format!(
        "{}: RMSE against the 4N reference along the light path",
        summary.scene
    );
    super::report::plot::plot_lines(path, &title, "RMSE (tone-mapped RGB)", &series)
}

/// Writes a mode's last frame (`<mode>.png`) and its sampled frames (`<mode>_strip.png`).
fn save_mode_images(dir: &Path, opts: &GiRunOptions, r: &ModeRun) -> Result<()> {
    crate::image_io::save_rgba_png(
        &dir.join(format!("{}.png", r.mode.name())),
        opts.width,
        opts.height,
        r.last.clone(),
    )?;
    save_strip(
        &dir.join(format!("{}_strip.png", r.mode.name())),
        opts.width,
        opts.height,
        &r.samples,
    )
}

/// Writes images side by side, each downscaled to half size.
pub fn save_strip(path: &Path, width: u32, height: u32, images: &[Vec<u8>]) -> Result<()> {
    if images.is_empty() {
        return Ok(());
    }
    let (w, h) = ((width / 2).max(1), (height / 2).max(1));
    let mut strip = image::RgbaImage::new(w * images.len() as u32, h);
    for (i, px) in images.iter().enumerate() {
        let img = image::RgbaImage::from_raw(width, height, px.clone())
            .ok_or_else(|| Error::Input("pixel buffer does not match the image size".into()))?;
        let small = image::imageops::resize(&img, w, h, image::imageops::FilterType::Triangle);
        image::imageops::replace(&mut strip, &small, (i as u32 * w) as i64, 0);
    }
    strip
        .save(path)
        .map_err(|e| Error::Input(format!("{}: cannot write PNG: {e}", path.display())))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_light_inside_a_closed_solid_is_told_from_one_in_a_room() {
        let cube = crate::scene::mesh::Mesh::cube();
        let triangles: Vec<[Vec3; 3]> = cube
            .indices
            .chunks_exact(3)
            .map(|t| {
                [t[0], t[1], t[2]]
                    .map(|i| Vec3::from_array(cube.vertices[i as usize].position) * 4.0)
            })
            .collect();
        let grey = vec![Vec3::splat(0.5); triangles.len()];
        let solid = RayScene::new(triangles.clone(), grey.clone());
        assert!(solid.inside_solid(Vec3::new(0.3, 0.2, -0.1), 100.0));
        assert!(!solid.inside_solid(Vec3::new(0.0, 5.0, 0.0), 100.0));
        // The same box turned inside out is a room: its walls face the light.
        let room: Vec<[Vec3; 3]> = triangles.iter().map(|t| [t[0], t[2], t[1]]).collect();
        let room = RayScene::new(room, grey);
        assert!(!room.inside_solid(Vec3::new(0.3, 0.2, -0.1), 100.0));
    }

    #[test]
    fn a_walking_camera_follows_its_path_over_the_run_and_a_fixed_one_stands() {
        let pose = |x: f32| CameraPose {
            eye: Vec3::new(x, 1.7, 0.0),
            target: Vec3::new(x, 1.7, -5.0),
        };
        let path = CameraPath {
            name: "interior".into(),
            keys: vec![pose(0.0), pose(3.0), pose(6.0)],
        };
        let camera = Camera::from_pose(pose(-1.0), 16.0 / 9.0, 100.0);
        let walking = CameraTrack {
            camera,
            walk: Some(path),
        };
        let near = |a: Vec3, b: Vec3| (a - b).length() < 1e-4;
        assert!(near(walking.at(0.0).eye, pose(0.0).eye));
        assert!(near(walking.at(0.5).eye, pose(3.0).eye));
        assert!(near(walking.at(1.0).eye, pose(6.0).eye));
        assert!(near(walking.at(1.0).target, pose(6.0).target));
        let standing = CameraTrack { camera, walk: None };
        assert_eq!(standing.at(0.7).eye, pose(-1.0).eye);
    }

    /// With no frame compared (`--samples 0`) a mode has no RMSE, and the table says so
    /// instead of printing a zero; with frames compared it is their mean.
    #[test]
    fn the_rmse_is_absent_when_no_frame_was_compared() {
        let opts = GiRunOptions {
            vpls: 16,
            budget: 4,
            frames: 3,
            width: 2,
            height: 1,
            modes: vec![GiMode::Incremental],
            shadow_size: 8,
            sample_frames: 0,
            ism: IsmOptions::default(),
        };
        let run = |samples: Vec<Vec<u8>>| ModeRun {
            mode: GiMode::Incremental,
            frames: vec![GiFrame::default(); 3],
            update_ms: vec![0.0; 3],
            samples,
            last: Vec::new(),
        };
        let none = summarize_mode(&run(Vec::new()), &[], &opts);
        assert_eq!(none.rmse_vs_reference, None);
        let mut summary = GiSummary {
            scene: "s".into(),
            objects: 1,
            triangles: 1,
            device: "d".into(),
            size: "2x1".into(),
            frames: 3,
            movers: 0,
            animation: None,
            rmse_frames: Vec::new(),
            algorithms: vec![("incremental".into(), none)],
        };
        let table = summary.table();
        assert!(table.contains("no frame compared"), "{table}");
        assert!(!table.contains("0.0000"), "{table}");
        let black = vec![0u8; 8];
        let grey = vec![51u8; 8];
        let some = summarize_mode(
            &run(vec![black.clone(), grey.clone()]),
            &[black.clone(), black],
            &opts,
        );
        let e = some.rmse_vs_reference.expect("two frames compared");
        assert!((e - rmse(&grey, &[0u8; 8]) / 2.0).abs() < 1e-9, "{e}");
        summary.rmse_frames = vec![1, 2];
        summary.algorithms = vec![("incremental".into(), some)];
        assert!(summary.table().contains(&format!("{e:.4}")));
    }
}
