//! The windowed viewer (`coherent view`): a winit window presented through
//! [`crate::gpu::swapchain`], a fly camera and path playback, live switching of culling
//! algorithms and CHC++ parts, the stats overlay and the query visualization, and a
//! non-interactive mode (N frames, screenshot, per-frame CSV) for tests and scripts.

use std::collections::HashSet;
use std::io::Write;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use glam::Vec3;
use raw_window_handle::{HasDisplayHandle, HasWindowHandle};
use winit::application::ApplicationHandler;
use winit::dpi::PhysicalSize;
use winit::event::{ElementState, MouseButton, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{KeyCode, PhysicalKey};
use winit::window::{Window, WindowId};

use super::overlay::{self, Class};
use crate::bvh::ObjectBvh;
use crate::culling::{
    self, ChcppParams, CullStats, Culler, FrameInput, OcclusionBackend, QueryId, QueryPurpose,
};
use crate::error::{Error, Result};
use crate::gpu::swapchain::{self, Panel, Presented, Swapchain};
use crate::gpu::{CommandCounts, ContextOptions, GpuContext, Recorder, ValidationLog};
use crate::render::hiz::{HizCuller, HizParams};
use crate::render::{FrameResult, Renderer};
use crate::scene::camera::Camera;
use crate::scene::movers::Movers;
use crate::scene::{Aabb, CameraPath, CameraPose, Scene};

/// What `coherent view` was asked to do.
pub struct ViewerConfig {
    /// The scene.
    pub scene: Scene,
    /// Its object hierarchy.
    pub bvh: ObjectBvh,
    /// The path played back.
    pub path: CameraPath,
    /// Window (and offscreen target) size.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// Starting algorithm.
    pub algorithm: String,
    /// CHC++ parameters (the keys B, I, M, T toggle its parts).
    pub params: ChcppParams,
    /// The CHC++ parameters on a GPU device, if they differ from `params` (e.g.
    /// [`ChcppParams::for_gpu`]'s predicated policy); `None`: `params` on every device.
    pub gpu_params: Option<ChcppParams>,
    /// Non-interactive: present this many frames of the path, then exit.
    pub frames: Option<u32>,
    /// Where to save the last frame (non-interactive) or the F12 screenshot.
    pub screenshot: Option<PathBuf>,
    /// CSV with one row per presented frame.
    pub stats: Option<PathBuf>,
    /// Validation layer on.
    pub validation: bool,
    /// FIFO present mode (else MAILBOX/IMMEDIATE where available).
    pub vsync: bool,
    /// Start with the query visualization on.
    pub visualize: bool,
    /// Scripted resize for tests: before presented frame `.0`, ask for a window of `.1`.
    pub resize_at: Option<(u32, (u32, u32))>,
}

/// What a viewer run did.
pub struct ViewerOutcome {
    /// Frames presented.
    pub frames_presented: u32,
    /// Validation messages captured (teardown included).
    pub validation_messages: usize,
}

/// Runs the viewer until the window is closed (or, non-interactive, until the frames are done).
pub fn run(cfg: ViewerConfig) -> Result<ViewerOutcome> {
    run_with_movers(cfg, Movers::default())
}

/// [`run`] with built-in movers (objects of `cfg.scene`): they move every frame; key O stops
/// and starts them.
pub fn run_with_movers(cfg: ViewerConfig, movers: Movers) -> Result<ViewerOutcome> {
    let event_loop =
        EventLoop::new().map_err(|e| Error::Input(format!("cannot open a window: {e}")))?;
    event_loop.set_control_flow(ControlFlow::Poll);
    let mut app = App {
        cfg,
        movers,
        state: None,
        log: None,
        error: None,
        presented: 0,
    };
    let ran = event_loop.run_app(&mut app);
    app.state = None;
    if let Some(e) = app.error.take() {
        return Err(e);
    }
    ran.map_err(|e| Error::Input(format!("window event loop: {e}")))?;
    Ok(ViewerOutcome {
        frames_presented: app.presented,
        validation_messages: app.log.map(|l| l.count()).unwrap_or(0),
    })
}

struct App {
    cfg: ViewerConfig,
    movers: Movers,
    state: Option<Running>,
    log: Option<Arc<ValidationLog>>,
    error: Option<Error>,
    presented: u32,
}

/// Everything that lives while the window is open. Fields drop in order: the swapchain before
/// the renderer and context, the window last.
struct Running {
    swapchain: Swapchain,
    renderer: Renderer,
    recorder: Recorder,
    culler: Box<dyn Culler>,
    /// The GPU-driven culler, when the algorithm is `hiz` (then `culler` is unused).
    hiz: Option<Box<HizCuller>>,
    algorithm: String,
    /// Latency mode of chc and chcpp (key L cycles [`LATENCIES`]).
    latency: &'static str,
    params: ChcppParams,
    stats: Option<std::io::BufWriter<std::fs::File>>,
    pending: CommandCounts,
    frame: u64,
    path_t: f32,
    playing: bool,
    eye: Vec3,
    yaw: f32,
    pitch: f32,
    held: HashSet<KeyCode>,
    dragging: bool,
    cursor: Option<(f64, f64)>,
    last_tick: Instant,
    visualize: bool,
    screenshot_requested: bool,
    screenshots: u32,
    resized: bool,
    /// The hierarchy as the movers leave it (a copy of the configured one).
    bvh: ObjectBvh,
    movers: Movers,
    /// Movers on the move (key O), and the frame of their motion.
    movers_on: bool,
    mover_frame: u64,
    /// The `R` recording: its start and the keys so far.
    recording: Option<(Instant, crate::scene::paths::PathRecorder)>,
    _ctx: Arc<GpuContext>,
    window: Window,
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.state.is_some() {
            return;
        }
        match self.start(event_loop) {
            Ok(s) => self.state = Some(s),
            Err(e) => {
                self.error = Some(e);
                event_loop.exit();
            }
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        let Some(s) = self.state.as_mut() else {
            return;
        };
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(_) => s.swapchain.invalidate(),
            WindowEvent::KeyboardInput { event, .. } => {
                let PhysicalKey::Code(code) = event.physical_key else {
                    return;
                };
                if event.state == ElementState::Released {
                    s.held.remove(&code);
                    return;
                }
                if event.repeat {
                    return;
                }
                s.held.insert(code);
                if let Err(e) = s.key(code, &self.cfg) {
                    self.error = Some(e);
                    event_loop.exit();
                }
                if code == KeyCode::Escape {
                    event_loop.exit();
                }
            }
            WindowEvent::MouseInput {
                state,
                button: MouseButton::Left,
                ..
            } => s.dragging = state == ElementState::Pressed,
            WindowEvent::CursorMoved { position, .. } => {
                if let (true, Some((x, y))) = (s.dragging, s.cursor) {
                    s.yaw += ((position.x - x) * 0.005) as f32;
                    s.pitch = (s.pitch - ((position.y - y) * 0.005) as f32).clamp(-1.5, 1.5);
                    s.playing = false;
                }
                s.cursor = Some((position.x, position.y));
            }
            _ => {}
        }
    }

    fn about_to_wait(&mut self, event_loop: &ActiveEventLoop) {
        if self.error.is_some() {
            return;
        }
        let Some(s) = self.state.as_mut() else {
            return;
        };
        match s.frame(&self.cfg, self.presented) {
            Ok(true) => {
                self.presented += 1;
                if self.cfg.frames.is_some_and(|n| self.presented >= n) {
                    event_loop.exit();
                }
            }
            Ok(false) => std::thread::sleep(std::time::Duration::from_millis(10)),
            Err(e) => {
                self.error = Some(e);
                event_loop.exit();
            }
        }
    }

    fn exiting(&mut self, _event_loop: &ActiveEventLoop) {
        if let Some(s) = self.state.as_mut() {
            if let Some(w) = s.stats.as_mut() {
                if let Err(e) = w.flush() {
                    self.error.get_or_insert(Error::Io(e));
                }
            }
        }
        self.state = None;
    }
}

