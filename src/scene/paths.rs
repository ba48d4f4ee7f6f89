//! Path files: one JSON format for camera paths and light paths (keyframes with a time, a
//! position and either a point looked at or an orientation quaternion), read with one-line
//! errors naming the file and the problem, written back for round trips and recordings.
//!
//! ```json
//! { "keys": [
//!     { "time": 0.0, "position": [0, 1.7, 0], "look_at": [0, 1.7, -1] },
//!     { "time": 2.5, "position": [4, 1.7, 0], "orientation": [0, 0.7071, 0, 0.7071] } ] }
//! ```
//!
//! `time` is in seconds and strictly increasing; `orientation` is a unit quaternion
//! `[x, y, z, w]` rotating the glTF camera's forward axis (-Z) into the view direction. A light
//! path uses the same keys: the light sits at `position` and points where the key looks.

use std::path::Path;

use glam::{Quat, Vec3};
use serde_json::Value;

use super::camera::FRAMES_PER_KEY;
use super::{CameraPath, CameraPose};
use crate::Error;

/// Most keys a path file's keys are resampled to.
const MAX_RESAMPLED_KEYS: usize = 4096;

/// One keyframe: where the camera (or light) is at `time` and the point it looks at.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathKey {
    /// Seconds from the start of the path.
    pub time: f32,
    /// Eye (or light) position.
    pub position: Vec3,
    /// A point on the view (or light) axis in front of `position`.
    pub target: Vec3,
}

/// Reads a path file. Any problem (unreadable, not JSON, missing or mistyped keys, non-finite
/// numbers, fewer than two keys, times not increasing) is [`Error::Input`] with one line
/// `"<file>: <problem>"`.
pub fn read_path_file(file: &Path) -> Result<Vec<PathKey>, Error> {
    let text = std::fs::read_to_string(file)
        .map_err(|e| format!("cannot read path file: {e}"))
        .and_then(|t| parse_keys(&t));
    text.map_err(|problem| {
        Error::Input(format!(
            "{}: {}",
            file.display(),
            problem.replace(['\n', '\r'], " ")
        ))
    })
}

/// Parses the JSON text of a path file into its keys.
pub fn parse_keys(text: &str) -> Result<Vec<PathKey>, String> {
    let root: Value = serde_json::from_str(text).map_err(|e| format!("invalid JSON: {e}"))?;
    let keys = root
        .get("keys")
        .ok_or("missing \"keys\" (an array of keyframes)")?
        .as_array()
        .ok_or("\"keys\" is not an array")?;
    if keys.len() < 2 {
        return Err(format!(
            "a path needs at least 2 keys, the file has {}",
            keys.len()
        ));
    }
    let parsed = keys
        .iter()
        .enumerate()
        .map(|(i, k)| parse_key(k).map_err(|e| format!("key {i}: {e}")))
        .collect::<Result<Vec<_>, _>>()?;
    for (i, w) in parsed.windows(2).enumerate() {
        if w[1].time <= w[0].time {
            return Err(format!(
                "key {}: time {} is not after the previous key's {}",
                i + 1,
                w[1].time,
                w[0].time
            ));
        }
    }
    Ok(parsed)
}

fn parse_key(k: &Value) -> Result<PathKey, String> {
    if !k.is_object() {
        return Err("is not an object".into());
    }
    let time = number(k, "time")?.ok_or("missing \"time\"")?;
    let position = vec3(k, "position")?.ok_or("missing \"position\"")?;
    let look_at = vec3(k, "look_at")?;
    let orientation = quat(k)?;
    let target = match (look_at, orientation) {
        (Some(_), Some(_)) => return Err("has both \"look_at\" and \"orientation\"".into()),
        (Some(t), None) => t,
        (None, Some(q)) => position + q * Vec3::NEG_Z,
        (None, None) => return Err("needs \"look_at\" or \"orientation\"".into()),
    };
    if (target - position).length_squared() < 1e-12 {
        return Err("\"look_at\" is the position itself (no view direction)".into());
    }
    Ok(PathKey {
        time,
        position,
        target,
    })
}

fn finite(v: &Value, what: &str) -> Result<f32, String> {
    let x = v
        .as_f64()
        .ok_or_else(|| format!("{what} is not a number ({v})"))?;
    let f = x as f32;
    if !f.is_finite() {
        return Err(format!("{what} is not a finite 32-bit number ({x})"));
    }
    Ok(f)
}

fn number(k: &Value, name: &str) -> Result<Option<f32>, String> {
    k.get(name)
        .map(|v| finite(v, &format!("\"{name}\"")))
        .transpose()
}

