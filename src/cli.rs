//! Flag parsing and the commands of the `coherent` binary. Thin: all work is in the library.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{bail, Context, Result};
use clap::Args;

use coherent::app::pvs_build::PvsBuild;
use coherent::app::walk::{self, WalkConfig};
use coherent::bvh::ObjectBvh;
use coherent::culling::{self, ChcppParams};
use coherent::gpu::GpuContext;
use coherent::render::hiz::{check_algorithm, FrameAlgorithm};
use coherent::render::Renderer;
use coherent::scene::movers::Movers;
use coherent::scene::{CameraPath, Scene};

use crate::cli_common::{
    check_validation, context, load_scene, progress_bar, single_scale, SceneArgs,
};
use crate::cli_setup::{self, CacheArgs, PvsArgs};

/// `coherent render`.
#[derive(Args, Debug)]
pub struct RenderArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Image size WxH.
    #[arg(long, default_value = "1280x720")]
    pub size: String,
    /// Culling algorithm (vfc, stop-and-wait, chc, chcpp, oracle, oracle-box, nohc, pvs, hiz).
    #[arg(long, default_value = "vfc")]
    pub algorithm: String,
    /// Latency mode of chc, chcpp and nohc: in-frame, predicated, next-frame,
    /// next-frame-conservative, with an optional `-kN` suffix (N frames in flight).
    #[arg(long, default_value = "in-frame")]
    pub latency: String,
    /// Frame of the scene's default path (temporal algorithms render frames 0..=N); with
    /// `--walk-frames`, the frame of a walk as its frames.csv numbers it.
    #[arg(long, default_value_t = 0)]
    pub frame: u32,
    /// Take the camera (and the movers) of `coherent walk --frames F` at `--frame`, numbered
    /// as the walk's frames.csv and report number them (after its warm-up frames).
    #[arg(long, value_name = "F")]
    pub walk_frames: Option<u32>,
    /// With `--walk-frames`: the walk's `--warmup` [default: 10].
    #[arg(long)]
    pub warmup: Option<u32>,
    /// Camera path: one of the scene's paths or a path file (.json; see README "Your own
    /// scene"). Default: the scene's first path.
    #[arg(long)]
    pub path: Option<String>,
    /// Output PNG.
    #[arg(long)]
    pub out: PathBuf,
    /// Turn the validation layer off (it is on by default for render).
    #[arg(long)]
    pub no_validation: bool,
    #[command(flatten)]
    pub pvs: PvsArgs,
    #[command(flatten)]
    pub cache: CacheArgs,
    /// Built-in moving objects (cars in city and parking, fans elsewhere), drawn where they are
    /// at the rendered frame.
    #[arg(long, default_value_t = 0, value_parser = crate::cli_common::movers_count)]
    pub movers: usize,
}

/// `coherent walk`.
#[derive(Args, Debug)]
pub struct WalkArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Camera path: one of the scene's paths or a path file (.json; see README "Your own
    /// scene"). Default: the scene's first path.
    #[arg(long)]
    pub path: Option<String>,
    /// Recorded frames along the path.
    #[arg(long, default_value_t = 300)]
    pub frames: u32,
    /// Warm-up frames before recording (excluded from the report).
    #[arg(long, default_value_t = WALK_WARMUP)]
    pub warmup: u32,
    /// Run the whole interleaved walk this many times; ratios are reported with their median
    /// and min-max over the repeats.
    #[arg(long, default_value_t = 1)]
    pub repeat: u32,
    /// Image size WxH.
    #[arg(long, default_value = "1280x720")]
    pub size: String,
    /// Algorithms to compare, comma separated (also: stop-and-wait).
    #[arg(
        long,
        default_value = "vfc,pvs,nohc,chc,chcpp,oracle",
        value_delimiter = ','
    )]
    pub algorithms: Vec<String>,
    /// Output directory.
    #[arg(long, default_value = "out/walk")]
    pub out: PathBuf,
    /// Turn the validation layer on (off by default: it slows everything down).
    #[arg(long)]
    pub validation: bool,
    /// Exactness check: render the exact ID pass at every pose (not timed) and report each
    /// algorithm's missed objects and pixels (visible but not drawn).
    #[arg(long)]
    pub check: bool,
    /// Latency modes of chc, chcpp and nohc, comma separated: in-frame (exact, waits inside the
    /// frame), predicated (exact, one submission: hidden nodes drawn under their queries'
    /// predicates), next-frame (queries read one frame late), next-frame-conservative; a
    /// `-kN` suffix reads them N frames late (N frames in flight, 1 to 16, e.g. predicated-k2).
    /// Reported as `ALGORITHM@MODE`.
    #[arg(long, default_value = "in-frame", value_delimiter = ',')]
    pub latency: Vec<String>,
    #[command(flatten)]
    pub chcpp: ChcppArgs,
    #[command(flatten)]
    pub pvs: PvsArgs,
    #[command(flatten)]
    pub cache: CacheArgs,
    /// Built-in moving objects (cars in city and parking, fans elsewhere); the report adds
    /// refit_ms_median, rebuilds and movers, and chcpp also runs on the scene without movers
    /// (as chcpp-static) for comparison.
    #[arg(long, default_value_t = 0, value_parser = crate::cli_common::movers_count)]
    pub movers: usize,
    /// Cull by the frustum alone: don't also cull objects whose box falls between pixel
    /// centres (they can own no pixel of the one-sample image), for comparison.
    #[arg(long)]
    pub no_pixel_grid: bool,
    /// Test boxes in the predicated mode with occlusion queries (one draw each) instead of
    /// box flags (one instanced draw at each resolve), for comparison.
    #[arg(long)]
    pub no_box_flags: bool,
    /// With box flags, decide the parts of split nodes by the depth part test (a compute pass
    /// over their screen rectangles) instead of box flags gated by their node's, for comparison.
    #[arg(long)]
    pub depth_part_tests: bool,
}