impl App {
    fn start(&mut self, event_loop: &ActiveEventLoop) -> Result<Running> {
        let cfg = &self.cfg;
        let attrs = Window::default_attributes()
            .with_title(format!("coherent: {}", cfg.scene.name))
            .with_inner_size(PhysicalSize::new(cfg.width, cfg.height));
        let window = event_loop
            .create_window(attrs)
            .map_err(|e| Error::Input(format!("cannot create a window: {e}")))?;
        let display = window
            .display_handle()
            .map_err(|e| Error::Input(format!("no display handle: {e}")))?
            .as_raw();
        let handle = window
            .window_handle()
            .map_err(|e| Error::Input(format!("no window handle: {e}")))?
            .as_raw();
        let ctx = GpuContext::new(&ContextOptions {
            validation: cfg.validation,
            echo_validation: true,
            instance_extensions: swapchain::required_instance_extensions(display)?,
            device_extensions: crate::gpu::swapchain::required_device_extensions(),
            ..Default::default()
        })?;
        self.log = Some(ctx.validation_log());
        let size = window.inner_size();
        let swapchain = Swapchain::new(&ctx, display, handle, size.width, size.height, cfg.vsync)?;
        let mut renderer = Renderer::new(&ctx, &cfg.scene, cfg.width, cfg.height)?;
        let params = match &cfg.gpu_params {
            Some(p) if !ctx.info.is_cpu() => p.clone(),
            _ => cfg.params.clone(),
        };
        renderer.visibility_threshold = params.pixel_threshold;
        let (algorithm, latency) = split_latency(&cfg.algorithm)?;
        let hiz = hiz_for(&algorithm, &renderer)?;
        let culler = match hiz {
            Some(_) => culling::create("vfc", &params)?,
            None => viewer_culler(&algorithm, latency, &params)?,
        };
        let stats = match &cfg.stats {
            Some(p) => {
                let mut w = std::io::BufWriter::new(std::fs::File::create(p)?);
                writeln!(
                    w,
                    "frame,algorithm,frame_ms,pipeline_binds,compute_binds,draws,queries,wasted_queries,state_changes,triangles,submits"
                )?;
                Some(w)
            }
            None => None,
        };
        let pose = cfg.path.pose_at(0.0);
        let dir = (pose.target - pose.eye).normalize_or(Vec3::NEG_Z);
        Ok(Running {
            swapchain,
            renderer,
            recorder: Recorder::new(&ctx),
            culler,
            hiz,
            algorithm,
            latency,
            params,
            stats,
            pending: CommandCounts::default(),
            frame: 0,
            path_t: 0.0,
            playing: true,
            eye: pose.eye,
            yaw: dir.z.atan2(dir.x),
            pitch: dir.y.clamp(-1.0, 1.0).asin(),
            held: HashSet::new(),
            dragging: false,
            cursor: None,
            last_tick: Instant::now(),
            visualize: cfg.visualize,
            screenshot_requested: false,
            screenshots: 0,
            resized: false,
            bvh: cfg.bvh.clone(),
            movers: self.movers.clone(),
            movers_on: true,
            mover_frame: 0,
            recording: None,
            _ctx: ctx,
            window,
        })
    }
}

