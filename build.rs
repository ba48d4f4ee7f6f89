//! Compiles every GLSL shader in shaders/ to Vulkan 1.2 SPIR-V with shaderc. A GLSL error fails
//! the build and names the shader file and line. Code shared between shaders lives in
//! shaders/include/*.glsl, pulled in with `#include "include/x.glsl"` (GL_GOOGLE_include_directive,
//! resolved relative to shaders/); include files are not shader stages and are not compiled alone.

use std::path::Path;

/// Where the shaders are, and what `#include` paths are relative to.
const SHADER_DIR: &str = "shaders";

fn main() {
    let out_dir = std::env::var("OUT_DIR").expect("cargo sets OUT_DIR");
    println!("cargo:rerun-if-changed={SHADER_DIR}");
    let compiler = shaderc::Compiler::new().expect("shaderc compiler");
    let mut options = shaderc::CompileOptions::new().expect("shaderc options");
    options.set_target_env(
        shaderc::TargetEnv::Vulkan,
        shaderc::EnvVersion::Vulkan1_2 as u32,
    );
    options.set_optimization_level(shaderc::OptimizationLevel::Performance);
    options.set_generate_debug_info();
    options.set_include_callback(resolve_include);
    let mut entries: Vec<_> = std::fs::read_dir(SHADER_DIR)
        .expect("shaders/ directory")
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .collect();
    entries.sort();
    let mut failed = false;
    for path in entries {
        // Only stage files; shaders/include/ (a directory, of .glsl files) is skipped here.
        let kind = match path.extension().and_then(|e| e.to_str()) {
            Some("vert") => shaderc::ShaderKind::Vertex,
            Some("frag") => shaderc::ShaderKind::Fragment,
            Some("comp") => shaderc::ShaderKind::Compute,
            Some("geom") => shaderc::ShaderKind::Geometry,
            _ => continue,
        };
        println!("cargo:rerun-if-changed={}", path.display());
        let source = std::fs::read_to_string(&path).expect("readable shader");
        let name = path.display().to_string();
        match compiler.compile_into_spirv(&source, kind, &name, "main", Some(&options)) {
            Ok(artifact) => {
                let file = path.file_name().expect("file name").to_string_lossy();
                let out = Path::new(&out_dir).join(format!("{file}.spv"));
                std::fs::write(out, artifact.as_binary_u8()).expect("write spv");
            }
            Err(e) => {
                // shaderc's messages read "shaders/x.frag:12: error: ...".
                for line in e.to_string().lines() {
                    println!("cargo:warning={line}");
                }
                eprintln!("{e}");
                failed = true;
            }
        }
    }
    if failed {
        panic!("shader compilation failed (see the file:line messages above)");
    }
}

/// shaderc's include callback: `#include "x"` and `#include <x>` both name a file relative to
/// the shaders directory. A file that can't be read gives an error naming the path tried (shaderc
/// prefixes the including file and line, and appends the requested name).
fn resolve_include(
    requested: &str,
    _kind: shaderc::IncludeType,
    _requesting: &str,
    _depth: usize,
) -> shaderc::IncludeCallbackResult {
    let path = Path::new(SHADER_DIR).join(requested);
    match std::fs::read_to_string(&path) {
        Ok(content) => {
            println!("cargo:rerun-if-changed={}", path.display());
            Ok(shaderc::ResolvedInclude {
                resolved_name: path.display().to_string(),
                content,
            })
        }
        Err(e) => Err(format!("cannot read {}: {e}", path.display())),
    }
}