fn array<const N: usize>(k: &Value, name: &str) -> Result<Option<[f32; N]>, String> {
    let Some(v) = k.get(name) else {
        return Ok(None);
    };
    let a = v
        .as_array()
        .filter(|a| a.len() == N)
        .ok_or_else(|| format!("\"{name}\" is not an array of {N} numbers"))?;
    let mut out = [0.0; N];
    for (i, x) in a.iter().enumerate() {
        out[i] = finite(x, &format!("\"{name}\"[{i}]"))?;
    }
    Ok(Some(out))
}

fn vec3(k: &Value, name: &str) -> Result<Option<Vec3>, String> {
    Ok(array::<3>(k, name)?.map(Vec3::from_array))
}

fn quat(k: &Value) -> Result<Option<Quat>, String> {
    let Some(q) = array::<4>(k, "orientation")? else {
        return Ok(None);
    };
    let q = Quat::from_array(q);
    let len = q.length();
    if (len - 1.0).abs() > 1e-2 {
        return Err(format!(
            "\"orientation\" is not a unit quaternion (length {len})"
        ));
    }
    Ok(Some(q.normalize()))
}

/// The keys as a [`CameraPath`] named `name` whose uniformly spaced keys (one per
/// [`FRAMES_PER_KEY`] frames) follow the keys' timing: keys with equal time steps are taken
/// as they are, others are resampled at the smallest time step (Catmull-Rom in time).
pub fn keys_to_path(name: &str, keys: &[PathKey]) -> CameraPath {
    let poses: Vec<CameraPose> = keys
        .iter()
        .map(|k| CameraPose {
            eye: k.position,
            target: k.target,
        })
        .collect();
    if keys.len() < 2 {
        return CameraPath {
            name: name.to_string(),
            keys: poses,
        };
    }
    let gaps: Vec<f32> = keys.windows(2).map(|w| w[1].time - w[0].time).collect();
    let min_gap = gaps.iter().copied().fold(f32::INFINITY, f32::min);
    let max_gap = gaps.iter().copied().fold(0.0, f32::max);
    if max_gap - min_gap <= 1e-4 * max_gap {
        return CameraPath {
            name: name.to_string(),
            keys: poses,
        };
    }
    let (t0, t1) = (keys[0].time, keys[keys.len() - 1].time);
    let steps = (((t1 - t0) / min_gap).round() as usize).clamp(keys.len() - 1, MAX_RESAMPLED_KEYS);
    let resampled = (0..=steps)
        .map(|s| pose_at_time(keys, t0 + (t1 - t0) * s as f32 / steps as f32))
        .collect();
    CameraPath {
        name: name.to_string(),
        keys: resampled,
    }
}

/// The pose at `time` on timed keys (non-uniform Catmull-Rom through the key poses, as the
/// uniform one on the segment's neighbours).
fn pose_at_time(keys: &[PathKey], time: f32) -> CameraPose {
    let i = keys
        .windows(2)
        .position(|w| time <= w[1].time)
        .unwrap_or(keys.len() - 2);
    let (a, b) = (keys[i].time, keys[i + 1].time);
    let f = ((time - a) / (b - a).max(1e-9)).clamp(0.0, 1.0);
    let local = CameraPath {
        name: String::new(),
        keys: (i as isize - 1..=i as isize + 2)
            .map(|k| {
                let k = keys[k.clamp(0, keys.len() as isize - 1) as usize];
                CameraPose {
                    eye: k.position,
                    target: k.target,
                }
            })
            .collect(),
    };
    local.pose_at((1.0 + f) * FRAMES_PER_KEY)
}

/// The keys of `path` with one second per key (the time at which a walk at 30 frames per
/// second passes them).
pub fn path_to_keys(path: &CameraPath) -> Vec<PathKey> {
    path.keys
        .iter()
        .enumerate()
        .map(|(i, k)| PathKey {
            time: i as f32 * FRAMES_PER_KEY / 30.0,
            position: k.eye,
            target: k.target,
        })
        .collect()
}

/// The JSON text of a path file holding `keys`.
pub fn keys_to_json(keys: &[PathKey]) -> String {
    let keys: Vec<Value> = keys
        .iter()
        .map(|k| {
            serde_json::json!({
                "time": k.time,
                "position": k.position.to_array(),
                "look_at": k.target.to_array(),
            })
        })
        .collect();
    let doc = serde_json::json!({ "keys": keys });
    serde_json::to_string_pretty(&doc).unwrap_or_default()
}

/// Writes `keys` as a path file.
pub fn write_path_file(file: &Path, keys: &[PathKey]) -> Result<(), Error> {
    std::fs::write(file, keys_to_json(keys) + "\n")
        .map_err(|e| Error::Input(format!("{}: cannot write path file: {e}", file.display())))
}

/// True when `spec` names a path file rather than a path of the scene.
pub fn is_path_file(spec: &str) -> bool {
    spec.to_lowercase().ends_with(".json")
}