/// `coherent view`.
#[derive(Args, Debug)]
pub struct ViewArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Camera path played back: one of the scene's paths or a path file (.json). Default: the
    /// scene's first path.
    #[arg(long)]
    pub path: Option<String>,
    /// Window size WxH.
    #[arg(long, default_value = "1280x720")]
    pub size: String,
    /// Starting culling algorithm (keys 1-6 switch: vfc, stop-and-wait, chc, chcpp, oracle, hiz).
    #[arg(long, default_value = "chcpp")]
    pub algorithm: String,
    /// Non-interactive: play the path for N presented frames, then exit.
    #[arg(long)]
    pub frames: Option<u32>,
    /// Save the last frame (with its overlay) as this PNG (non-interactive), or the F12/K
    /// screenshot (interactive).
    #[arg(long)]
    pub screenshot: Option<PathBuf>,
    /// Write one CSV row per presented frame (frame,algorithm,frame_ms,pipeline_binds,compute_binds,draws,..).
    #[arg(long)]
    pub stats: Option<PathBuf>,
    /// Turn the validation layer on (any message makes the run fail).
    #[arg(long)]
    pub validation: bool,
    /// Present without vsync (MAILBOX or IMMEDIATE where available).
    #[arg(long)]
    pub no_vsync: bool,
    /// Start with the query visualization (key V) on.
    #[arg(long)]
    pub visualize: bool,
    /// Testing aid: before presented frame F, resize the window to WxH ("F:WxH").
    #[arg(long, hide = true)]
    pub resize_at: Option<String>,
    #[command(flatten)]
    pub chcpp: ChcppArgs,
    /// Built-in moving objects (key M stops and starts them).
    #[arg(long, default_value_t = 0, value_parser = crate::cli_common::movers_count)]
    pub movers: usize,
}

/// CHC++ parameters.
#[derive(Args, Debug, Clone)]
pub struct ChcppArgs {
    /// CHC++ batch size b.
    #[arg(long, default_value_t = ChcppParams::default().batch_size)]
    pub batch_size: usize,
    /// CHC++ visible interval n_av.
    #[arg(long, default_value_t = ChcppParams::default().visible_interval)]
    pub visible_interval: u32,
    /// Predicated mode: its visible interval n_av (in place of --visible-interval).
    #[arg(long, default_value_t = ChcppParams::default().predicated_visible_interval)]
    pub predicated_visible_interval: u32,
    /// Visibility threshold in pixels.
    #[arg(long, default_value_t = ChcppParams::default().pixel_threshold)]
    pub pixel_threshold: u64,
    /// Turn CHC++ parts off: any of batching, interval, multiqueries, tight, and for the
    /// predicated mode split-multiqueries (draw a multiquery's objects under its own predicate
    /// instead of querying its nodes under it) and tested-parts (query the parts of split
    /// nodes instead of the renderer's depth part test) (comma separated).
    #[arg(long, value_delimiter = ',')]
    pub disable: Vec<String>,
    /// Predicated mode: levels below a queried node whose parts are queried under its
    /// predicate in the same frame (0: the node's objects all drawn under its own predicate).
    /// Default: 2 on a CPU device (lavapipe), 0 on a GPU, where recording the parts costs more
    /// than the extra objects drawn.
    #[arg(long)]
    pub refine_levels: Option<u32>,
    /// Predicated mode: a node is split into parts only while it holds more than this many
    /// objects in the frustum.
    #[arg(long, default_value_t = ChcppParams::default().predicated_refine_objects)]
    pub refine_objects: u32,
    /// Predicated mode: split a node only when (1 - p) * objects * RATIO exceeds its parts
    /// (p: the chance its query comes back hidden; RATIO: an object draw's cost over a query
    /// whose boxes a false predicate discards; not applied while the renderer's depth test
    /// decides the parts). 0: split by size alone.
    #[arg(long, default_value_t = ChcppParams::default().predicated_split_ratio)]
    pub split_ratio: f32,
    /// Predicated mode: the renderer's depth test decides the parts of split nodes (instead
    /// of a query each) in frames after one with at least this many parts (0: always;
    /// `--disable tested-parts`: never).
    #[arg(long, default_value_t = ChcppParams::default().predicated_tested_parts_min)]
    pub tested_parts_min: u32,
    /// Predicated mode: the most objects a previously invisible node may put under one
    /// predicate in expectation, (1 - p) * objects; a node above it is opened and its
    /// children queried instead (more queries, fewer extra draws).
    #[arg(long, default_value_t = ChcppParams::default().predicated_budget)]
    pub predicate_budget: f32,
    /// Predicated mode: a query box covering more than this fraction of the screen is
    /// replaced by its children's boxes where theirs cover less (one test still; 0: off)
    #[arg(long, value_name = "FRACTION", default_value_t = ChcppParams::default().predicated_screen_split)]
    pub screen_split: f32,
    /// Predicated mode: a node that enters the frustum with a box over this fraction of the
    /// screen is opened unconditionally instead of queried (what comes into view near the eye
    /// hides what lies behind it before the frame's tests; 0: off)
    #[arg(long, value_name = "FRACTION", default_value_t = ChcppParams::default().predicated_enter_fraction)]
    pub enter_fraction: f32,
}

impl ChcppArgs {
    /// `params` for a GPU: the predicated mode queries with tight bounds and, unless
    /// `--refine-levels` was given, uses one predicate level there ([`ChcppParams::for_gpu`]).
    fn on_gpu(&self, params: &ChcppParams) -> ChcppParams {
        let mut p = params.clone();
        p.predicated_tight_bounds = ChcppParams::for_gpu().predicated_tight_bounds;
        if self.refine_levels.is_none() {
            p.predicated_refine_levels = ChcppParams::for_gpu().predicated_refine_levels;
        }
        p
    }

    /// `params` for the device of `ctx` ([`ChcppArgs::on_gpu`] on a GPU); says so when the
    /// policy changed and `predicated` is among `latencies`.
    fn adapt_to_device(&self, params: &mut ChcppParams, ctx: &GpuContext, latencies: &[String]) {
        if ctx.info.is_cpu() {
            return;
        }
        let gpu = self.on_gpu(params);
        if gpu != *params && latencies.iter().any(|l| l.starts_with("predicated")) {
            println!(
                "predicated mode on a GPU: one predicate level, tight bounds (--refine-levels {}; \
                 --refine-levels 2 splits nodes as on a CPU device)",
                gpu.predicated_refine_levels
            );
        }
        *params = gpu;
    }