fn add_counts(a: &mut CommandCounts, b: &CommandCounts) {
    a.pipeline_binds += b.pipeline_binds;
    a.compute_binds += b.compute_binds;
    a.state_changes += b.state_changes;
    a.draw_calls += b.draw_calls;
    a.triangles += b.triangles;
    a.render_triangles += b.render_triangles;
    a.queries_begun += b.queries_begun;
    a.queries_read += b.queries_read;
    a.queries_visible += b.queries_visible;
    a.submits += b.submits;
    a.descriptor_binds += b.descriptor_binds;
    a.buffer_binds += b.buffer_binds;
}

fn on_off(b: bool) -> &'static str {
    if b {
        "ON"
    } else {
        "OFF"
    }
}

impl Running {
    /// The running culler's name: `chcpp@predicated` in a latency mode other than in-frame.
    fn culler_name(&self) -> String {
        if has_latency(&self.algorithm) && self.latency != LATENCIES[0] {
            format!("{}@{}", self.algorithm, self.latency)
        } else {
            self.algorithm.clone()
        }
    }

    fn key(&mut self, code: KeyCode, cfg: &ViewerConfig) -> Result<()> {
        let algorithm = match code {
            KeyCode::Digit1 => Some("vfc"),
            KeyCode::Digit2 => Some("stop-and-wait"),
            KeyCode::Digit3 => Some("chc"),
            KeyCode::Digit4 => Some("chcpp"),
            KeyCode::Digit5 => Some("oracle"),
            KeyCode::Digit6 => Some("hiz"),
            _ => None,
        };
        let mut rebuild = algorithm.is_some();
        if let Some(a) = algorithm {
            self.algorithm = a.to_string();
        }
        match code {
            KeyCode::KeyB => self.params.batching = !self.params.batching,
            KeyCode::KeyI => self.params.randomized_interval = !self.params.randomized_interval,
            KeyCode::KeyM => self.params.multiqueries = !self.params.multiqueries,
            KeyCode::KeyT => self.params.tight_bounds = !self.params.tight_bounds,
            KeyCode::KeyV => self.visualize = !self.visualize,
            KeyCode::KeyP => {
                self.playing = !self.playing;
                if !self.playing {
                    let pose = cfg.path.pose_at(self.path_t);
                    let dir = (pose.target - pose.eye).normalize_or(Vec3::NEG_Z);
                    self.eye = pose.eye;
                    self.yaw = dir.z.atan2(dir.x);
                    self.pitch = dir.y.clamp(-1.0, 1.0).asin();
                }
            }
            KeyCode::F12 | KeyCode::KeyK => self.screenshot_requested = true,
            KeyCode::KeyO => self.movers_on = !self.movers_on,
            KeyCode::KeyR => self.toggle_recording(),
            KeyCode::KeyL => {
                let at = LATENCIES.iter().position(|&l| l == self.latency);
                self.latency = LATENCIES[at.map_or(0, |i| (i + 1) % LATENCIES.len())];
                if !self.renderer.supports_predicates() && self.latency == "predicated" {
                    self.latency = LATENCIES[2];
                }
                eprintln!("view: latency {}", self.latency);
            }
            _ => {}
        }
        if matches!(
            code,
            KeyCode::KeyB | KeyCode::KeyI | KeyCode::KeyM | KeyCode::KeyT
        ) && self.algorithm == "chcpp"
            || code == KeyCode::KeyL && has_latency(&self.algorithm)
        {
            rebuild = true;
        }
        if rebuild {
            self.hiz = hiz_for(&self.algorithm, &self.renderer)?;
            if self.hiz.is_none() {
                self.culler = viewer_culler(&self.algorithm, self.latency, &self.params)?;
            }
        }
        Ok(())
    }

