//! What the commands share: the scene flags, the device context, loading a scene, the
//! validation check at the end of a command, progress bars.

use std::path::Path;
use std::sync::Arc;

use anyhow::{bail, Result};
use clap::Args;

use coherent::gpu::{ContextOptions, GpuContext};
use coherent::scene::gltf::AnimationChoice;
use coherent::scene::Scene;

/// Flags shared by commands that load a scene.
#[derive(Args, Clone, Debug)]
pub struct SceneArgs {
    /// Built-in scene (city, parking, powerplant, cornell, hall) or a .gltf/.glb path.
    #[arg(long)]
    pub scene: String,
    /// Size multiplier (1 = default): a built-in scene grows (more blocks, rows or rooms; up to
    /// 64), a glTF file's coordinates are multiplied (for a model not in meters at life size;
    /// 0.001 to 1000). `walk` takes a list (e.g. 1,4,16) and adds a scaling table.
    #[arg(long, default_value = "1", value_delimiter = ',')]
    pub scale: Vec<f32>,
    /// Split glTF meshes into chunks of at most this many triangles (0: don't split).
    #[arg(long, default_value_t = 4096)]
    pub chunk_triangles: u32,
    /// Objects per BVH leaf (at least 1).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub leaf_size: u32,
    /// A glTF file's animation to play, by index or name, or `none` (every object static);
    /// the file's first by default. Its moving objects are movers.
    #[arg(long, value_name = "INDEX|NAME|none")]
    pub animation: Option<AnimationChoice>,
}

/// The Vulkan context, echoing validation messages as they come.
pub fn context(validation: bool) -> Result<Arc<GpuContext>> {
    Ok(GpuContext::new(&ContextOptions {
        validation,
        echo_validation: true,
        ..Default::default()
    })?)
}

/// The scene of the flags at `scale`; the interior walk of a glTF file is kept in
/// `cache_dir`.
pub fn load_scene(a: &SceneArgs, scale: f32, cache_dir: &Path) -> Result<Scene> {
    Ok(Scene::load_with(
        &a.scene,
        scale,
        a.chunk_triangles,
        Some(cache_dir),
        &a.animation.clone().unwrap_or_default(),
    )?)
}

/// Most `--movers`: each costs about 0.8 KB of host memory, and ten million took 7.7 GB
/// before the device refused their per-object buffer.
pub const MAX_MOVERS: usize = 2_000_000;

/// `--movers N`: a count of at most [`MAX_MOVERS`].
pub fn movers_count(s: &str) -> Result<usize, String> {
    let n: usize = s.parse().map_err(|_| format!("\"{s}\" is not a count"))?;
    if n > MAX_MOVERS {
        return Err(format!("{n} is more than {MAX_MOVERS} movers"));
    }
    Ok(n)
}

/// The one `--scale` of a command that takes no list.
pub fn single_scale(a: &SceneArgs) -> Result<f32> {
    match a.scale.as_slice() {
        [s] => Ok(*s),
        _ => bail!("this command takes one --scale value"),
    }
}

/// Fails when the validation layer reported anything (the messages were printed).
pub fn check_validation(ctx: &GpuContext) -> Result<()> {
    let n = ctx.validation_log().count();
    if n > 0 {
        bail!("the validation layer reported {n} messages (printed above)");
    }
    Ok(())
}

/// A progress bar on a terminal, plain lines otherwise.
pub struct Progress {
    bar: Option<indicatif::ProgressBar>,
    last: std::cell::Cell<u64>,
    unit: &'static str,
}

/// A progress bar counting frames.
pub fn progress_bar() -> Progress {
    progress_bar_named("frames")
}

/// A progress bar counting `unit`s.
pub fn progress_bar_named(unit: &'static str) -> Progress {
    use std::io::IsTerminal;
    let bar = std::io::stderr().is_terminal().then(|| {
        let b = indicatif::ProgressBar::new(1);
        if let Ok(style) = indicatif::ProgressStyle::with_template(&format!(
            "{{bar:40}} {{pos}}/{{len}} {unit} {{elapsed}} (eta {{eta}})"
        )) {
            b.set_style(style);
        }
        b
    });
    Progress {
        bar,
        last: std::cell::Cell::new(0),
        unit,
    }
}

impl Progress {
    pub fn tick(&self, done: u64, total: u64) {
        match &self.bar {
            Some(b) => {
                b.set_length(total);
                b.set_position(done);
            }
            None => {
                let pct = done * 10 / total.max(1);
                if pct > self.last.get() {
                    self.last.set(pct);
                    eprintln!("{done}/{total} {}", self.unit);
                }
            }
        }
    }
    pub fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}