    fn params(&self) -> Result<ChcppParams> {
        for (name, value) in [
            ("--batch-size", self.batch_size as u64),
            ("--visible-interval", u64::from(self.visible_interval)),
            (
                "--predicated-visible-interval",
                u64::from(self.predicated_visible_interval),
            ),
        ] {
            if value == 0 {
                bail!("{name} must be at least 1 (1: no batching or no interval)");
            }
        }
        let mut p = ChcppParams {
            batch_size: self.batch_size,
            visible_interval: self.visible_interval,
            predicated_visible_interval: self.predicated_visible_interval,
            pixel_threshold: self.pixel_threshold,
            predicated_refine_levels: self
                .refine_levels
                .unwrap_or(ChcppParams::default().predicated_refine_levels),
            predicated_refine_objects: self.refine_objects,
            predicated_split_ratio: self.split_ratio,
            predicated_tested_parts_min: self.tested_parts_min,
            predicated_budget: self.predicate_budget,
            predicated_screen_split: self.screen_split,
            predicated_enter_fraction: self.enter_fraction,
            ..ChcppParams::default()
        };
        for d in &self.disable {
            match d.as_str() {
                "batching" => p.batching = false,
                // No interval: every visible leaf is queried every frame.
                "interval" => {
                    p.randomized_interval = false;
                    p.visible_interval = 1;
                    p.predicated_visible_interval = 1;
                }
                "multiqueries" => p.multiqueries = false,
                "tight" => p.tight_bounds = false,
                "split-multiqueries" => p.predicated_split_multiqueries = false,
                "tested-parts" => p.predicated_tested_parts_min = u32::MAX,
                other => bail!(
                    "unknown CHC++ part \"{other}\" (batching, interval, multiqueries, tight, \
                     split-multiqueries, tested-parts)"
                ),
            }
        }
        if !(p.predicated_split_ratio >= 0.0 && p.predicated_split_ratio.is_finite()) {
            bail!(
                "--split-ratio {} must be a finite number at least 0",
                p.predicated_split_ratio
            );
        }
        if !(p.predicated_budget >= 0.0 && p.predicated_budget.is_finite()) {
            bail!(
                "--predicate-budget {} must be a finite number at least 0",
                p.predicated_budget
            );
        }
        if !(0.0..=1.0).contains(&p.predicated_screen_split) {
            bail!(
                "--screen-split {} must be a fraction of the screen from 0 (off) to 1",
                p.predicated_screen_split
            );
        }
        if !(p.predicated_enter_fraction >= 0.0 && p.predicated_enter_fraction.is_finite()) {
            bail!(
                "--enter-fraction {} must be a finite number at least 0",
                p.predicated_enter_fraction
            );
        }
        if p.multiqueries && !p.batching {
            bail!(
                "multiqueries group the i-queue, so they need batching: \
                 use --disable batching,multiqueries"
            );
        }
        // What the options above do not name (the culler checks the same each frame).
        p.validate()?;
        Ok(p)
    }
}

/// Parses "WxH".
pub fn parse_size(s: &str) -> Result<(u32, u32)> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .with_context(|| format!("size \"{s}\" is not WxH"))?;
    let w: u32 = w
        .trim()
        .parse()
        .with_context(|| format!("size \"{s}\": bad width"))?;
    let h: u32 = h
        .trim()
        .parse()
        .with_context(|| format!("size \"{s}\": bad height"))?;
    if w == 0 || h == 0 || w > 16384 || h > 16384 {
        bail!("size {w}x{h} is out of range (1..16384)");
    }
    Ok((w, h))
}

/// `coherent info`.
pub fn info() -> Result<()> {
    let ctx = context(false)?;
    let i = &ctx.info;
    println!("device:          {}", i.name);
    println!("type:            {}", i.device_type);
    println!("driver:          {}", i.driver);
    println!("Vulkan version:  {}", i.api_version);
    println!("chosen because:  {}", i.reason);
    println!("devices seen:    {}", i.candidates.join("; "));
    println!("timestamp tick:  {} ns", i.timestamp_period_ns);
    println!("max layers:      {}", i.max_image_array_layers);
    println!(
        "hiz needs:       drawIndirectCount {}, multiDrawIndirect {}, drawIndirectFirstInstance {}, \
         sampled D32 {}, storage R32F {} (samplerFilterMinmax {}: not needed, the pyramid \
         reduces by hand)",
        i.optional.draw_indirect_count,
        i.optional.multi_draw_indirect,
        i.optional.draw_indirect_first_instance,
        i.optional.depth_sampled,
        i.optional.r32f_storage,
        i.optional.sampler_filter_minmax
    );
    println!(
        "gi shadow maps:  shaderClipDistance {} (without it they clip in the vertex shader, \
         slower)",
        i.optional.shader_clip_distance
    );
    println!(
        "oracle-box:      fragmentStoresAndAtomics {}",
        i.optional.fragment_stores
    );
    println!(
        "predicated:      VK_EXT_conditional_rendering (conditionalRendering) {} (the \
         predicated latency mode needs it)",
        i.optional.conditional_rendering
    );
    println!(
        "features used:   {} (all present)",
        coherent::gpu::context::REQUIRED_FEATURES.join(", ")
    );
    match coherent::app::report::plot::font_file() {
        Ok(path) => println!("plots font:      {path}"),
        Err(e) => println!("plots font:      {e}; walk and gi --out need it"),
    }
    Ok(())
}

