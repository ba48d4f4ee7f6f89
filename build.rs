//! Compiles every GLSL shader in shaders/ to Vulkan 1.2 SPIR-V with shaderc. A GLSL error fails
//! the build and names the shader file and line.

use std::path::Path;

fn main() {
    let out_dir = std::env::var("OUT_DIR").expect("cargo sets OUT_DIR");
    println!("cargo:rerun-if-changed=shaders");
    let compiler = shaderc::Compiler::new().expect("shaderc compiler");
    let mut options = shaderc::CompileOptions::new().expect("shaderc options");
    options.set_target_env(
        shaderc::TargetEnv::Vulkan,
        shaderc::EnvVersion::Vulkan1_2 as u32,
    );
    options.set_optimization_level(shaderc::OptimizationLevel::Performance);
    options.set_generate_debug_info();
    let mut entries: Vec<_> = std::fs::read_dir("shaders")
        .expect("shaders/ directory")
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .collect();
    entries.sort();
    let mut failed = false;
    for path in entries {
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
