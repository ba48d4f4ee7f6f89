//! Device calibration for cost-driven culling (NOHC): measures, with the renderer's own
//! pipelines and submit path, what a draw call, a triangle, a shaded fragment, an occlusion
//! query (and a pixel of its box fill) and a segment round trip cost on this device, and keeps
//! the result in the user's cache directory, one file per device, driver and Vulkan version.
//!
//! Each figure is a difference of median frame times over a synthetic scene (tiny cubes for
//! draws, dense spheres far away for triangles, full-screen quads drawn back to front for
//! fragments, boxes for queries), divided by what was added. A difference lost in the noise is
//! measured again with more repetitions; if it still is not positive it is reported as not
//! measurable and set to the smallest positive figure (printed, never hidden).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{Mat4, Vec3};

use crate::bvh::ObjectBvh;
use crate::culling::{CostModel, CullStats, Culler, FrameInput, OcclusionBackend, QueryId};
use crate::error::{Error, Result};
use crate::gpu::GpuContext;
use crate::render::Renderer;
use crate::scene::camera::Camera;
use crate::scene::mesh::{Mesh, SceneBuilder};
use crate::scene::{Aabb, CameraPose, Scene};

/// Format name and version in the cache file.
const FORMAT: &str = "coherent-calibration";
const VERSION: u32 = 1;
/// Render size of the calibration frames.
const SIZE: (u32, u32) = (640, 360);
const TINY: u32 = 1024;
const SPHERES: u32 = 4;
const QUADS: u32 = 8;

/// A calibration as stored: the device it was measured on and its costs.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Calibration {
    /// Always "coherent-calibration".
    pub format: String,
    /// Format version.
    pub version: u32,
    /// Device name.
    pub device: String,
    /// Driver name and version.
    pub driver: String,
    /// Vulkan version of the device.
    pub api_version: String,
    /// The measured costs.
    pub costs: CostModel,
    /// Figures that were not measurable above the noise (set to the smallest positive value).
    pub unmeasurable: Vec<String>,
}

impl Calibration {
    /// The costs as a table (milliseconds and microseconds).
    pub fn table(&self) -> String {
        let c = &self.costs;
        let rows = [
            ("draw call", c.draw_ms, "per draw"),
            ("triangle", c.triangle_ms, "per triangle"),
            ("shaded fragment", c.fragment_ms, "per pixel"),
            (
                "occlusion query",
                c.query_ms,
                "per query (small box, read back)",
            ),
            ("query box fill", c.query_fragment_ms, "per box pixel"),
            (
                "segment round trip",
                c.round_trip_ms,
                "submit, signal, wait, read",
            ),
        ];
        let mut out = format!(
            "calibration: {} ({}, Vulkan {})\n{:<20} {:>14}  {}\n",
            self.device, self.driver, self.api_version, "operation", "cost (us)", "unit"
        );
        for (name, ms, unit) in rows {
            out.push_str(&format!("{name:<20} {:>14.6}  {unit}\n", ms * 1e3));
        }
        if !self.unmeasurable.is_empty() {
            out.push_str(&format!(
                "not measurable above the noise (set to the smallest positive figure): {}\n",
                self.unmeasurable.join(", ")
            ));
        }
        out
    }

    fn matches_device(
        &self,
        device: &str,
        driver: &str,
        api_version: &str,
    ) -> std::result::Result<(), String> {
        if self.format != FORMAT || self.version != VERSION {
            // The file's strings are Debug-quoted: they may hold line breaks.
            return Err(format!("format {:?} v{}", self.format, self.version));
        }
        if self.device != device || self.driver != driver || self.api_version != api_version {
            return Err(format!(
                "made for {:?} ({:?}, Vulkan {:?})",
                self.device, self.driver, self.api_version
            ));
        }
        if !self.costs.is_valid() {
            return Err("costs are not all positive and finite".into());
        }
        Ok(())
    }
}

/// Where a calibration came from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Source {
    /// Read from the cache file.
    Cache,
    /// Measured now; `replaced` says why an existing file was not used.
    Measured {
        /// The reason an existing cache file was replaced.
        replaced: Option<String>,
    },
}

/// The user's cache directory for coherent: `$XDG_CACHE_HOME/coherent`, else
/// `$HOME/.cache/coherent`, else a folder in the system's temp directory.
pub fn default_cache_dir() -> PathBuf {
    let base = std::env::var_os("XDG_CACHE_HOME")
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .or_else(|| {
            std::env::var_os("HOME")
                .filter(|v| !v.is_empty())
                .map(|h| PathBuf::from(h).join(".cache"))
        })
        .unwrap_or_else(std::env::temp_dir);
    base.join("coherent")
}

/// The calibration file of this device in `dir`.
pub fn cache_file(dir: &Path, ctx: &GpuContext) -> PathBuf {
    let id = format!(
        "{}|{}|{}",
        ctx.info.name, ctx.info.driver, ctx.info.api_version
    );
    dir.join(format!(
        "calibration-{:016x}.json",
        crate::culling::pvs::fnv1a(id.as_bytes())
    ))
}

