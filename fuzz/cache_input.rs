//! One fuzz input read as a path file, a PVS cache file, a calibration cache file, an
//! interior walk cache file or a path check cache file (picked by its first byte), the way the
//! program reads it, then used the way a walk uses it: the path's poses drive vfc and chcpp,
//! the PVS drives the `pvs` culler, the calibration's costs drive `nohc`, the interior walk's
//! and its light's poses drive vfc, over a small grid of boxes with a host backend; a path
//! check's report is printed as a warning. Refusing the file with a one-line
//! error naming it is fine; a panic (or an error of another shape) is a finding.
//!
//! Shared by `fuzz/fuzz_targets/cache_files.rs` and `tests/gpu/fuzz_regressions.rs` (which includes
//! it with `#[path]`), so that the stable test replays exactly what the fuzzer ran.

use std::path::Path;
use std::sync::Arc;

use coherent::app::calibrate;
use coherent::app::pvs_build::PvsFile;
use coherent::bvh::ObjectBvh;
use coherent::culling::nohc::NohcParams;
use coherent::culling::pvs::{fnv1a, Pvs};
use coherent::culling::{create_with, CullerSetup, FrameInput, OcclusionBackend, QueryId};
use coherent::scene::camera::Camera;
use coherent::scene::{interior, path_check, paths, Aabb, CameraPose};

/// The PVS key the harness expects (a real key names scene, settings and object count).
pub const PVS_KEY: &str = "fuzz;objects=27";
/// The device a calibration file must name to be accepted.
pub const DEVICE: [&str; 3] = ["fuzz device", "fuzz driver", "1.3.0"];
/// The interior walk key the harness expects (a real key hashes the code, the scene and the
/// parameters).
pub const INTERIOR_KEY: &str = "interior fuzz";
/// The path check key the harness expects (a real key hashes the code, the scene and the
/// path).
pub const PATH_CHECK_KEY: &str = "path check fuzz";
/// Objects of the harness scene (a 3 x 3 x 3 grid of unit boxes).
pub const OBJECTS: u32 = 27;

/// What the first byte selects; the rest of the input is the file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// `p` (and any byte not listed): a path file (JSON keyframes).
    Path,
    /// `v`: a PVS cache file as it is.
    Pvs,
    /// `V`: a PVS cache file body; the harness appends the right checksum, so that mutations
    /// reach the parser behind it.
    PvsBody,
    /// `c`: a calibration cache file.
    Calibration,
    /// `i`: an interior walk cache file.
    Interior,
    /// `k`: a path check cache file.
    PathCheck,
}

/// The kind and the file's bytes of a fuzz input.
pub fn split(data: &[u8]) -> (Kind, &[u8]) {
    let rest = data.get(1..).unwrap_or(&[]);
    match data.first() {
        Some(b'v') => (Kind::Pvs, rest),
        Some(b'V') => (Kind::PvsBody, rest),
        Some(b'c') => (Kind::Calibration, rest),
        Some(b'i') => (Kind::Interior, rest),
        Some(b'k') => (Kind::PathCheck, rest),
        Some(b'p') => (Kind::Path, rest),
        _ => (Kind::Path, data),
    }
}

/// The fuzz input of `kind` holding `file` (the inverse of [`split`]; for seeds).
#[allow(dead_code)] // the fuzz target only splits
pub fn join(kind: Kind, file: &[u8]) -> Vec<u8> {
    let tag = match kind {
        Kind::Path => b'p',
        Kind::Pvs => b'v',
        Kind::PvsBody => b'V',
        Kind::Calibration => b'c',
        Kind::Interior => b'i',
        Kind::PathCheck => b'k',
    };
    let mut out = vec![tag];
    out.extend_from_slice(file);
    out
}