    /// `R`: starts recording the flown camera, or stops and writes `view_path_N.json`.
    fn toggle_recording(&mut self) {
        match self.recording.take() {
            None => {
                self.recording =
                    Some((Instant::now(), crate::scene::paths::PathRecorder::new(0.1)));
                eprintln!("view: recording the camera (R stops)");
            }
            Some((_, rec)) => {
                let file = (0..)
                    .map(|n| PathBuf::from(format!("view_path_{n}.json")))
                    .find(|f| !f.exists())
                    .unwrap_or_else(|| PathBuf::from("view_path.json"));
                match rec.finish(&file) {
                    Ok(()) => eprintln!(
                        "view: wrote {} ({} keys; play it with --path {0})",
                        file.display(),
                        rec.keys().len()
                    ),
                    Err(e) => eprintln!("view: {e}"),
                }
            }
        }
    }

    fn pose(&mut self, cfg: &ViewerConfig, presented: u32) -> CameraPose {
        let pose = self.flown_pose(cfg, presented);
        if let Some((start, rec)) = &mut self.recording {
            rec.push(start.elapsed().as_secs_f32(), pose);
        }
        pose
    }

    fn flown_pose(&mut self, cfg: &ViewerConfig, presented: u32) -> CameraPose {
        let now = Instant::now();
        let dt = (now - self.last_tick).as_secs_f32().min(0.1);
        self.last_tick = now;
        if cfg.frames.is_some() {
            self.path_t = presented as f32;
            return cfg.path.pose_at(self.path_t);
        }
        let dir = Vec3::new(
            self.yaw.cos() * self.pitch.cos(),
            self.pitch.sin(),
            self.yaw.sin() * self.pitch.cos(),
        );
        let right = dir.cross(Vec3::Y).normalize_or(Vec3::X);
        let world = cfg.bvh.nodes[0].bounds;
        let speed = world.extent().length().max(1.0) * 0.08 * dt;
        let mut step = Vec3::ZERO;
        for (k, v) in [
            (KeyCode::KeyW, dir),
            (KeyCode::KeyS, -dir),
            (KeyCode::KeyD, right),
            (KeyCode::KeyA, -right),
            (KeyCode::KeyE, Vec3::Y),
            (KeyCode::KeyQ, -Vec3::Y),
        ] {
            if self.held.contains(&k) {
                step += v;
            }
        }
        if step != Vec3::ZERO {
            self.playing = false;
        }
        if self.playing {
            self.path_t = (self.path_t + dt * 30.0) % cfg.path.natural_frames().max(1) as f32;
            let pose = cfg.path.pose_at(self.path_t);
            let d = (pose.target - pose.eye).normalize_or(Vec3::NEG_Z);
            self.eye = pose.eye;
            self.yaw = d.z.atan2(d.x);
            self.pitch = d.y.clamp(-1.0, 1.0).asin();
            return pose;
        }
        self.eye += step * speed;
        CameraPose {
            eye: self.eye,
            target: self.eye + dir,
        }
    }