/// The device's calibration from `dir`, or a new one (stored there) when there is none, it
/// cannot be read, was made for another device, driver or version, or `force` is set.
pub fn load_or_calibrate(
    ctx: &Arc<GpuContext>,
    dir: &Path,
    force: bool,
) -> Result<(Calibration, Source)> {
    let path = cache_file(dir, ctx);
    let replaced = if force {
        Some("recalibration requested".to_owned())
    } else {
        match read_cache(&path, ctx) {
            Ok(Some(c)) => return Ok((c, Source::Cache)),
            Ok(None) => None,
            Err(why) => Some(why),
        }
    };
    if let Some(why) = &replaced {
        eprintln!(
            "calibration: {} not used ({why}): measuring again",
            path.display()
        );
    }
    let cal = calibrate(ctx)?;
    std::fs::create_dir_all(dir)?;
    let text = serde_json::to_string_pretty(&cal)
        .map_err(|e| Error::Input(format!("calibration encoding: {e}")))?;
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, text)?;
    std::fs::rename(&tmp, &path)?;
    Ok((cal, Source::Measured { replaced }))
}

/// `Ok(None)`: no file. `Err(reason)`: a file that can't be trusted.
fn read_cache(path: &Path, ctx: &GpuContext) -> std::result::Result<Option<Calibration>, String> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(format!("unreadable: {e}")),
    };
    parse_cache(
        &text,
        &ctx.info.name,
        &ctx.info.driver,
        &ctx.info.api_version,
    )
    .map(Some)
}

/// A calibration cache file's text checked as `load_or_calibrate` checks it: JSON of a
/// [`Calibration`] of this format and version, made for this device, driver and Vulkan
/// version, with all costs positive and finite. `Err` says why it cannot be trusted.
pub fn parse_cache(
    text: &str,
    device: &str,
    driver: &str,
    api_version: &str,
) -> std::result::Result<Calibration, String> {
    let cal: Calibration = serde_json::from_str(text).map_err(|e| format!("corrupt: {e}"))?;
    cal.matches_device(device, driver, api_version)
        .map_err(|why| format!("foreign or invalid: {why}"))?;
    Ok(cal)
}

/// Measures the device's costs (a few seconds on lavapipe).
pub fn calibrate(ctx: &Arc<GpuContext>) -> Result<Calibration> {
    let scene = calibration_scene();
    let bvh = scene.hierarchy(1);
    let mut bench = Bench {
        renderer: Renderer::new(ctx, &scene, SIZE.0, SIZE.1)?,
        bvh,
        unmeasurable: Vec::new(),
    };
    let costs = bench.measure_all(&scene)?;
    Ok(Calibration {
        format: FORMAT.into(),
        version: VERSION,
        device: ctx.info.name.clone(),
        driver: ctx.info.driver.clone(),
        api_version: ctx.info.api_version.clone(),
        costs,
        unmeasurable: bench.unmeasurable,
    })
}

/// Object ranges of the calibration scene: `TINY` tiny cubes, then `SPHERES` dense spheres,
/// then `QUADS` full-screen quads from far to near.
fn calibration_scene() -> Scene {
    let mut b = SceneBuilder::new("calibration");
    let cube = b.proto(&Mesh::cube());
    for i in 0..TINY {
        let (x, y) = ((i % 64) as f32 - 32.0, (i / 64) as f32 - 8.0);
        let t = Mat4::from_translation(Vec3::new(x * 1.2, y * 1.2, -80.0))
            * Mat4::from_scale(Vec3::splat(0.08));
        b.instance(cube, t, Vec3::ONE);
    }
    let sphere = b.proto(&Mesh::sphere(128, 64));
    for i in 0..SPHERES {
        let t = Mat4::from_translation(Vec3::new(i as f32 * 3.0 - 4.5, 0.0, -90.0))
            * Mat4::from_scale(Vec3::splat(0.3));
        b.instance(sphere, t, Vec3::ONE);
    }
    for i in 0..QUADS {
        let z = -10.0 + i as f32;
        let t = Mat4::from_translation(Vec3::new(0.0, 0.0, z))
            * Mat4::from_scale(Vec3::new(60.0, 40.0, 0.01));
        b.instance(cube, t, Vec3::new(0.5, 0.5, 0.5));
    }
    b.path(
        "default",
        &[(Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.0, 0.0, -1.0))],
    );
    b.finish()
}

/// One scripted step of a calibration frame.
#[derive(Clone, Debug)]
enum Step {
    Draw(Vec<u32>),
    Query(Aabb),
    /// Submit, then wait for the last query (a round trip).
    Sync,
}

/// A culler that plays a fixed script through the backend.
struct Script(Vec<Step>);

