//! The interior walk kept in a cache directory. Finding the walk casts millions of rays
//! (seconds on a real level: about 10 s for the Sibenik cathedral on two cores), and what it
//! finds depends only on the scene's geometry and flat colours, the [`InteriorParams`] and
//! the code that finds it. So a command that meets the same scene again (a glTF file's
//! default walk, or `--path interior` on a scene without it) reads the walk (or the reason
//! there is none) from one small JSON file instead:
//!
//! ```json
//! { "key": "interior v1;code=…;scene=…;params=…",
//!   "camera": [[ex, ey, ez, tx, ty, tz], …], "light": [[…], …] }
//! ```
//!
//! or `"no_inside": "<why>"` in place of the two paths. The key names a hash of the code
//! (the walk's source files, hashed when the program is compiled), of the scene (vertices,
//! indices, colours, objects, materials, the sun) and the parameters; the file's name is a
//! hash of the key, and a file whose key differs is not used. A file that cannot be read or
//! trusted is replaced, with one line on stderr saying why; a cache that cannot be written
//! costs only the time.

use std::hash::{Hash, Hasher};
use std::path::{Path, PathBuf};

use glam::Vec3;
use serde_json::{json, Value};

use super::{InteriorParams, LIGHT_PATH_NAME, PATH_NAME};
use crate::culling::pvs::fnv1a;
use crate::scene::{CameraPath, CameraPose, Scene};
use crate::Error;

/// The source files whose code decides the walk and the path check; any change to them gives
/// new keys.
const SOURCES: [&[u8]; 7] = [
    include_bytes!("mod.rs"),
    include_bytes!("../backdrop.rs"),
    include_bytes!("places.rs"),
    include_bytes!("rays.rs"),
    include_bytes!("walk.rs"),
    include_bytes!("../path_check.rs"),
    include_bytes!("../camera.rs"),
];

/// FNV-1a of `SOURCES`, computed by the compiler.
pub(crate) const CODE_HASH: u64 = {
    let mut h = FNV_BASIS;
    let mut f = 0;
    while f < SOURCES.len() {
        h = fnv_extend(h, SOURCES[f]);
        f += 1;
    }
    h
};

/// FNV-1a's offset basis (that of [`fnv1a`]).
const FNV_BASIS: u64 = 0xcbf2_9ce4_8422_2325;

/// FNV-1a from state `h` over `bytes` ([`fnv1a`] is this from [`FNV_BASIS`]), usable where
/// the compiler evaluates it.
const fn fnv_extend(mut h: u64, bytes: &[u8]) -> u64 {
    let mut i = 0;
    while i < bytes.len() {
        h ^= bytes[i] as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
        i += 1;
    }
    h
}

/// Most keys of a cached path (a walk has a few hundred).
const MAX_KEYS: usize = 1 << 16;
/// Longest reason for no inside a cache file may hold.
const MAX_WHY: usize = 4096;

/// A [`Hasher`] stable across builds and platforms (unlike the standard one) that takes
/// eight bytes per step: each word is mixed in by a multiply and a rotation (the constants of
/// splitmix64), the bytes left over one by one, and [`finish`](Hasher::finish) mixes once
/// more. Also the hasher of GI's vertex keys (`gi::geometry`), where SipHash was slow.
pub(crate) struct Words(u64);

impl Words {
    pub(crate) fn new() -> Words {
        Words(FNV_BASIS)
    }

    fn mix(&mut self, w: u64) {
        self.0 = (self.0 ^ w)
            .wrapping_mul(0x9e37_79b9_7f4a_7c15)
            .rotate_left(29);
    }
}

impl Default for Words {
    fn default() -> Words {
        Words::new()
    }
}

impl Hasher for Words {
    fn write(&mut self, bytes: &[u8]) {
        let mut words = bytes.chunks_exact(8);
        for w in &mut words {
            self.mix(u64::from_le_bytes(w.try_into().expect("eight bytes")));
        }
        for &b in words.remainder() {
            self.mix(u64::from(b));
        }
    }