/// `coherent render`.
pub fn render(a: &RenderArgs) -> Result<()> {
    let (w, h) = parse_size(&a.size)?;
    let walk = render_walk_frames(a)?;
    coherent::image_io::prepare_png_path(&a.out)?;
    check_algorithm(&a.algorithm, &ChcppParams::default())?;
    let name = match a.algorithm.as_str() {
        alg if culling::has_latency_modes(alg) => culling::with_latency_names(
            std::slice::from_ref(&a.algorithm),
            std::slice::from_ref(&a.latency),
        )?
        .remove(0),
        _ if a.latency == "in-frame" => a.algorithm.clone(),
        other => bail!("--latency is for chc, chcpp and nohc, not \"{other}\""),
    };
    let cache_dir = a.cache.dir();
    let mut scene = load_scene(&a.scene, single_scale(&a.scene)?, &cache_dir)?;
    // The path of the scene without movers (checked and found on the fixed geometry).
    let path = scene.resolve_path_cached(a.path.as_deref(), &cache_dir)?;
    let movers = Movers::add(&mut scene, a.movers);
    let mut bvh = scene.hierarchy(a.scene.leaf_size);
    let ctx = context(!a.no_validation)?;
    {
        let scale = single_scale(&a.scene)?;
        let mut setup = coherent::culling::CullerSetup::default();
        if !ctx.info.is_cpu() {
            // As walk and view do on a GPU (render has no CHC++ flags).
            setup.params = ChcppParams::for_gpu();
        }
        if a.algorithm == "nohc" {
            setup.nohc = Some(cli_setup::nohc_params(&ctx, &a.cache, &scene, (w, h))?);
        }
        if a.algorithm == "pvs" {
            let b = cli_setup::pvs(&ctx, &a.scene, scale, &scene, &bvh, &path, &a.pvs, &a.cache)?;
            setup.pvs = Some(b.pvs);
        }
        let renderer_scene = Renderer::new(&ctx, &scene, w, h)?;
        let mut renderer = renderer_scene;
        let mut culler = FrameAlgorithm::create(&name, &setup, &renderer)?;
        // Algorithms without state between frames start one frame early, so that the frame
        // printed is not the renderer's first (on lavapipe the first draws of a pipeline
        // compile its shader variants).
        // With `--walk-frames` the frames are the walk's, warm-up included.
        let target = walk.map_or(a.frame, |(_, warmup)| a.frame + warmup);
        let first = if culler.needs_exact_visibility() || a.algorithm == "vfc" {
            target.saturating_sub(1)
        } else {
            0
        };
        let mut last = None;
        for f in first..=target {
            walk::place_movers(&movers, f as u64, &mut bvh, &mut renderer)?;
            let pose = match walk {
                Some((frames, warmup)) => path.sample(f, frames + warmup),
                None => path.pose_at(f as f32),
            };
            let cam = renderer.camera(pose, &bvh);
            last = Some(culler.render_frame(&mut renderer, &bvh, &cam, f as u64)?);
        }
        renderer.save_png(&a.out)?;
        if let Some(r) = last {
            let c = &r.counts;
            let predicated = if c.predicate_resolves > 0 {
                format!(
                    ", {} objects under predicates ({} drawn)",
                    c.predicated_objects, c.predicated_objects_taken
                )
            } else {
                String::new()
            };
            let tests = if c.flag_tests > 0 {
                format!("{} box tests (flags)", c.flag_tests)
            } else {
                format!("{} queries", c.queries_begun)
            };
            let frame = match walk {
                Some((frames, warmup)) => format!(
                    "frame {} of a walk of {frames} (+ {warmup} warm-up)",
                    a.frame
                ),
                None => format!("frame {}", a.frame),
            };
            println!(
                "{}: {} {frame} with {}: {:.1} ms, {} draws, {} triangles, {tests}, {} state changes, {} submits{predicated} -> {}",
                scene.name,
                path.name,
                name,
                r.frame_ms,
                c.draw_calls,
                c.drawn_triangles(),
                c.state_changes,
                c.submits,
                a.out.display()
            );
        }
    }
    check_validation(&ctx)
}

/// Most frames of a walk, a `view` playback or a `gi` run (a walk keeps a record of each).
const MAX_FRAMES: u32 = 100_000;

/// `walk`'s warm-up frames unless `--warmup` says otherwise (and `render --walk-frames`'s).
const WALK_WARMUP: u32 = 10;

/// `render`'s frame numbering: `Some((frames, warmup))` with `--walk-frames` (a walk's frames
/// and warm-up frames), checked against `--frame`.
fn render_walk_frames(a: &RenderArgs) -> Result<Option<(u32, u32)>> {
    if a.frame > MAX_FRAMES {
        bail!("--frame must be at most {MAX_FRAMES}");
    }
    let Some(frames) = a.walk_frames else {
        if a.warmup.is_some() {
            bail!("--warmup is for --walk-frames (the walk's warm-up frames)");
        }
        return Ok(None);
    };
    let warmup = a.warmup.unwrap_or(WALK_WARMUP);
    if !(1..=MAX_FRAMES).contains(&frames) || warmup > MAX_FRAMES {
        bail!("--walk-frames must be 1 to {MAX_FRAMES} and --warmup at most {MAX_FRAMES}");
    }
    if a.frame >= frames {
        bail!(
            "--frame {} is past a walk of {frames} frames (its frames are 0 to {})",
            a.frame,
            frames - 1
        );
    }
    Ok(Some((frames, warmup)))
}

/// Most VPLs of `gi` (the reference renders four times as many, each with its shadow map).
const MAX_VPLS: usize = 65_536;

/// `coherent walk`.
pub fn walk(a: &WalkArgs) -> Result<()> {
    let (w, h) = parse_size(&a.size)?;
    if !(1..=MAX_FRAMES).contains(&a.frames) || a.warmup > MAX_FRAMES {
        bail!("--frames must be 1 to {MAX_FRAMES} and --warmup at most {MAX_FRAMES}");
    }
    if !(1..=100).contains(&a.repeat) || u64::from(a.frames) * u64::from(a.repeat) > 1_000_000 {
        bail!("--repeat must be 1 to 100, and --frames times --repeat at most 1000000");
    }
    let mut params = a.chcpp.params()?;
    for alg in &a.algorithms {
        check_algorithm(alg, &params)?;
    }
    let algorithms = culling::with_latency_names(&a.algorithms, &a.latency)?;
    let twice = (1..algorithms.len()).find(|&i| algorithms[..i].contains(&algorithms[i]));
    if let Some(name) = twice.map(|i| &algorithms[i]) {
        bail!(
            "--algorithms with --latency names {name} twice (each runs once a pose: name it once)"
        );
    }
    // The report ends with plots: a missing font fails now, not after the walk.
    coherent::app::report::plot::check_font()?;
    let ctx = context(a.validation)?;
    a.chcpp.adapt_to_device(&mut params, &ctx, &a.latency);
    let cfg = WalkConfig {
        algorithms,
        frames: a.frames,
        warmup: a.warmup,
        params,
        repeats: a.repeat,
        check: a.check,
        no_pixel_grid: a.no_pixel_grid,
        no_box_flags: a.no_box_flags,
        depth_part_tests: a.depth_part_tests,
        nohc: None,
        pvs: None,
    };
    let scales = a.scene.scale.clone();
    let mut summaries = Vec::new();
    for &scale in &scales {
        let dir = if scales.len() > 1 {
            a.out.join(format!("scale_{scale}"))
        } else {
            a.out.clone()
        };
        let summary = walk_scale(a, &ctx, &cfg, scale, &dir, (w, h))?;
        summaries.push((scale, summary));
    }
    if summaries.len() > 1 {
        write_scaling_table(&a.out, &summaries)?;
    }
    check_validation(&ctx)
}