impl Culler for Script {
    fn name(&self) -> &str {
        "calibration"
    }
    fn cull_frame(
        &mut self,
        _: &FrameInput,
        backend: &mut dyn OcclusionBackend,
    ) -> coherent_cull::Result<CullStats> {
        let mut queries: Vec<QueryId> = Vec::new();
        for step in &self.0 {
            match step {
                Step::Draw(objects) => backend.draw_objects(objects)?,
                Step::Query(b) => queries.push(backend.issue_query(std::slice::from_ref(b))?),
                Step::Sync => {
                    backend.flush()?;
                    if let Some(&q) = queries.last() {
                        backend.wait_query(q)?;
                    }
                }
            }
        }
        backend.finish()?;
        for q in queries {
            backend.wait_query(q)?;
        }
        Ok(CullStats::default())
    }
    fn reset(&mut self) {}
}

struct Bench {
    renderer: Renderer,
    bvh: ObjectBvh,
    unmeasurable: Vec<String>,
}

impl Bench {
    /// Median frame time of `steps` over `runs` runs (after one warm-up run).
    fn time(&mut self, steps: &[Step], runs: usize) -> Result<f64> {
        let camera = Camera::from_pose(
            CameraPose {
                eye: Vec3::ZERO,
                target: Vec3::new(0.0, 0.0, -1.0),
            },
            SIZE.0 as f32 / SIZE.1 as f32,
            200.0,
        );
        let mut script = Script(steps.to_vec());
        let mut times = Vec::with_capacity(runs);
        for i in 0..=runs {
            let r = self
                .renderer
                .render_frame(&mut script, &self.bvh, &camera, i as u64)?;
            if i > 0 {
                times.push(r.frame_ms);
            }
        }
        Ok(super::report::median(&mut times))
    }

    /// `(time(with) − time(base)) / units`, measured again with more runs while it is not
    /// positive; the smallest positive figure (and a note) if it never is.
    fn per_unit(
        &mut self,
        name: &str,
        base: &[Step],
        with: &[Step],
        extra_ms: f64,
        units: f64,
    ) -> Result<f64> {
        for runs in [7, 15, 31] {
            let t0 = self.time(base, runs)?;
            let t1 = self.time(with, runs)?;
            let v = (t1 - t0 - extra_ms) / units;
            if v.is_finite() && v > 0.0 {
                return Ok(v);
            }
        }
        self.unmeasurable.push(name.to_owned());
        Ok(f64::MIN_POSITIVE)
    }

    fn measure_all(&mut self, scene: &Scene) -> Result<CostModel> {
        let pixels = f64::from(SIZE.0) * f64::from(SIZE.1);
        let base = vec![Step::Draw(vec![0])];
        let draws = vec![Step::Draw((0..TINY).collect())];
        let draw_ms = self.per_unit("draw call", &base, &draws, 0.0, f64::from(TINY - 1))?;
        let spheres: Vec<u32> = (TINY..TINY + SPHERES).collect();
        let tris: u64 = spheres
            .iter()
            .map(|&o| scene.objects[o as usize].triangle_count())
            .sum();
        let with_spheres = vec![Step::Draw([vec![0], spheres].concat())];
        let extra = f64::from(SPHERES) * draw_ms;
        let triangle_ms = self.per_unit("triangle", &base, &with_spheres, extra, tris as f64)?;
        let quads: Vec<u32> = (TINY + SPHERES..TINY + SPHERES + QUADS).collect();
        let with_quads = vec![Step::Draw([vec![0], quads].concat())];
        let extra = f64::from(QUADS) * (draw_ms + 12.0 * triangle_ms);
        let fragment_ms = self.per_unit(
            "shaded fragment",
            &base,
            &with_quads,
            extra,
            f64::from(QUADS) * pixels,
        )?;
        let small = Aabb::new(
            Vec3::new(-0.01, -0.01, -60.01),
            Vec3::new(0.01, 0.01, -60.0),
        );
        let with_queries: Vec<Step> = base
            .iter()
            .cloned()
            .chain((0..256).map(|_| Step::Query(small)))
            .collect();
        let query_ms = self.per_unit("occlusion query", &base, &with_queries, 0.0, 256.0)?;
        let screen = Aabb::new(
            Vec3::new(-500.0, -500.0, -61.0),
            Vec3::new(500.0, 500.0, -60.0),
        );
        let with_fill: Vec<Step> = base
            .iter()
            .cloned()
            .chain((0..32).map(|_| Step::Query(screen)))
            .collect();
        let query_fragment_ms = self.per_unit(
            "query box fill",
            &base,
            &with_fill,
            32.0 * query_ms,
            32.0 * pixels,
        )?;
        let sync: Vec<Step> = base
            .iter()
            .cloned()
            .chain((0..16).flat_map(|_| [Step::Query(small), Step::Sync]))
            .collect();
        let round_trip_ms =
            self.per_unit("segment round trip", &base, &sync, 16.0 * query_ms, 16.0)?;
        Ok(CostModel {
            draw_ms,
            triangle_ms,
            fragment_ms,
            query_ms,
            query_fragment_ms,
            round_trip_ms,
        })
    }
}
