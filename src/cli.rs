//! Flag parsing and the commands of the `coherent` binary. Thin: all work is in the library.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{bail, Context, Result};
use clap::Args;

use coherent::bvh::ObjectBvh;
use coherent::culling::{self, ChcppParams};
use coherent::gpu::{ContextOptions, GpuContext};
use coherent::render::Renderer;
use coherent::scene::Scene;

/// Flags shared by commands that load a scene.
#[derive(Args, Clone, Debug)]
pub struct SceneArgs {
    /// Built-in scene (city, parking, powerplant, cornell, hall) or a .gltf/.glb path.
    #[arg(long)]
    pub scene: String,
    /// Size multiplier of a built-in scene (1 = default).
    #[arg(long, default_value_t = 1.0)]
    pub scale: f32,
    /// Split glTF meshes into chunks of at most this many triangles (0: don't split).
    #[arg(long, default_value_t = 4096)]
    pub chunk_triangles: u32,
    /// Objects per BVH leaf.
    #[arg(long, default_value_t = 1)]
    pub leaf_size: u32,
}

/// `coherent render`.
#[derive(Args, Debug)]
pub struct RenderArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Image size WxH.
    #[arg(long, default_value = "1280x720")]
    pub size: String,
    /// Culling algorithm (vfc, stop-and-wait, chc, chcpp, oracle).
    #[arg(long, default_value = "vfc")]
    pub algorithm: String,
    /// Frame of the scene's default path (temporal algorithms render frames 0..=N).
    #[arg(long, default_value_t = 0)]
    pub frame: u32,
    /// Camera path (default: the scene's first path).
    #[arg(long)]
    pub path: Option<String>,
    /// Output PNG.
    #[arg(long)]
    pub out: PathBuf,
    /// Turn the validation layer off (it is on by default for render).
    #[arg(long)]
    pub no_validation: bool,
}

/// `coherent walk`.
#[derive(Args, Debug)]
pub struct WalkArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
}

/// Parses "WxH".
pub fn parse_size(s: &str) -> Result<(u32, u32)> {
    let (w, h) = s.split_once(['x', 'X']).with_context(|| format!("size \"{s}\" is not WxH"))?;
    let w: u32 = w.trim().parse().with_context(|| format!("size \"{s}\": bad width"))?;
    let h: u32 = h.trim().parse().with_context(|| format!("size \"{s}\": bad height"))?;
    if w == 0 || h == 0 || w > 16384 || h > 16384 {
        bail!("size {w}x{h} is out of range (1..16384)");
    }
    Ok((w, h))
}

fn context(validation: bool) -> Result<Arc<GpuContext>> {
    Ok(GpuContext::new(&ContextOptions { validation, echo_validation: true, ..Default::default() })?)
}

fn load_scene(a: &SceneArgs) -> Result<Scene> {
    Ok(Scene::load(&a.scene, a.scale, a.chunk_triangles)?)
}

fn check_validation(ctx: &GpuContext) -> Result<()> {
    let n = ctx.validation_log().count();
    if n > 0 {
        bail!("the validation layer reported {n} messages (printed above)");
    }
    Ok(())
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
    println!("features used:   {} (all present)", coherent::gpu::context::REQUIRED_FEATURES.join(", "));
    Ok(())
}

/// `coherent render`.
pub fn render(a: &RenderArgs) -> Result<()> {
    let (w, h) = parse_size(&a.size)?;
    let mut culler = culling::create(&a.algorithm, &ChcppParams::default())?;
    let scene = load_scene(&a.scene)?;
    let path = match &a.path {
        Some(p) => scene.path(p)?.clone(),
        None => scene.default_path()?.clone(),
    };
    let bounds: Vec<_> = scene.objects.iter().map(|o| o.bounds).collect();
    let bvh = ObjectBvh::build(&bounds, a.scene.leaf_size);
    let ctx = context(!a.no_validation)?;
    {
        let mut renderer = Renderer::new(&ctx, &scene, w, h)?;
        let first = if culler.needs_exact_visibility() || a.algorithm == "vfc" { a.frame } else { 0 };
        let mut last = None;
        for f in first..=a.frame {
            let cam = renderer.camera(path.pose_at(f as f32), &bvh);
            last = Some(renderer.render_frame(culler.as_mut(), &bvh, &cam, f as u64)?);
        }
        renderer.save_png(&a.out).with_context(|| format!("writing {}", a.out.display()))?;
        if let Some(r) = last {
            println!(
                "{}: {} frame {} with {}: {:.1} ms, {} draws, {} triangles, {} queries, {} state changes -> {}",
                scene.name,
                path.name,
                a.frame,
                culler.name(),
                r.frame_ms,
                r.counts.draw_calls,
                r.counts.render_triangles,
                r.counts.queries_begun,
                r.counts.state_changes,
                a.out.display()
            );
        }
    }
    check_validation(&ctx)
}

/// `coherent walk`.
pub fn walk(_a: &WalkArgs) -> Result<()> {
    bail!("walk is not implemented yet")
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
    /// incremental, full or both.
    #[arg(long, default_value = "both")]
    pub mode: String,
    /// Shadow-map resolution (per VPL layer).
    #[arg(long, default_value_t = 256)]
    pub shadow_size: u32,
    /// Output directory (PNGs and summary.json).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Turn the validation layer on.
    #[arg(long)]
    pub validation: bool,
}

/// `coherent gi`.
pub fn gi(a: &GiArgs) -> Result<()> {
    use coherent::gi::session::{self, GiMode, GiRunOptions};
    let (width, height) = parse_size(&a.size)?;
    let modes = GiMode::parse_list(&a.mode)?;
    if a.vpls == 0 || a.budget == 0 || a.frames == 0 || a.shadow_size == 0 {
        bail!("--vpls, --budget, --frames and --shadow-size must be positive");
    }
    let scene = load_scene(&a.scene)?;
    let ctx = context(a.validation)?;
    let opts = GiRunOptions {
        vpls: a.vpls,
        budget: a.budget,
        frames: a.frames,
        width,
        height,
        modes,
        shadow_size: a.shadow_size,
        sample_frames: 5,
    };
    let summary = session::run(&ctx, &scene, &opts, a.out.as_deref())?;
    print!("{}", summary.table());
    if let Some(dir) = &a.out {
        println!("wrote {}", dir.display());
    }
    check_validation(&ctx)
}