/// Writes the input's file into `dir`, reads and uses it. `Ok(true)`: accepted and used;
/// `Ok(false)`: refused with a proper one-line error naming the file. Panics on anything else.
pub fn run(dir: &Path, data: &[u8]) -> Result<bool, coherent::Error> {
    let (kind, bytes) = split(data);
    let (name, file_bytes) = match kind {
        Kind::Path => ("input.json", bytes.to_vec()),
        Kind::Pvs => ("input.pvs", bytes.to_vec()),
        Kind::PvsBody => {
            let mut b = bytes.to_vec();
            let sum = fnv1a(&b);
            b.extend_from_slice(&sum.to_le_bytes());
            ("input.pvs", b)
        }
        Kind::Calibration => ("calibration.json", bytes.to_vec()),
        Kind::Interior => ("interior.json", bytes.to_vec()),
        Kind::PathCheck => ("pathcheck.json", bytes.to_vec()),
    };
    let file = dir.join(name);
    std::fs::write(&file, &file_bytes).map_err(coherent::Error::from)?;
    let read = match kind {
        Kind::Path => use_path(&file),
        Kind::Pvs | Kind::PvsBody => use_pvs(&file),
        Kind::Calibration => use_calibration(&file),
        Kind::Interior => use_interior(&file),
        Kind::PathCheck => use_path_check(&file),
    };
    match read {
        Ok(()) => Ok(true),
        Err(e) => {
            let text = e.to_string();
            assert!(!text.contains('\n'), "error is not one line: {text}");
            let shown = file.display().to_string();
            assert!(
                text.contains(&shown),
                "error does not name the file: {text}"
            );
            Ok(false)
        }
    }
}

/// A path file: read as `walk --path FILE` reads it, then 24 poses of it culled by vfc and chcpp.
fn use_path(file: &Path) -> Result<(), String> {
    let path = paths::read_camera_path(file).map_err(|e| e.to_string())?;
    let poses: Vec<CameraPose> = (0..24).map(|i| path.sample(i, 24)).collect();
    for algorithm in ["vfc", "chcpp"] {
        cull(algorithm, &CullerSetup::default(), &poses)
            .map_err(|e| format!("{}: {e}", file.display()))?;
    }
    Ok(())
}

/// A PVS cache file: loaded as `walk --algorithms pvs` loads it (`pvs_build::load_or_build`
/// for a scene of [`OBJECTS`] objects), then culled from the centre
/// of (at most 8 of) its cells and a few fixed points.
fn use_pvs(file: &Path) -> Result<(), String> {
    let pvs = match Pvs::load_for_scene(file, PVS_KEY, OBJECTS as usize) {
        Ok(Some(p)) => p,
        Ok(None) => return Err(format!("{}: vanished", file.display())),
        Err(e) => return Err(e.to_string()),
    };
    let mut poses: Vec<CameraPose> = pvs
        .cells
        .iter()
        .take(8)
        .map(|c| {
            let eye = Pvs::cell_bounds(pvs.origin, pvs.cell_size, c.coord).center();
            CameraPose {
                eye,
                target: eye + glam::Vec3::NEG_Z,
            }
        })
        .collect();
    poses.extend(fixed_poses());
    let setup = CullerSetup {
        pvs: Some(Arc::new(pvs)),
        ..CullerSetup::default()
    };
    cull("pvs", &setup, &poses).map_err(|e| format!("{}: {e}", file.display()))?;
    Ok(())
}

/// A calibration cache file: read and checked as `load_or_calibrate` does, then its costs
/// drive nohc.
fn use_calibration(file: &Path) -> Result<(), String> {
    let text = std::fs::read_to_string(file)
        .map_err(|e| format!("{}: unreadable: {e}", file.display()))?;
    let cal = calibrate::parse_cache(&text, DEVICE[0], DEVICE[1], DEVICE[2])
        .map_err(|why| format!("{}: {why}", file.display()))?;
    let setup = CullerSetup {
        nohc: Some(NohcParams::new(
            cal.costs,
            (320, 180),
            vec![12; OBJECTS as usize],
        )),
        ..CullerSetup::default()
    };
    cull("nohc", &setup, &fixed_poses()).map_err(|e| format!("{}: {e}", file.display()))?;
    Ok(())
}

