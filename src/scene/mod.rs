//! Scenes: objects as ranges in one shared vertex and index buffer, with a transform, a base color
//! and world-space bounds; procedural built-in scenes, the glTF loader and camera paths.

use glam::{Mat4, Vec3, Vec4};

pub use coherent_cull::camera::CameraPose;
pub use coherent_cull::Aabb;

/// One vertex of the shared scene vertex buffer (object space).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Vertex {
    pub position: [f32; 3],
    pub normal: [f32; 3],
}

/// One drawable object: a range in the scene's shared index buffer (indices are relative to
/// `vertex_offset`), a transform to world space, a base color and world-space bounds.
#[derive(Clone, Debug)]
pub struct Object {
    pub first_index: u32,
    pub index_count: u32,
    pub vertex_offset: u32,
    pub vertex_count: u32,
    pub transform: Mat4,
    pub color: Vec4,
    pub bounds: Aabb,
    /// Index into `Scene::materials` (texture, alpha mask); `None`: opaque, untextured.
    pub material: Option<u32>,
}

impl Object {
    pub fn triangle_count(&self) -> u64 {
        (self.index_count / 3) as u64
    }
}

/// A named walkthrough: keyframes interpolated over a number of frames.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraPath {
    pub name: String,
    pub keys: Vec<CameraPose>,
}

/// The factors a glTF file's coordinates may be multiplied by when it is loaded (`--scale`):
/// from a model in millimetres to one at 1/1000 of life size.
pub const GLTF_SCALES: std::ops::RangeInclusive<f32> = 0.001..=1000.0;

/// A scene: shared geometry, objects, walkthrough paths and a sun direction.
#[derive(Clone, Debug)]
pub struct Scene {
    pub name: String,
    pub vertices: Vec<Vertex>,
    pub indices: Vec<u32>,
    pub objects: Vec<Object>,
    pub paths: Vec<CameraPath>,
    /// Direction *towards* the directional light, normalized.
    pub sun_dir: Vec3,
    /// Per-vertex texture coordinates and colors, parallel to `vertices`; empty when the scene
    /// has no textures, vertex colors or alpha masks (then it is drawn as before, untextured).
    pub attributes: Vec<VertexAttributes>,
    /// Materials that objects refer to.
    pub materials: Vec<Material>,
    /// Decoded images the textures use.
    pub images: Vec<TextureImage>,
    /// Textures (an image and a sampler) the materials use.
    pub textures: Vec<Texture>,
    /// The objects a glTF file's first animation moves (not in `objects`:
    /// [`Movers::add`](movers::Movers::add) adds them as movers), `None` without any.
    pub animation: Option<std::sync::Arc<animation::Animation>>,
}

pub use material::{
    AlphaMode, Material, SamplerDesc, Texture, TextureImage, VertexAttributes, Wrap,
};

pub mod animation;
pub mod backdrop;
pub mod camera;
pub mod chunk;
pub mod gltf;
mod gltf_draco;
pub mod gltf_ext;
mod gltf_material;
mod gltf_skin;
pub mod interior;
pub mod mask;
pub mod material;
pub mod mesh;
pub mod movers;
pub mod path_check;
pub mod paths;
pub mod procedural;
pub mod raycast;

impl Scene {
    /// Whether the scene has per-vertex material attributes (textures, vertex colors or
    /// alpha masks), so the renderer draws it with its material pipelines.
    pub fn has_materials(&self) -> bool {
        !self.attributes.is_empty()
    }

    /// The material of `object`, if it has one.
    pub fn object_material(&self, object: usize) -> Option<&Material> {
        let m = self.objects.get(object)?.material?;
        self.materials.get(m as usize)
    }

    /// The texture image and sampler of a material, if it has a usable one.
    pub fn material_texture(&self, m: &Material) -> Option<(&TextureImage, &SamplerDesc)> {
        let t = self.textures.get(m.base_color_texture? as usize)?;
        Some((self.images.get(t.image as usize)?, &t.sampler))
    }

    /// Whether `object`'s material is unlit ([`Material::unlit`]): the forward pass draws its
    /// color without the light.
    pub fn is_unlit(&self, object: usize) -> bool {
        self.object_material(object).is_some_and(|m| m.unlit)
    }

    /// Whether `object` is blended ([`Material::blend`]): drawn by the renderer after the
    /// culled pass, and kept out of the culling hierarchy.
    pub fn is_blended(&self, object: usize) -> bool {
        self.object_material(object).is_some_and(|m| m.blend)
    }

    /// The culling hierarchy over the scene's objects (object `i` has id `i`) with at most
    /// `leaf_size` per leaf, blended objects left out: they hide nothing, and the renderer
    /// draws those in the view after the culled pass, back to front.
    pub fn hierarchy(&self, leaf_size: u32) -> coherent_cull::ObjectBvh {
        let bounds: Vec<Aabb> = self.objects.iter().map(|o| o.bounds).collect();
        coherent_cull::ObjectBvh::build_where(&bounds, |o| !self.is_blended(o as usize), leaf_size)
    }

    /// Total triangles over all objects.
    pub fn triangle_count(&self) -> u64 {
        self.objects.iter().map(|o| o.triangle_count()).sum()
    }

