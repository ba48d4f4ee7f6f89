//! The `coherent` command line: thin; parses flags and calls the library.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod cli;
mod cli_common;
mod cli_setup;

#[derive(Parser)]
#[command(
    name = "coherent",
    version,
    about = "Temporal coherence in object space on raw Vulkan: CHC++ occlusion culling and incremental instant radiosity"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print the chosen Vulkan device, driver, version and the features coherent relies on.
    Info,
    /// Render one frame of a scene's default path to a PNG.
    Render(cli::RenderArgs),
    /// Walk a camera path with several culling algorithms side by side; write a report and plots.
    Walk(cli::WalkArgs),
    /// Incremental instant radiosity vs full recompute along a moving spotlight; PNGs and a report.
    Gi(cli::GiArgs),
    /// Open a window: fly camera, path playback, live algorithm switching, stats overlay.
    View(cli::ViewArgs),
    /// Measure the device's costs for NOHC (draw, triangle, fragment, query, round trip).
    Calibrate(cli_setup::CalibrateArgs),
    /// Precompute the potentially visible sets of a scene's path (cached).
    Pvs(cli_setup::PvsCommandArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Info => cli::info(),
        Command::Render(a) => cli::render(&a),
        Command::Walk(a) => cli::walk(&a),
        Command::Gi(a) => cli::gi(&a),
        Command::View(a) => cli::view(&a),
        Command::Calibrate(a) => cli_setup::calibrate_command(&a),
        Command::Pvs(a) => cli_setup::pvs_command(&a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // One line: the chain of causes, no backtrace.
            let msg: Vec<String> = e.chain().map(|c| c.to_string()).collect();
            eprintln!("error: {}", msg.join(": "));
            ExitCode::FAILURE
        }
    }
}