    /// Renders and presents one frame; `Ok(false)` when nothing could be shown.
    fn frame(&mut self, cfg: &ViewerConfig, presented: u32) -> Result<bool> {
        self.scripted_resize(cfg, presented);
        let size = self.window.inner_size();
        if size.width == 0 || size.height == 0 {
            return Ok(false);
        }
        let pose = self.pose(cfg, presented);
        if !self.movers.is_empty() {
            if self.movers_on {
                self.mover_frame += 1;
            }
            super::walk::place_movers(
                &self.movers,
                self.mover_frame,
                &mut self.bvh,
                &mut self.renderer,
            )?;
        }
        // The offscreen image is stretched to the window: give the camera the window's aspect.
        let mut camera = self.renderer.camera(pose, &self.bvh);
        camera.aspect = size.width as f32 / size.height as f32;
        let (result, log) = match self.hiz.as_mut() {
            Some(hiz) => (
                hiz.render_frame(&mut self.renderer, &camera)?,
                FrameLog::default(),
            ),
            None => {
                let mut observed = Observed {
                    inner: self.culler.as_mut(),
                    log: FrameLog::default(),
                };
                let result =
                    self.renderer
                        .render_frame(&mut observed, &self.bvh, &camera, self.frame)?;
                (result, observed.log)
            }
        };
        self.frame += 1;
        add_counts(&mut self.pending, &result.counts);
        add_counts(&mut self.pending, &self.renderer.take_prepass_counts());
        let panels = self.panels(
            cfg,
            &result,
            presented,
            (size.width, size.height),
            &camera,
            &log,
        );
        let last = cfg.frames.is_some_and(|n| presented + 1 >= n);
        let want_shot = self.screenshot_requested || (last && cfg.screenshot.is_some());
        let shown = self.swapchain.present(
            &mut self.recorder,
            self.renderer.color_image(),
            &panels,
            (size.width, size.height),
            want_shot,
        )?;
        let Presented::Shown { pixels } = shown else {
            return Ok(false);
        };
        let present_counts = self.recorder.take_counts();
        let mut total = std::mem::take(&mut self.pending);
        add_counts(&mut total, &present_counts);
        self.write_stats(presented, result.frame_ms, &total)?;
        if let Some((w, h, px)) = pixels {
            self.save_screenshot(cfg, w, h, px)?;
        }
        self.screenshot_requested = false;
        Ok(true)
    }

    /// Asks for the scripted window size once, at the frame the test aid names.
    fn scripted_resize(&mut self, cfg: &ViewerConfig, presented: u32) {
        if let Some((at, (w, h))) = cfg.resize_at {
            if presented == at && !self.resized {
                self.resized = true;
                // The new size arrives with a Resized event or is already current.
                let _ = self.window.request_inner_size(PhysicalSize::new(w, h));
            }
        }
    }