    fn finish(&self) -> u64 {
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
}

/// Hashes the bits of `v`.
fn floats(h: &mut Words, v: &[f32]) {
    for f in v {
        f.to_bits().hash(h);
    }
}

/// What finding the walk gave: the walk and its light path, or why the scene has no inside.
#[derive(Clone, Debug, PartialEq)]
pub enum Outcome {
    /// The walk ([`PATH_NAME`]) and the light path that goes with it ([`LIGHT_PATH_NAME`]).
    Walk {
        camera: CameraPath,
        light: CameraPath,
    },
    /// No inside, and why (the note printed when the orbit stays the default path).
    NoInside(String),
}

/// Where a cached value (an interior walk's outcome, a path check's verdict) came from.
#[derive(Clone, Debug, PartialEq)]
pub enum Source {
    /// Read from this file.
    Cached(PathBuf),
    /// Found (or checked) now; kept in this file (`None`: it could not be written, a warning
    /// said why).
    Found(Option<PathBuf>),
}

/// The cache key of `scene`'s walk with `params`: the code, the scene and the parameters.
pub fn key(scene: &Scene, params: &InteriorParams) -> String {
    format!(
        "interior v2;code={CODE_HASH:016x};scene={:016x};params={params:?}",
        scene_hash(scene)
    )
}

/// A hash of everything in `scene` that the interior walk and the path check look at:
/// vertices, indices, vertex colours, objects (ranges, transforms, colours, materials), what
/// of the materials they read, and the sun. Stable across builds and platforms; it reads the
/// large arrays eight bytes at a time (0.03 s for the city at scale 16, whose 216,385
/// objects instance a few meshes).
pub fn scene_hash(scene: &Scene) -> u64 {
    let mut h = Words::new();
    bytemuck::cast_slice::<_, u8>(&scene.vertices).hash(&mut h);
    scene.indices.hash(&mut h);
    bytemuck::cast_slice::<_, u8>(&scene.attributes).hash(&mut h);
    scene.objects.len().hash(&mut h);
    for o in &scene.objects {
        (
            o.first_index,
            o.index_count,
            o.vertex_offset,
            o.vertex_count,
        )
            .hash(&mut h);
        floats(&mut h, &o.transform.to_cols_array());
        floats(&mut h, &o.color.to_array());
        o.material.hash(&mut h);
    }
    scene.materials.len().hash(&mut h);
    for m in &scene.materials {
        m.base_color_texture.is_some().hash(&mut h);
        m.double_sided.hash(&mut h);
    }
    floats(&mut h, &scene.sun_dir.to_array());
    h.finish()
}

/// A hash of a camera path: its name and its keys' bits.
pub fn path_hash(path: &CameraPath) -> u64 {
    let mut h = Words::new();
    path.name.hash(&mut h);
    path.keys.len().hash(&mut h);
    for k in &path.keys {
        floats(&mut h, &k.eye.to_array());
        floats(&mut h, &k.target.to_array());
    }
    h.finish()
}

/// The cache file of `key` in `dir`.
pub fn file(dir: &Path, key: &str) -> PathBuf {
    dir.join(format!("interior-{:016x}.json", fnv1a(key.as_bytes())))
}

/// Reads the outcome kept for `key` in `file`: `Ok(None)` when there is no file, an error
/// saying why when it exists but cannot be used (unreadable, not this format, another key,
/// numbers that are not finite, too many keys).
pub fn load(file: &Path, key: &str) -> Result<Option<Outcome>, Error> {
    load_with(file, key, parse)
}

/// What `parse` reads for `key` from the text of `file`: `Ok(None)` when there is no file, an
/// error naming the file and saying why when it exists but cannot be used. The reading of
/// every cache file of this kind (the interior walk's, the path check's).
pub(crate) fn load_with<T>(
    file: &Path,
    key: &str,
    parse: impl FnOnce(&str, &str) -> Result<T, String>,
) -> Result<Option<T>, Error> {
    let text = match std::fs::read_to_string(file) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(Error::Input(format!("{}: {e}", file.display()))),
    };
    parse(&text, key)
        .map(Some)
        .map_err(|why| Error::Input(format!("{}: {why}", file.display())))
}

/// The value kept in `file` (read by `load`), or, when there is none or it cannot be used
/// (one line on stderr says why), the value `make` makes now, kept in `file` by `save` (one
/// line on stderr when it cannot be: then it costs only the time). `what` names the value in
/// those lines ("the interior walk"), `again` says what happens instead of using a file that
/// cannot be ("finding the interior walk again"). `None` when `make` has nothing.
pub(crate) fn kept_or_made<T>(
    file: PathBuf,
    load: impl FnOnce(&Path) -> Result<Option<T>, Error>,
    make: impl FnOnce() -> Option<T>,
    save: impl FnOnce(&Path, &T) -> std::io::Result<()>,
    (what, again): (&str, &str),
) -> Option<(T, Source)> {
    match load(&file) {
        Ok(Some(value)) => return Some((value, Source::Cached(file))),
        Ok(None) => {}
        Err(why) => eprintln!("warning: {why}; {again}"),
    }
    let value = make()?;
    let kept = match save(&file, &value) {
        Ok(()) => Some(file),
        Err(e) => {
            eprintln!("warning: {}: {e}; {what} is not cached", file.display());
            None
        }
    };
    Some((value, Source::Found(kept)))
}