/// An interior walk cache file: read as `Scene::load_cached` reads it, then 24 poses of its
/// walk and 24 of its light path culled by vfc.
fn use_interior(file: &Path) -> Result<(), String> {
    match interior::cache::load(file, INTERIOR_KEY) {
        Ok(Some(interior::Outcome::Walk { camera, light })) => {
            for path in [camera, light] {
                let poses: Vec<CameraPose> = (0..24).map(|i| path.sample(i, 24)).collect();
                cull("vfc", &CullerSetup::default(), &poses)
                    .map_err(|e| format!("{}: {e}", file.display()))?;
            }
            Ok(())
        }
        Ok(Some(interior::Outcome::NoInside(why))) => {
            assert!(!why.contains('\n'), "a reason of several lines: {why}");
            Ok(())
        }
        Ok(None) => Err(format!("{}: vanished", file.display())),
        Err(e) => Err(e.to_string()),
    }
}

/// A path check cache file: read as the commands read it; a report must be one line, as the
/// warning it is printed as.
fn use_path_check(file: &Path) -> Result<(), String> {
    match path_check::load_verdict(file, PATH_CHECK_KEY) {
        Ok(Some(report)) => {
            if let Some(line) = report {
                assert!(!line.contains('\n'), "a report of several lines: {line}");
            }
            Ok(())
        }
        Ok(None) => Err(format!("{}: vanished", file.display())),
        Err(e) => Err(e.to_string()),
    }
}

/// Poses around and inside the grid.
fn fixed_poses() -> Vec<CameraPose> {
    use glam::Vec3;
    [
        (Vec3::new(0.0, 1.0, 12.0), Vec3::ZERO),
        (Vec3::new(0.1, 0.2, 0.3), Vec3::new(5.0, 0.0, 0.0)),
        (Vec3::new(-9.0, 6.0, -9.0), Vec3::ZERO),
    ]
    .into_iter()
    .map(|(eye, target)| CameraPose { eye, target })
    .collect()
}

/// Runs `algorithm` over the harness scene for each pose, one frame each.
fn cull(algorithm: &str, setup: &CullerSetup, poses: &[CameraPose]) -> coherent::Result<()> {
    let bounds: Vec<Aabb> = (0..OBJECTS)
        .map(|i| {
            let c = glam::Vec3::new((i % 3) as f32, (i / 3 % 3) as f32, (i / 9) as f32);
            let min = (c - 1.0) * 3.0;
            Aabb::new(min, min + 1.0)
        })
        .collect();
    let bvh = ObjectBvh::build(&bounds, 1);
    let mut culler = create_with(algorithm, setup)?;
    let mut backend = HostBackend::default();
    for (frame, pose) in poses.iter().enumerate() {
        let camera = Camera::from_pose(*pose, 16.0 / 9.0, 100.0);
        let input = FrameInput {
            bvh: &bvh,
            view: (&camera).into(),
            frame: frame as u64 + 1,
            exact_visible: None,
        };
        culler.cull_frame(&input, &mut backend)?;
    }
    Ok(())
}

/// A backend without a device: checks the object ids it is asked to draw and answers queries
/// with a fixed pattern of pixel counts (some visible, some not).
#[derive(Default)]
struct HostBackend {
    queries: u32,
}

impl OcclusionBackend for HostBackend {
    fn draw_objects(&mut self, objects: &[u32]) -> coherent::culling::Result<()> {
        assert!(
            objects.iter().all(|&o| o < OBJECTS),
            "culler drew an object out of range: {objects:?}"
        );
        Ok(())
    }
    fn issue_query(&mut self, boxes: &[Aabb]) -> coherent::culling::Result<QueryId> {
        assert!(!boxes.is_empty(), "query without boxes");
        self.queries += 1;
        Ok(self.queries - 1)
    }
    fn flush(&mut self) -> coherent::culling::Result<()> {
        Ok(())
    }
    fn query_result(&mut self, query: QueryId) -> coherent::culling::Result<Option<u64>> {
        assert!(
            query < self.queries,
            "read of a query never issued: {query}"
        );
        Ok(Some(u64::from(query.wrapping_mul(2_654_435_761) % 7) * 40))
    }
    fn wait_query(&mut self, query: QueryId) -> coherent::culling::Result<u64> {
        self.query_result(query).map(Option::unwrap_or_default)
    }
    fn finish(&mut self) -> coherent::culling::Result<()> {
        Ok(())
    }
}