    /// The box of all objects' world boxes ([`Aabb::EMPTY`] without objects).
    pub fn bounds(&self) -> Aabb {
        self.objects
            .iter()
            .fold(Aabb::EMPTY, |b, o| b.union(&o.bounds))
    }

    /// The path called `name`, or an error listing the scene's paths.
    pub fn path(&self, name: &str) -> crate::Result<&CameraPath> {
        self.paths.iter().find(|p| p.name == name).ok_or_else(|| {
            crate::Error::Input(format!(
                "scene \"{}\" has no path \"{name}\" (paths: {})",
                self.name,
                self.paths
                    .iter()
                    .map(|p| p.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ))
        })
    }

    /// The first (default) path.
    pub fn default_path(&self) -> crate::Result<&CameraPath> {
        self.paths
            .first()
            .ok_or_else(|| crate::Error::Input(format!("scene \"{}\" has no paths", self.name)))
    }

    /// Multiplies every position of the scene by `factor` (> 0) about the origin: the objects'
    /// transforms and boxes, and the paths' eyes and targets. For a model made in other units
    /// than meters, or at another size than life size (the renderer's near plane is 0.1 and
    /// the interior walk's eye 1.7 units high where the storeys allow).
    pub fn magnify(&mut self, factor: f32) {
        let m = Mat4::from_scale(Vec3::splat(factor));
        for o in &mut self.objects {
            o.transform = m * o.transform;
            o.bounds = Aabb {
                min: o.bounds.min * factor,
                max: o.bounds.max * factor,
            };
        }
        for p in &mut self.paths {
            for k in &mut p.keys {
                k.eye *= factor;
                k.target *= factor;
            }
        }
        if let Some(a) = &mut self.animation {
            std::sync::Arc::make_mut(a).magnify(factor);
        }
    }

    /// Loads a built-in scene by name or a .gltf/.glb file by path (large meshes are split into
    /// chunks of at most `chunk_triangles`). `scale` multiplies a built-in scene's size (its
    /// blocks, rows or rooms; (0, 64]) and a glTF file's coordinates ([`Scene::magnify`];
    /// [`GLTF_SCALES`]). Warnings are printed to stderr.
    pub fn load(name_or_path: &str, scale: f32, chunk_triangles: u32) -> crate::Result<Scene> {
        Scene::load_with(
            name_or_path,
            scale,
            chunk_triangles,
            None,
            &gltf::AnimationChoice::First,
        )
    }

    /// As [`Scene::load`], with the interior walk of a glTF file read from the cache directory
    /// `cache_dir` when it was found there before, and kept there when it is found now (see
    /// [`interior::cache`]; on a real level finding it takes seconds).
    pub fn load_cached(
        name_or_path: &str,
        scale: f32,
        chunk_triangles: u32,
        cache_dir: &std::path::Path,
    ) -> crate::Result<Scene> {
        Scene::load_with(
            name_or_path,
            scale,
            chunk_triangles,
            Some(cache_dir),
            &gltf::AnimationChoice::First,
        )
    }

    /// As [`Scene::load`], with the interior walk kept in `cache_dir` if given (see
    /// [`Scene::load_cached`]), playing the glTF animation `animation` (the file's first by
    /// default; see [`gltf::load_gltf_playing`]). A built-in scene takes only the default.
    pub fn load_with(
        name_or_path: &str,
        scale: f32,
        chunk_triangles: u32,
        cache_dir: Option<&std::path::Path>,
        animation: &gltf::AnimationChoice,
    ) -> crate::Result<Scene> {
        let lower = name_or_path.to_lowercase();
        let is_gltf = lower.ends_with(".gltf") || lower.ends_with(".glb");
        if !is_gltf && *animation != gltf::AnimationChoice::First {
            return Err(crate::Error::Input(format!(
                "--animation picks one of a glTF file's animations; \"{name_or_path}\" is a \
                 built-in scene (its movers come with --movers)"
            )));
        }
        if is_gltf {
            if !(scale.is_finite() && GLTF_SCALES.contains(&scale)) {
                return Err(crate::Error::Input(format!(
                    "scale {scale} is out of range for a glTF file ({} to {}: it multiplies \
                     the file's coordinates)",
                    GLTF_SCALES.start(),
                    GLTF_SCALES.end()
                )));
            }
            let (mut scene, warnings) =
                gltf::load_gltf_playing(std::path::Path::new(name_or_path), animation)?;
            for w in warnings {
                eprintln!("warning: {w}");
            }
            if scale != 1.0 {
                scene.magnify(scale);
            }
            chunk::split_large_objects(&mut scene, chunk_triangles);
            let backdrop = backdrop::find(&scene);
            if let Some(b) = &backdrop {
                eprintln!("note: {}", b.note(&scene.name));
            }
            if scale != 1.0 || backdrop.is_some() {
                gltf::refit_default_path(&mut scene, backdrop.map(|b| b.rest));
            }
            match cache_dir {
                Some(dir) => {
                    interior::default_if_enclosed_cached(&mut scene, dir);
                }
                None => interior::default_if_enclosed(&mut scene),
            }
            Ok(scene)
        } else {
            procedural::build(name_or_path, scale)
        }
    }
}