    /// The stats text panel and, when the query visualization is on, the map panel.
    fn panels(
        &self,
        cfg: &ViewerConfig,
        result: &FrameResult,
        presented: u32,
        (width, height): (u32, u32),
        camera: &Camera,
        log: &FrameLog,
    ) -> Vec<Panel> {
        let lines = self.stats_lines(cfg, result, presented);
        let scale = if width >= 800 { 2 } else { 1 };
        let mut panels = vec![overlay::text_panel(&lines, 4, 4, scale)];
        if self.visualize {
            let side = width.min(height) / 3;
            let boxes = classify(&cfg.scene, camera, log);
            panels.push(overlay::map_panel(
                &cfg.bvh.nodes[0].bounds,
                &boxes,
                camera.eye,
                width.saturating_sub(side + 4),
                height.saturating_sub(side + 4),
                side,
            ));
        }
        panels
    }

    /// The overlay's lines: algorithm, frame time and the recorder's counts.
    fn stats_lines(&self, cfg: &ViewerConfig, result: &FrameResult, presented: u32) -> Vec<String> {
        let c = &result.counts;
        let mut lines = vec![
            format!(
                "{}  {:.1} MS  FRAME {}",
                self.culler_name(),
                result.frame_ms,
                presented
            ),
            format!("QUERIES {}  WASTED {}", c.queries_begun, c.queries_visible),
            format!(
                "STATE CHANGES {}  BINDS {}",
                c.state_changes, c.pipeline_binds
            ),
            format!("DRAWS {}  TRIANGLES {}", c.draw_calls, c.drawn_triangles()),
        ];
        if self.algorithm == "chcpp" {
            lines.push(format!(
                "B {} I {} M {} T {}",
                on_off(self.params.batching),
                on_off(self.params.randomized_interval),
                on_off(self.params.multiqueries),
                on_off(self.params.tight_bounds)
            ));
        }
        if self.visualize {
            lines.push("MAP: GREEN DRAWN  RED QUERY-CULLED".into());
            lines.push("GRAY FRUSTUM  OTHER: MULTI-BOX QUERY".into());
        }
        if !self.movers.is_empty() {
            lines.push(format!(
                "MOVERS {} {} (O)",
                self.movers.len(),
                on_off(self.movers_on)
            ));
        }
        if cfg.frames.is_none() {
            lines.push("1-6 ALG  L LATENCY  BIMT PARTS  V VIS  P PATH".into());
        }
        lines
    }

    /// One `--stats` row: every command buffer of the presented frame.
    fn write_stats(&mut self, presented: u32, frame_ms: f64, total: &CommandCounts) -> Result<()> {
        let name = self.culler_name();
        if let Some(w) = self.stats.as_mut() {
            writeln!(
                w,
                "{},{},{:.3},{},{},{},{},{},{},{},{}",
                presented,
                name,
                frame_ms,
                total.pipeline_binds,
                total.compute_binds,
                total.draw_calls,
                total.queries_begun,
                total.queries_visible,
                total.state_changes,
                total.render_triangles,
                total.submits
            )?;
        }
        Ok(())
    }

    /// Saves a screenshot: to `--screenshot` when scripted, else to `coherent-N.png`.
    fn save_screenshot(&mut self, cfg: &ViewerConfig, w: u32, h: u32, px: Vec<u8>) -> Result<()> {
        let path = match (&cfg.screenshot, self.screenshot_requested) {
            (Some(p), false) => p.clone(),
            (Some(p), true) if cfg.frames.is_some() => p.clone(),
            _ => {
                self.screenshots += 1;
                PathBuf::from(format!("coherent-{}.png", self.screenshots))
            }
        };
        crate::image_io::save_rgba_png(&path, w, h, px)?;
        if cfg.frames.is_none() {
            eprintln!("view: saved {}", path.display());
        }
        Ok(())
    }
}

/// Draws, queries and their results of one frame, seen between a culler and the renderer.
#[derive(Default)]
struct FrameLog {
    drawn: Vec<u32>,
    queries: Vec<(QueryId, Vec<Aabb>, bool)>,
    results: std::collections::HashMap<QueryId, u64>,
}