/// One scale of `coherent walk`: loads the scene, walks its path with every algorithm and
/// writes the report to `dir`.
fn walk_scale(
    a: &WalkArgs,
    ctx: &Arc<GpuContext>,
    cfg: &WalkConfig,
    scale: f32,
    dir: &std::path::Path,
    (w, h): (u32, u32),
) -> Result<coherent::app::report::WalkSummary> {
    let cache_dir = a.cache.dir();
    let scene = load_scene(&a.scene, scale, &cache_dir)?;
    // Built-in movers, or objects a glTF animation moves: the walk places them every frame.
    if a.movers > 0 || scene.animation.is_some() {
        return walk_scale_movers(a, ctx, cfg, (scene, scale), dir, (w, h));
    }
    let path = scene.resolve_path_cached(a.path.as_deref(), &cache_dir)?;
    let bvh = scene.hierarchy(a.scene.leaf_size);
    let mut cfg = cfg.clone();
    let pvs = prepare_walk(
        a,
        ctx,
        &mut cfg,
        scale,
        &scene,
        (&scene, &bvh),
        &path,
        (w, h),
    )?;
    let cfg = &cfg;
    println!(
        "walk: {} (scale {scale}: {} objects, {} triangles), path {}, {} frames + {} warm-up, {w}x{h}, {} on {}",
        scene.name,
        scene.objects.len(),
        scene.triangle_count(),
        path.name,
        a.frames,
        a.warmup,
        cfg.algorithms.join(", "),
        ctx.info.name
    );
    let records = {
        let mut renderer = Renderer::new(ctx, &scene, w, h)?;
        let bar = progress_bar();
        let records = walk::run(&mut renderer, &bvh, &path, cfg, |done, total| {
            bar.tick(done, total)
        })?;
        bar.finish();
        records
    };
    let walk::WrittenReport { mut summary, files } = walk::write_report(
        dir,
        &scene,
        &path.name,
        &ctx.info.name,
        (w, h),
        &records,
        &cfg.algorithms,
    )?;
    if let Some(b) = &pvs {
        let outside = cli_setup::frames_outside(&b.pvs, &path, a.frames, a.warmup);
        let pre = cli_setup::preprocess_summary(b, outside);
        if let Some((_, s)) = summary.algorithms.iter_mut().find(|(n, _)| n == "pvs") {
            s.preprocess = Some(pre);
        }
        summary.write_json(&dir.join("summary.json"))?;
    }
    let reference = a
        .algorithms
        .iter()
        .any(|x| x == "oracle")
        .then_some("oracle");
    println!("{}", summary.table(reference));
    print_written(&files);
    Ok(summary)
}

/// Names the report's files, as [`walk::write_report`] wrote them.
fn print_written(files: &[std::path::PathBuf]) {
    let names: Vec<String> = files.iter().map(|f| f.display().to_string()).collect();
    println!("wrote {}", names.join(", "));
}

/// [`walk_scale`] with `--movers N`: the scene with its movers, and the same scene without them
/// for chcpp-static, in one interleaved walk.
fn walk_scale_movers(
    a: &WalkArgs,
    ctx: &Arc<GpuContext>,
    cfg: &WalkConfig,
    (fixed, scale): (Scene, f32),
    dir: &std::path::Path,
    (w, h): (u32, u32),
) -> Result<coherent::app::report::WalkSummary> {
    let cache_dir = a.cache.dir();
    let mut scene = fixed.clone();
    let movers = Movers::add(&mut scene, a.movers);
    // The same paths as without movers: built-in names, path files, `interior`, found and
    // checked on the scene without them (the movers' triangles at frame 0 would only slow
    // the check: at a million movers, past the machine's memory).
    let path = fixed.resolve_path_cached(a.path.as_deref(), &cache_dir)?;
    let (mut bvh, fixed_bvh) = (
        bvh_of(&scene, a.scene.leaf_size),
        bvh_of(&fixed, a.scene.leaf_size),
    );
    // Without fixed objects (a glTF file whose animation moves everything) there is no
    // static scene to compare with.
    let baseline = if fixed.objects.is_empty() {
        Vec::new()
    } else {
        static_baseline(&a.algorithms)
    };
    let mut cfg = cfg.clone();
    // pvs is built on the scene without movers: it cannot know where they go, so it draws
    // them frustum-culled only (their ids lie past the PVS's objects).
    prepare_walk(
        a,
        ctx,
        &mut cfg,
        scale,
        &scene,
        (&fixed, &fixed_bvh),
        &path,
        (w, h),
    )?;
    let cfg = &cfg;
    println!(
        "walk: {} (scale {scale}: {} objects, {} of them movers), path {}, {} frames + {} warm-up, {w}x{h}, {}{} on {}",
        scene.name,
        scene.objects.len(),
        movers.len(),
        path.name,
        a.frames,
        a.warmup,
        a.algorithms.join(", "),
        if baseline.is_empty() {
            String::new()
        } else {
            format!(" (+ {} without movers)", baseline.join(", "))
        },
        ctx.info.name
    );
    let (records, stats) = run_movers_walk(
        ctx,
        (&scene, &fixed),
        (&mut bvh, &fixed_bvh),
        (&movers, &baseline),
        &path,
        cfg,
        (w, h),
    )?;
    let mut names = a.algorithms.clone();
    names.extend(baseline.iter().map(|b| format!("{b}-static")));
    let walk::WrittenReport { mut summary, files } = walk::write_report(
        dir,
        &scene,
        &path.name,
        &ctx.info.name,
        (w, h),
        &records,
        &names,
    )?;
    let ms = coherent::app::report::summary::mover_summary(
        stats.movers,
        &stats.refit_ms,
        stats.rebuilds,
        &records,
    );
    let mut ms = ms;
    ms.deformed_meshes = movers.deformed_meshes();
    ms.animation = movers.animation_label().map(String::from);
    ms.pose_ms_median = coherent::app::report::median(&mut stats.pose_ms.clone());
    summary.movers = Some(ms.clone());
    summary.write_json(&dir.join("summary.json"))?;
    let reference = a.algorithms.iter().any(|x| x == "oracle");
    println!("{}", summary.table(reference.then_some("oracle")));
    print_movers(&ms);
    print_mover_draws(&summary, &files);
    Ok(summary)
}