/// The outcome in a cache file's `text`, made for `key`.
pub fn parse(text: &str, key: &str) -> Result<Outcome, String> {
    let v: Value = serde_json::from_str(text).map_err(|e| format!("not JSON: {e}"))?;
    match v.get("key").and_then(Value::as_str) {
        Some(k) if k == key => {}
        Some(_) => return Err("made for another scene, parameters or version".into()),
        None => return Err("no \"key\" string".into()),
    }
    if let Some(why) = v.get("no_inside") {
        let why = why.as_str().ok_or("\"no_inside\" is not a string")?;
        if why.len() > MAX_WHY || why.contains('\n') {
            return Err("\"no_inside\" is not one short line".into());
        }
        return Ok(Outcome::NoInside(why.to_string()));
    }
    let camera = poses(&v, "camera")?;
    let light = poses(&v, "light")?;
    if camera.is_empty() || camera.len() != light.len() {
        return Err(format!(
            "{} camera keys and {} light keys (one each, at least one)",
            camera.len(),
            light.len()
        ));
    }
    Ok(Outcome::Walk {
        camera: CameraPath {
            name: PATH_NAME.to_string(),
            keys: camera,
        },
        light: CameraPath {
            name: LIGHT_PATH_NAME.to_string(),
            keys: light,
        },
    })
}

/// The poses of array `name`: each six finite numbers, eye then target.
fn poses(v: &Value, name: &str) -> Result<Vec<CameraPose>, String> {
    let list = v
        .get(name)
        .and_then(Value::as_array)
        .ok_or_else(|| format!("no \"{name}\" array"))?;
    if list.len() > MAX_KEYS {
        return Err(format!(
            "\"{name}\" has {} keys (at most {MAX_KEYS})",
            list.len()
        ));
    }
    list.iter()
        .enumerate()
        .map(|(i, k)| {
            let n: Vec<f32> = k
                .as_array()
                .filter(|a| a.len() == 6)
                .and_then(|a| a.iter().map(|x| x.as_f64().map(|x| x as f32)).collect())
                .filter(|n: &Vec<f32>| n.iter().all(|x| x.is_finite()))
                .ok_or_else(|| format!("\"{name}\" key {i} is not six finite numbers"))?;
            Ok(CameraPose {
                eye: Vec3::new(n[0], n[1], n[2]),
                target: Vec3::new(n[3], n[4], n[5]),
            })
        })
        .collect()
}

/// The text of the cache file of `outcome` for `key`.
pub fn to_json(outcome: &Outcome, key: &str) -> String {
    let poses = |p: &CameraPath| -> Vec<Value> {
        p.keys
            .iter()
            .map(|k| json!([k.eye.x, k.eye.y, k.eye.z, k.target.x, k.target.y, k.target.z]))
            .collect()
    };
    match outcome {
        Outcome::Walk { camera, light } => {
            json!({ "key": key, "camera": poses(camera), "light": poses(light) })
        }
        Outcome::NoInside(why) => json!({ "key": key, "no_inside": why }),
    }
    .to_string()
}

/// Writes `outcome` for `key` to `file` (through a temporary file, so that a crash or a
/// second process never leaves half a file).
pub fn save(file: &Path, key: &str, outcome: &Outcome) -> std::io::Result<()> {
    write_whole(file, &to_json(outcome, key))
}

/// Writes `text` to `file`, creating its directory, through a temporary file and a rename so
/// that a crash or a second process never leaves half a file.
pub(crate) fn write_whole(file: &Path, text: &str) -> std::io::Result<()> {
    if let Some(dir) = file.parent() {
        std::fs::create_dir_all(dir)?;
    }
    let tmp = file.with_extension(format!("{}.tmp", std::process::id()));
    std::fs::write(&tmp, text)?;
    std::fs::rename(&tmp, file).inspect_err(|_| {
        let _ = std::fs::remove_file(&tmp);
    })
}

#[cfg(test)]
mod tests {
    /// The compile-time FNV-1a is the project's [`fnv1a`](super::fnv1a), so cache file names
    /// stay those of the PVS's hash.
    #[test]
    fn the_const_hash_is_fnv1a() {
        for bytes in [&b""[..], b"a", b"interior v1;code=0"] {
            assert_eq!(
                super::fnv_extend(super::FNV_BASIS, bytes),
                super::fnv1a(bytes)
            );
        }
    }
}