/// Reads a path file as a camera path named after the file.
pub fn read_camera_path(file: &Path) -> Result<CameraPath, Error> {
    let keys = read_path_file(file)?;
    let name = file
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "file".into());
    Ok(keys_to_path(&name, &keys))
}

/// Records a flown camera as path keys (the viewer's `R` key): at most one key per
/// `min_interval` seconds, written as a path file when done.
#[derive(Clone, Debug)]
pub struct PathRecorder {
    keys: Vec<PathKey>,
    min_interval: f32,
}

impl PathRecorder {
    /// A recorder keeping at most one key per `min_interval` seconds.
    pub fn new(min_interval: f32) -> PathRecorder {
        PathRecorder {
            keys: Vec::new(),
            min_interval: min_interval.max(1e-3),
        }
    }

    /// Adds the pose at `time` seconds since the recording started (ignored when too soon
    /// after the last key, not after it, or without a view direction).
    pub fn push(&mut self, time: f32, pose: CameraPose) {
        let due = self
            .keys
            .last()
            .is_none_or(|k| time >= k.time + self.min_interval);
        let valid = pose.eye.is_finite()
            && pose.target.is_finite()
            && (pose.target - pose.eye).length_squared() > 1e-12;
        if due && valid && time.is_finite() {
            self.keys.push(PathKey {
                time,
                position: pose.eye,
                target: pose.target,
            });
        }
    }

    /// The keys recorded so far.
    pub fn keys(&self) -> &[PathKey] {
        &self.keys
    }

    /// Writes the keys to `file`; an error when fewer than two were recorded.
    pub fn finish(&self, file: &Path) -> Result<(), Error> {
        if self.keys.len() < 2 {
            return Err(Error::Input(format!(
                "{}: a path needs at least 2 keys, {} recorded",
                file.display(),
                self.keys.len()
            )));
        }
        write_path_file(file, &self.keys)
    }
}

impl super::Scene {
    /// The camera path a `--path` value names: `None` is the scene's default path; a `.json`
    /// value is a path file; `interior` is the automatic interior walk (computed unless the
    /// scene already has it); anything else is one of the scene's named paths.
    /// Every path is checked first ([`super::path_check`]): bad frames are reported in one
    /// line on stderr.
    pub fn resolve_path(&self, spec: Option<&str>) -> crate::Result<CameraPath> {
        self.resolve_path_in(spec, None)
    }

    /// [`resolve_path`](Self::resolve_path), with the interior walk it has to compute read
    /// from (or kept in) the cache directory `cache_dir` (see
    /// [`interior_path_cached`](super::interior::interior_path_cached)).
    pub fn resolve_path_cached(
        &self,
        spec: Option<&str>,
        cache_dir: &Path,
    ) -> crate::Result<CameraPath> {
        self.resolve_path_in(spec, Some(cache_dir))
    }

    fn resolve_path_in(
        &self,
        spec: Option<&str>,
        cache_dir: Option<&Path>,
    ) -> crate::Result<CameraPath> {
        use super::interior;
        let path = match spec {
            None => self.default_path().cloned(),
            Some(s) if is_path_file(s) => read_camera_path(Path::new(s)),
            Some(s) if s == interior::PATH_NAME && self.path(s).is_err() => match cache_dir {
                Some(dir) => interior::interior_path_cached(self, dir),
                None => interior::interior_path(self, &interior::InteriorParams::default()),
            },
            Some(s) => self.path(s).cloned(),
        }?;
        match cache_dir {
            Some(dir) => {
                super::path_check::warn_if_bad_cached(self, &path, dir);
            }
            None => super::path_check::warn_if_bad(self, &path),
        }
        Ok(path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orientation_looks_down_rotated_minus_z() {
        let text = r#"{"keys":[
            {"time":0,"position":[0,0,0],"orientation":[0,0,0,1]},
            {"time":1,"position":[1,0,0],"orientation":[0,0.70710677,0,0.70710677]}]}"#;
        let keys = parse_keys(text).expect("parse");
        assert!((keys[0].target - Vec3::NEG_Z).length() < 1e-5);
        // 90° about +Y turns -Z into -X.
        assert!((keys[1].target - Vec3::new(0.0, 0.0, 0.0)).length() < 1e-5);
    }

    #[test]
    fn uneven_times_are_resampled_uniformly() {
        let keys = [0.0, 1.0, 3.0].map(|t| PathKey {
            time: t,
            position: Vec3::new(t, 0.0, 0.0),
            target: Vec3::new(t, 0.0, -1.0),
        });
        let path = keys_to_path("p", &keys);
        assert_eq!(path.keys.len(), 4);
        for (i, k) in path.keys.iter().enumerate() {
            assert!((k.eye.x - i as f32).abs() < 0.2, "{k:?}");
        }
        assert_eq!(path.keys[3].eye, Vec3::new(3.0, 0.0, 0.0));
    }
}