/// The interleaved walk of [`walk_scale_movers`]: `scene` with its movers, and `baseline`
/// algorithms on `fixed` (the scene without them), at `w`x`h`.
fn run_movers_walk(
    ctx: &Arc<GpuContext>,
    (scene, fixed): (&Scene, &Scene),
    (bvh, fixed_bvh): (&mut ObjectBvh, &ObjectBvh),
    (movers, baseline): (&Movers, &[String]),
    path: &coherent::scene::CameraPath,
    cfg: &WalkConfig,
    (w, h): (u32, u32),
) -> Result<(Vec<coherent::app::report::FrameRecord>, walk::MoverStats)> {
    let mut renderer = Renderer::new(ctx, scene, w, h)?;
    let mut fixed_renderer = Renderer::new(ctx, fixed, w, h)?;
    let mut mw = walk::MoverWalk {
        movers,
        baseline: Some((&mut fixed_renderer, fixed_bvh)),
        baseline_algorithms: baseline.to_vec(),
    };
    let bar = progress_bar();
    let out = walk::run_with_movers(&mut renderer, bvh, path, cfg, &mut mw, |d, t| {
        bar.tick(d, t)
    })?;
    bar.finish();
    Ok(out)
}

/// Adds to `cfg` what the walk's `nohc` and `pvs` need: NOHC's parameters for `scene` at
/// `size`, and the PVS of `static_scene` (the scene without movers, with its hierarchy) along
/// `path`. Returns the PVS build for the report.
#[allow(clippy::too_many_arguments)]
fn prepare_walk(
    a: &WalkArgs,
    ctx: &Arc<GpuContext>,
    cfg: &mut WalkConfig,
    scale: f32,
    scene: &Scene,
    (static_scene, static_bvh): (&Scene, &ObjectBvh),
    path: &CameraPath,
    size: (u32, u32),
) -> Result<Option<PvsBuild>> {
    let uses = |name: &str| a.algorithms.iter().any(|x| x == name);
    if uses("nohc") {
        cfg.nohc = Some(cli_setup::nohc_params(ctx, &a.cache, scene, size)?);
    }
    if !uses("pvs") {
        return Ok(None);
    }
    let b = cli_setup::pvs(
        ctx,
        &a.scene,
        scale,
        static_scene,
        static_bvh,
        path,
        &a.pvs,
        &a.cache,
    )?;
    cfg.pvs = Some(b.pvs.clone());
    Ok(Some(b))
}

/// The algorithms of a movers walk that also run on the scene without movers (as
/// `NAME-static`): chcpp, when it is walked.
fn static_baseline(algorithms: &[String]) -> Vec<String> {
    algorithms
        .iter()
        .filter(|x| *x == "chcpp")
        .cloned()
        .collect()
}

/// The object hierarchy of a scene.
fn bvh_of(scene: &Scene, leaf_size: u32) -> ObjectBvh {
    scene.hierarchy(leaf_size)
}

/// Prints each algorithm's median object draws of movers (pvs draws them frustum-culled only)
/// and the report's files.
fn print_mover_draws(summary: &coherent::app::report::WalkSummary, files: &[std::path::PathBuf]) {
    let draws: Vec<String> = summary
        .algorithms
        .iter()
        .filter_map(|(n, s)| s.mover_draws_median.map(|d| format!("{n} {d}")))
        .collect();
    println!("mover draws (median per frame): {}", draws.join(", "));
    print_written(files);
}

/// Prints what the movers cost: refit time, rebuilds, frame-time ratios to the static scene.
fn print_movers(ms: &coherent::app::report::summary::MoverSummary) {
    let skinned = match ms.deformed_meshes {
        0 => String::new(),
        n => format!(
            ", {n} mesh(es) skinned or morphed in pose_ms_median {:.3}",
            ms.pose_ms_median
        ),
    };
    let animation = match &ms.animation {
        Some(a) => format!(" (glTF animation {a})"),
        None => String::new(),
    };
    println!(
        "movers: {}{animation}, refit_ms_median {:.3}, refit_ms_max {:.3}, rebuilds {}{skinned}",
        ms.movers, ms.refit_ms_median, ms.refit_ms_max, ms.rebuilds
    );
    for (name, s) in &ms.vs_static {
        println!(
            "{name} with movers / without: {:.3} (min {:.3}, max {:.3})",
            s.median, s.min, s.max
        );
    }
}

/// Prints the table comparing the scales of a walk and writes it to `out/scaling.txt`.
fn write_scaling_table(
    out: &std::path::Path,
    summaries: &[(f32, coherent::app::report::WalkSummary)],
) -> Result<()> {
    let rows: Vec<(f32, &coherent::app::report::WalkSummary)> =
        summaries.iter().map(|(s, m)| (*s, m)).collect();
    let table = coherent::app::report::scaling_table(&rows);
    println!("{table}");
    std::fs::create_dir_all(out)?;
    std::fs::write(out.join("scaling.txt"), &table)?;
    Ok(())
}

/// `coherent view`.
pub fn view(a: &ViewArgs) -> Result<()> {
    let (w, h) = parse_size(&a.size)?;
    if a.frames.is_some_and(|f| !(1..=MAX_FRAMES).contains(&f)) {
        bail!("--frames must be 1 to {MAX_FRAMES}");
    }
    if let Some(shot) = &a.screenshot {
        coherent::image_io::prepare_png_path(shot)?;
    }
    let params = a.chcpp.params()?;
    check_algorithm(&a.algorithm, &params)?;
    let cache_dir = coherent::app::calibrate::default_cache_dir();
    let mut scene = load_scene(&a.scene, single_scale(&a.scene)?, &cache_dir)?;
    // The path of the scene without movers (checked and found on the fixed geometry).
    let path = scene.resolve_path_cached(a.path.as_deref(), &cache_dir)?;
    let movers = Movers::add(&mut scene, a.movers);
    let bvh = scene.hierarchy(a.scene.leaf_size);
    let resize_at = match &a.resize_at {
        Some(s) => {
            let (f, size) = s
                .split_once(':')
                .with_context(|| format!("--resize-at \"{s}\" is not F:WxH"))?;
            let f: u32 = f
                .parse()
                .with_context(|| format!("--resize-at \"{s}\": bad frame"))?;
            Some((f, parse_size(size)?))
        }
        None => None,
    };
    let config = coherent::app::viewer::ViewerConfig {
        scene,
        bvh,
        path,
        width: w,
        height: h,
        algorithm: a.algorithm.clone(),
        gpu_params: Some(a.chcpp.on_gpu(&params)),
        params,
        frames: a.frames,
        screenshot: a.screenshot.clone(),
        stats: a.stats.clone(),
        validation: a.validation,
        vsync: !a.no_vsync,
        visualize: a.visualize,
        resize_at,
    };
    let outcome = coherent::app::viewer::run_with_movers(config, movers)?;
    if outcome.validation_messages > 0 {
        bail!(
            "the validation layer reported {} messages (printed above)",
            outcome.validation_messages
        );
    }
    if let Some(n) = a.frames {
        println!("view: presented {} of {n} frames", outcome.frames_presented);
        if outcome.frames_presented < n {
            bail!(
                "the window closed after {} of {n} frames",
                outcome.frames_presented
            );
        }
    }
    Ok(())
}