/// A culler wrapped so that the backend it talks to is logged.
/// Latency modes the key L cycles through (for chc and chcpp).
const LATENCIES: [&str; 3] = ["in-frame", "predicated", "next-frame"];

/// Whether `algorithm` has latency modes.
fn has_latency(algorithm: &str) -> bool {
    algorithm == "chc" || algorithm == "chcpp"
}

/// Splits `chcpp@predicated` into the algorithm and one of [`LATENCIES`] (`in-frame` when
/// there is no `@`).
fn split_latency(name: &str) -> Result<(String, &'static str)> {
    let Some((algorithm, mode)) = name.split_once('@') else {
        return Ok((name.to_string(), LATENCIES[0]));
    };
    let latency = LATENCIES.iter().find(|&&l| l == mode).ok_or_else(|| {
        Error::Input(format!(
            "the viewer's latency modes are {} (not \"{mode}\")",
            LATENCIES.join(", ")
        ))
    })?;
    if !has_latency(algorithm) {
        return Err(Error::Input(format!(
            "latency modes are for chc and chcpp, not \"{algorithm}\""
        )));
    }
    Ok((algorithm.to_string(), latency))
}

/// The culler for `algorithm` in latency mode `latency` (chc and chcpp; others ignore it).
fn viewer_culler(algorithm: &str, latency: &str, params: &ChcppParams) -> Result<Box<dyn Culler>> {
    if !has_latency(algorithm) || latency == LATENCIES[0] {
        return Ok(culling::create(algorithm, params)?);
    }
    let setup = culling::CullerSetup {
        params: params.clone(),
        ..Default::default()
    };
    Ok(culling::create_named(
        &format!("{algorithm}@{latency}"),
        &setup,
    )?)
}

/// The Hi-Z culler for `renderer` when `algorithm` is `hiz`.
fn hiz_for(algorithm: &str, renderer: &Renderer) -> Result<Option<Box<HizCuller>>> {
    if algorithm != "hiz" {
        return Ok(None);
    }
    let hiz = HizCuller::new(renderer, HizParams::default())?;
    Ok(Some(Box::new(hiz)))
}

struct Observed<'a> {
    inner: &'a mut dyn Culler,
    log: FrameLog,
}

struct Probe<'a> {
    inner: &'a mut dyn OcclusionBackend,
    log: &'a mut FrameLog,
}

impl Culler for Observed<'_> {
    fn name(&self) -> &str {
        self.inner.name()
    }
    fn needs_exact_visibility(&self) -> bool {
        self.inner.needs_exact_visibility()
    }
    fn needs_box_visibility(&self) -> bool {
        self.inner.needs_box_visibility()
    }
    fn reads_tests_after_frame(&self) -> bool {
        self.inner.reads_tests_after_frame()
    }
    fn cull_frame(
        &mut self,
        input: &FrameInput,
        backend: &mut dyn OcclusionBackend,
    ) -> coherent_cull::Result<CullStats> {
        let mut probe = Probe {
            inner: backend,
            log: &mut self.log,
        };
        self.inner.cull_frame(input, &mut probe)
    }
    fn reset(&mut self) {
        self.inner.reset()
    }
}