/// `coherent gi`.
#[derive(Args, Debug)]
pub struct GiArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Number of VPLs (N).
    #[arg(long, default_value_t = 256)]
    pub vpls: usize,
    /// New VPLs (and shadow maps) per frame in incremental mode (B).
    #[arg(long, default_value_t = 8)]
    pub budget: usize,
    /// Frames along the light path.
    #[arg(long, default_value_t = 100)]
    pub frames: u32,
    /// Image size WxH.
    #[arg(long, default_value = "640x480")]
    pub size: String,
    /// incremental, full, both (incremental and full) or all.
    #[arg(long, default_value = "both")]
    pub mode: String,
    /// Frames compared with the reference (evenly spaced over the frames after the first).
    #[arg(long, default_value_t = 8)]
    pub samples: u32,
    /// Imperfect shadow map edge in texels (ism mode; a power of two, 4 to 32).
    #[arg(long, default_value_t = 32)]
    pub ism_size: u32,
    /// Surface points splatted into each imperfect shadow map (ism mode).
    #[arg(long, default_value_t = 2048)]
    pub ism_points: u32,
    /// Shadow-map resolution (per VPL layer).
    #[arg(long, default_value_t = 256)]
    pub shadow_size: u32,
    /// Output directory (PNGs and summary.json).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Turn the validation layer on.
    #[arg(long)]
    pub validation: bool,
    /// Camera: its first pose is the GI camera (one of the scene's paths or a path file).
    /// Without it, on an enclosed glTF with no spot light the camera walks the interior path
    /// over the run, with the light a key ahead.
    #[arg(long)]
    pub path: Option<String>,
    /// Light path file (.json, the camera path format: the light sits at each key's position
    /// and points where it looks). Default: the glTF's first spot light, else the scene's
    /// sweep.
    #[arg(long)]
    pub light_path: Option<PathBuf>,
    /// Built-in moving objects (fans; cars in city and parking): incremental re-renders the
    /// shadow maps they may have changed, full and ism rebuild every map anyway.
    #[arg(long, default_value_t = 0, value_parser = crate::cli_common::movers_count)]
    pub movers: usize,
}

/// `coherent gi`.
pub fn gi(a: &GiArgs) -> Result<()> {
    use coherent::app::gi_run::{self, GiMode, GiRunOptions};
    let (width, height) = parse_size(&a.size)?;
    let modes = GiMode::parse_list(&a.mode)?;
    if a.vpls == 0 || a.budget == 0 || a.frames == 0 || a.shadow_size == 0 {
        bail!("--vpls, --budget, --frames and --shadow-size must be positive");
    }
    if a.vpls > MAX_VPLS || a.frames > MAX_FRAMES {
        bail!("--vpls must be at most {MAX_VPLS} and --frames at most {MAX_FRAMES}");
    }
    if a.out.is_some() {
        // `rmse.png` ends the run: a missing font fails now, not after it.
        coherent::app::report::plot::check_font()?;
    }
    let scene = load_scene(
        &a.scene,
        single_scale(&a.scene)?,
        &coherent::app::calibrate::default_cache_dir(),
    )?;
    let ctx = context(a.validation)?;
    let opts = GiRunOptions {
        vpls: a.vpls,
        budget: a.budget,
        frames: a.frames,
        width,
        height,
        modes,
        shadow_size: a.shadow_size,
        sample_frames: a.samples,
        ism: coherent::gi::IsmOptions {
            map_size: a.ism_size,
            points_per_vpl: a.ism_points,
        },
    };
    let setup = gi_setup(a, &scene)?;
    if gi_run::walking_path(&scene, &setup).is_some() {
        println!(
            "camera: walks the interior path over the run, the light a key ahead \
             (--path P: stand at P's first pose)"
        );
    }
    let bar = progress_bar();
    let summary = gi_run::run_reporting(&ctx, &scene, &opts, a.out.as_deref(), &setup, |d, t| {
        bar.tick(d, t)
    })?;
    bar.finish();
    print!("{}", summary.table());
    if let Some(dir) = &a.out {
        println!("wrote {}", dir.display());
    }
    check_validation(&ctx)
}

/// The camera and light path of `coherent gi` from its flags.
fn gi_setup(a: &GiArgs, scene: &Scene) -> Result<coherent::app::gi_run::GiSetup> {
    use coherent::scene::paths;
    let camera = match &a.path {
        Some(p) => Some(
            scene
                .resolve_path_cached(Some(p), &coherent::app::calibrate::default_cache_dir())?
                .pose_at(0.0),
        ),
        None => None,
    };
    let light_keys = match &a.light_path {
        Some(file) => {
            let keys = paths::read_path_file(file)?;
            Some(paths::keys_to_path("light", &keys))
        }
        // A glTF's own spot light, if it has one.
        None => scene
            .path(coherent::scene::gltf_ext::LIGHT_PATH)
            .ok()
            .cloned(),
    };
    Ok(coherent::app::gi_run::GiSetup {
        camera,
        light_keys,
        movers: a.movers,
    })
}

#[cfg(test)]
mod tests {
    use super::ChcppParams;
    use clap::Parser;

    /// An algorithm named twice (directly, or as two latency names of one mode) is refused
    /// before any device is opened: the report would merge the two runs under one name.
    #[test]
    fn walk_refuses_an_algorithm_named_twice() {
        for extra in [
            &["--algorithms", "chcpp,vfc,chcpp"][..],
            &[
                "--algorithms",
                "chcpp",
                "--latency",
                "predicated,predicated-k1",
            ],
        ] {
            let mut argv = vec!["coherent", "walk", "--scene", "city"];
            argv.extend_from_slice(extra);
            let crate::Command::Walk(w) = crate::Cli::try_parse_from(argv).unwrap().command else {
                unreachable!()
            };
            let e = super::walk(&w).expect_err("named twice").to_string();
            assert!(e.contains("twice"), "{e}");
        }
    }

    /// `--movers` beyond what a machine can hold is refused when the command line is read, on
    /// every command that takes it, before the scene is built (ten million took 7.7 GB first).
    #[test]
    fn movers_beyond_the_limit_are_refused_before_anything_is_built() {
        let too_many = (crate::cli_common::MAX_MOVERS + 1).to_string();
        for cmd in [
            &["render", "--out", "x.png"][..],
            &["walk"],
            &["view"],
            &["gi"],
        ] {
            let mut argv = vec!["coherent"];
            argv.extend_from_slice(cmd);
            argv.extend_from_slice(&["--scene", "city", "--movers"]);
            let most = crate::cli_common::MAX_MOVERS.to_string();
            crate::Cli::try_parse_from([&argv[..], &[most.as_str()]].concat())
                .unwrap_or_else(|e| panic!("{cmd:?}: {e}"));
            let e = crate::Cli::try_parse_from([&argv[..], &[too_many.as_str()]].concat())
                .err()
                .unwrap_or_else(|| panic!("{cmd:?}: accepted"))
                .to_string();
            assert!(e.contains("more than 2000000 movers"), "{cmd:?}: {e}");
        }
    }

    /// Counts that would allocate past any machine (a record per walk frame, VPLs, frames in
    /// flight) are refused before a scene or a device is touched: four billion frames or VPLs
    /// aborted the command allocating hundreds of gigabytes.
    #[test]
    fn counts_past_any_machine_are_refused_up_front() {
        let parse = |command: &[&str], extra: &[&str]| {
            let argv = ["coherent"].iter().chain(command).chain(extra);
            crate::Cli::try_parse_from(argv).unwrap().command
        };
        let walk = |extra: &[&str]| {
            let crate::Command::Walk(w) = parse(&["walk", "--scene", "city"], extra) else {
                unreachable!()
            };
            super::walk(&w).expect_err("refused").to_string()
        };
        assert!(walk(&["--frames", "4294967295"]).contains("--frames must be 1 to 100000"));
        assert!(walk(&["--warmup", "100001"]).contains("--warmup at most"));
        assert!(walk(&["--repeat", "101"]).contains("--repeat must be 1 to 100"));
        assert!(walk(&["--frames", "20000", "--repeat", "51"]).contains("at most 1000000"));
        assert!(walk(&[
            "--latency",
            "next-frame-k4000000000",
            "--algorithms",
            "chcpp"
        ])
        .contains("frames in flight must be 1 to 16"));
        let gi = |extra: &[&str]| {
            let crate::Command::Gi(g) = parse(&["gi", "--scene", "cornell"], extra) else {
                unreachable!()
            };
            super::gi(&g).expect_err("refused").to_string()
        };
        assert!(gi(&["--vpls", "4294967295"]).contains("--vpls must be at most 65536"));
        assert!(gi(&["--frames", "100001"]).contains("--frames at most 100000"));
    }

    /// The PVS samples each cell's border unless `--no-cell-border` says not to.
    #[test]
    fn pvs_cells_are_sampled_on_their_border_by_default() {
        let border = |extra: &[&str]| {
            let mut argv = vec!["coherent", "render", "--scene", "city", "--out", "x.png"];
            argv.extend_from_slice(extra);
            let crate::Command::Render(r) = crate::Cli::try_parse_from(argv).unwrap().command
            else {
                unreachable!()
            };
            let scene = coherent::scene::procedural::cornell();
            r.pvs.settings(&scene).unwrap().border
        };
        assert!(border(&[]));
        assert!(!border(&["--no-cell-border"]));
    }

    /// On a GPU the predicated mode keeps one predicate level unless `--refine-levels` says
    /// otherwise, and queries with tight bounds; every other parameter is the user's.
    #[test]
    fn the_gpu_policy_applies_only_without_refine_levels() {
        let parse = |extra: &[&str]| {
            let mut argv = vec!["coherent", "walk", "--scene", "city", "--batch-size", "7"];
            argv.extend_from_slice(extra);
            match crate::Cli::try_parse_from(argv).unwrap().command {
                crate::Command::Walk(w) => w.chcpp,
                _ => unreachable!(),
            }
        };
        let auto = parse(&[]);
        let cpu = auto.params().unwrap();
        assert_eq!(cpu.predicated_refine_levels, 2);
        let gpu = auto.on_gpu(&cpu);
        assert_eq!(gpu.predicated_refine_levels, 0);
        assert_eq!(gpu.batch_size, 7);
        assert!(gpu.predicated_tight_bounds && !cpu.predicated_tight_bounds);
        let given = parse(&["--refine-levels", "2"]);
        let p = given.params().unwrap();
        assert_eq!(
            given.on_gpu(&p),
            ChcppParams {
                predicated_tight_bounds: true,
                ..p
            }
        );
        // The predicate budget: taken as given, refused when not a finite number >= 0.
        let p = parse(&["--predicate-budget", "32"]).params().unwrap();
        assert_eq!(p.predicated_budget, 32.0);
        assert_eq!(cpu.predicated_budget, 8.0);
        for bad in [
            "--predicate-budget=-1",
            "--predicate-budget=inf",
            "--predicate-budget=NaN",
        ] {
            let err = parse(&[bad]).params().unwrap_err();
            assert!(err.to_string().contains("--predicate-budget"), "{err}");
        }
        // Zero counts and a screen split outside [0, 1] are refused, not quietly changed.
        let argv = ["coherent", "walk", "--scene", "city", "--batch-size", "0"];
        let crate::Command::Walk(w) = crate::Cli::try_parse_from(argv).unwrap().command else {
            unreachable!()
        };
        let err = w.chcpp.params().unwrap_err();
        assert!(err.to_string().contains("--batch-size"), "{err}");
        for (bad, names) in [
            ("--visible-interval=0", "--visible-interval"),
            (
                "--predicated-visible-interval=0",
                "--predicated-visible-interval",
            ),
            ("--screen-split=-0.1", "--screen-split"),
            ("--screen-split=2", "--screen-split"),
            ("--screen-split=NaN", "--screen-split"),
        ] {
            let err = parse(&[bad]).params().unwrap_err();
            assert!(err.to_string().contains(names), "{bad}: {err}");
        }
        assert_eq!(
            parse(&["--screen-split=0"])
                .params()
                .unwrap()
                .predicated_screen_split,
            0.0
        );
        // A leaf holds at least one object.
        let argv = ["coherent", "walk", "--scene", "city", "--leaf-size", "0"];
        let err = crate::Cli::try_parse_from(argv).err().expect("refused");
        assert!(err.to_string().contains("--leaf-size"), "{err}");
    }
}