impl OcclusionBackend for Probe<'_> {
    fn draw_objects(&mut self, objects: &[u32]) -> coherent_cull::Result<()> {
        self.log.drawn.extend_from_slice(objects);
        self.inner.draw_objects(objects)
    }
    fn issue_query(&mut self, boxes: &[Aabb]) -> coherent_cull::Result<QueryId> {
        let id = self.inner.issue_query(boxes)?;
        self.log.queries.push((id, boxes.to_vec(), false));
        Ok(id)
    }
    fn issue_query_for(
        &mut self,
        boxes: &[Aabb],
        purpose: QueryPurpose,
    ) -> coherent_cull::Result<QueryId> {
        let id = self.inner.issue_query_for(boxes, purpose)?;
        let multiquery = purpose == QueryPurpose::Multiquery;
        self.log.queries.push((id, boxes.to_vec(), multiquery));
        Ok(id)
    }
    fn restore_render_state(&mut self) -> coherent_cull::Result<()> {
        self.inner.restore_render_state()
    }
    fn flush(&mut self) -> coherent_cull::Result<()> {
        self.inner.flush()
    }
    fn supports_predicates(&self) -> bool {
        self.inner.supports_predicates()
    }
    fn resolve_predicates(&mut self) -> coherent_cull::Result<()> {
        self.inner.resolve_predicates()
    }
    fn supports_predicated_queries(&self) -> bool {
        self.inner.supports_predicated_queries()
    }
    fn issue_query_if(
        &mut self,
        predicate: QueryId,
        boxes: &[Aabb],
        purpose: QueryPurpose,
    ) -> coherent_cull::Result<QueryId> {
        let id = self.inner.issue_query_if(predicate, boxes, purpose)?;
        self.log.queries.push((id, boxes.to_vec(), false));
        Ok(id)
    }
    fn gathers_predicated_draws(&mut self) -> bool {
        self.inner.gathers_predicated_draws()
    }
    fn test_part_if(
        &mut self,
        predicate: QueryId,
        boxes: &[Aabb],
    ) -> coherent_cull::Result<Option<QueryId>> {
        let id = self.inner.test_part_if(predicate, boxes)?;
        if let Some(id) = id {
            self.log.queries.push((id, boxes.to_vec(), false));
        }
        Ok(id)
    }
    fn draw_objects_if(&mut self, query: QueryId, objects: &[u32]) -> coherent_cull::Result<()> {
        // Drawn only if the predicate holds: the visualization shows them as drawn.
        self.log.drawn.extend_from_slice(objects);
        self.inner.draw_objects_if(query, objects)
    }
    fn set_draw_order(&mut self, order: &[u32]) -> coherent_cull::Result<()> {
        self.inner.set_draw_order(order)
    }
    fn draw_order_ranges_if(
        &mut self,
        query: QueryId,
        order: &[u32],
        ranges: &[std::ops::Range<u32>],
    ) -> coherent_cull::Result<()> {
        coherent_cull::extend_order_objects(&mut self.log.drawn, order, ranges)?;
        self.inner.draw_order_ranges_if(query, order, ranges)
    }
    fn query_result(&mut self, query: QueryId) -> coherent_cull::Result<Option<u64>> {
        let r = self.inner.query_result(query)?;
        if let Some(v) = r {
            self.log.results.insert(query, v);
        }
        Ok(r)
    }
    fn wait_query(&mut self, query: QueryId) -> coherent_cull::Result<u64> {
        let v = self.inner.wait_query(query)?;
        self.log.results.insert(query, v);
        Ok(v)
    }
    fn finish(&mut self) -> coherent_cull::Result<()> {
        self.inner.finish()
    }
}

/// The boxes of the query visualization, drawn in this order: objects outside the frustum,
/// boxes of queries that came back invisible (one color per multi-box query), drawn objects.
fn classify(
    scene: &Scene,
    camera: &crate::scene::camera::Camera,
    log: &FrameLog,
) -> Vec<(Aabb, Class)> {
    let frustum = camera.frustum();
    let mut out: Vec<(Aabb, Class)> = scene
        .objects
        .iter()
        .filter(|o| !frustum.intersects(&o.bounds))
        .map(|o| (o.bounds, Class::FrustumCulled))
        .collect();
    let mut multi = 0;
    for (id, boxes, multiquery) in &log.queries {
        let visible = log.results.get(id).is_some_and(|&v| v > 0);
        if visible {
            continue;
        }
        // Only real multiqueries get their own color; a tight bounding volume (several boxes
        // for one node) is a single node's query.
        let class = if *multiquery {
            multi += 1;
            Class::Multiquery(multi - 1)
        } else {
            Class::QueryCulled
        };
        out.extend(boxes.iter().map(|b| (*b, class)));
    }
    out.extend(log.drawn.iter().filter_map(|&o| {
        scene
            .objects
            .get(o as usize)
            .map(|ob| (ob.bounds, Class::Rendered))
    }));
    // Large boxes (the ground) first, so that they don't hide the small ones.
    let footprint = |b: &Aabb| (b.max.x - b.min.x) * (b.max.z - b.min.z);
    out.sort_by(|a, b| footprint(&b.0).total_cmp(&footprint(&a.0)));
    out
}
