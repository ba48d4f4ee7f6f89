//! Per-walk summaries: median statistics per algorithm, their JSON export
//! and fixed-width text tables (algorithm comparison and scene scaling).

use std::fmt::Write as _;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use serde::ser::{SerializeMap, Serializer};
use serde::Serialize;

use super::{median, percentile, FrameRecord};
use crate::Error;

/// Median (and p95 frame time) statistics of one algorithm over a walk.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct AlgorithmSummary {
    /// Median CPU frame time in ms.
    pub frame_ms_median: f64,
    /// 95th percentile CPU frame time in ms.
    pub frame_ms_p95: f64,
    /// Median GPU time in ms.
    pub gpu_ms_median: f64,
    /// Median query-result stall in ms.
    pub stall_ms_median: f64,
    /// Median CPU time in ms (traversal, recording, submission; stalls excluded).
    pub cpu_ms_median: f64,
    /// Median occlusion queries per frame.
    pub queries_median: f64,
    /// Median wasted queries per frame.
    pub wasted_queries_median: f64,
    /// Median state changes per frame.
    pub state_changes_median: f64,
    /// Median pipeline binds per frame.
    pub pipeline_binds_median: f64,
    /// Median draw calls per frame.
    pub draw_calls_median: f64,
    /// Median object draws per frame.
    pub object_draws_median: f64,
    /// Median query-box draws per frame.
    pub query_draws_median: f64,
    /// Median triangles per frame.
    pub triangles_median: f64,
    /// Median queue submissions per frame.
    pub submits_median: f64,
    /// With `walk --check`: the most objects missed in any frame (visible, not drawn).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub missed_objects_max: Option<u32>,
    /// With `walk --check`: the most pixels owned by missed objects in any frame.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub missed_pixels_max: Option<u64>,
    /// With `walk --check`: the first frame (numbered as in `frames.csv`) that missed those
    /// pixels; none when no frame missed a pixel. `coherent render --walk-frames F --frame N`
    /// renders it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub missed_pixels_worst_frame: Option<u32>,
    /// With `walk --check`: the frames (over all repeats) that missed an object, and the
    /// frames checked.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub missed_frames: Option<MissedFrames>,
    /// With `walk --check`: median drawn objects per frame that own no pixel of the exact ID
    /// pass (hidden or outside the view: the draws an exact visibility oracle saves).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub extra_objects_median: Option<f64>,
    /// With `walk --check`: median per frame of those drawn only under true predicates
    /// (predicated modes: the objects of nodes and parts whose test passed that own no pixel).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub extra_predicated_objects_median: Option<f64>,
    /// With movers (`walk --movers N`): median object draws of moving objects per frame.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mover_draws_median: Option<f64>,
    /// Median objects drawn (object draws, less those under a false predicate).
    pub objects_median: f64,
    /// Median object draws under predicates per frame (predicated modes).
    pub predicated_draws_median: f64,
    /// Median of those whose predicate was true.
    pub predicated_taken_median: f64,
    /// Most draws under a true predicate in any frame.
    pub predicated_taken_max: u32,
    /// Median predicate resolves (pass breaks) per frame.
    pub predicate_resolves_median: f64,
    /// Median parts of split nodes decided by the depth part test per frame (not queries).
    pub tested_parts_median: f64,
    /// Preprocessing figures of a precomputed algorithm (pvs).
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    pub preprocess: Option<PreprocessSummary>,
}

/// What a preprocessed visibility algorithm (pvs) cost before the walk.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct PreprocessSummary {
    /// Seconds spent building the PVS (0 when it was loaded from the cache).
    pub preprocess_s: f64,
    /// Whether the PVS came from the cache file rather than being built in this run.
    pub from_cache: bool,
    /// View cells.
    pub cells: usize,
    /// Edge length of a view cell, in scene units.
    pub cell_size: f32,
    /// Sample points per cell (Halton points).
    pub samples: u32,
    /// Whether eight points on each cell's border were sampled too, its corners and the
    /// midpoints of its sides (shared with the cells that meet there).
    pub border: bool,
    /// Pixels per side of each sample's six ID views.
    pub face_size: u32,
    /// Rays per pixel side at the far edges of the ID views (1: none more, as in rasterized
    /// views).
    pub face_refine: u32,
    /// Mean objects per cell's PVS.
    pub pvs_objects_mean: f64,
    /// Largest cell PVS.
    pub pvs_objects_max: usize,
    /// Size of the cache file in bytes.
    pub file_bytes: u64,
    /// Frames whose camera was outside every view cell (drawn frustum-culled only).
    pub frames_outside_cells: usize,
}

impl PreprocessSummary {
    /// How the cells were sampled, for a report line: "19 cells of 6, 4 samples and 8 border
    /// points each, 128-pixel views (4x4 rays at far edges)".
    pub fn sampling(&self) -> String {
        format!(
            "{} cells of {}, {} samples{} each, {}-pixel views{}",
            self.cells,
            (self.cell_size * 1000.0).round() / 1000.0,
            self.samples,
            if self.border {
                format!(
                    " and {} border points",
                    crate::app::pvs_build::BORDER_POINTS
                )
            } else {
                String::new()
            },
            self.face_size,
            match self.face_refine {
                0 | 1 => String::new(),
                r => format!(" ({r}x{r} rays at far edges)"),
            }
        )
    }
}

/// How many checked frames missed an object.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct MissedFrames {
    /// Frames that missed at least one object.
    pub with_a_miss: u32,
    /// Frames checked (`walk --check`), over all repeats.
    pub checked: u32,
}

impl MissedFrames {
    /// Counts over `records`; none when no record was checked.
    fn of(records: &[&FrameRecord]) -> Option<MissedFrames> {
        let mut frames = MissedFrames::default();
        for missed in records.iter().filter_map(|r| r.missed_objects) {
            frames.checked += 1;
            frames.with_a_miss += u32::from(missed > 0);
        }
        (frames.checked > 0).then_some(frames)
    }
}

/// The median of `values`; none when there are none (a figure that was not measured).
fn median_of(values: impl Iterator<Item = u32>) -> Option<f64> {
    let mut v: Vec<f64> = values.map(f64::from).collect();
    (!v.is_empty()).then(|| median(&mut v))
}

/// The first of `records` with the most missed pixels, if any missed one.
fn worst_frame(records: &[&FrameRecord]) -> Option<u32> {
    let mut worst: Option<(u64, u32)> = None;
    for r in records {
        match r.missed_pixels {
            Some(p) if p > 0 && worst.is_none_or(|(most, _)| p > most) => {
                worst = Some((p, r.frame));
            }
            _ => {}
        }
    }
    worst.map(|(_, frame)| frame)
}

impl AlgorithmSummary {
    /// Computes the statistics over the given frames (all zero when empty).
    pub fn from_records(records: &[&FrameRecord]) -> Self {
        let col = |f: &dyn Fn(&FrameRecord) -> f64| -> Vec<f64> {
            records.iter().map(|r| f(r)).collect()
        };
        let med = |f: &dyn Fn(&FrameRecord) -> f64| median(&mut col(f));
        Self {
            frame_ms_median: med(&|r| r.frame_ms),
            frame_ms_p95: percentile(&mut col(&|r| r.frame_ms), 95.0),
            gpu_ms_median: med(&|r| r.gpu_ms),
            stall_ms_median: med(&|r| r.stall_ms),
            cpu_ms_median: med(&|r| r.cpu_ms),
            queries_median: med(&|r| f64::from(r.queries)),
            wasted_queries_median: med(&|r| f64::from(r.wasted_queries)),
            state_changes_median: med(&|r| f64::from(r.state_changes)),
            pipeline_binds_median: med(&|r| f64::from(r.pipeline_binds)),
            draw_calls_median: med(&|r| f64::from(r.draw_calls)),
            object_draws_median: med(&|r| f64::from(r.object_draws)),
            query_draws_median: med(&|r| f64::from(r.query_draws)),
            triangles_median: med(&|r| r.triangles as f64),
            submits_median: med(&|r| f64::from(r.submits)),
            missed_objects_max: records.iter().filter_map(|r| r.missed_objects).max(),
            missed_pixels_max: records.iter().filter_map(|r| r.missed_pixels).max(),
            missed_pixels_worst_frame: worst_frame(records),
            missed_frames: MissedFrames::of(records),
            extra_objects_median: median_of(records.iter().filter_map(|r| r.extra_objects)),
            extra_predicated_objects_median: median_of(
                records.iter().filter_map(|r| r.extra_predicated_objects),
            ),
            mover_draws_median: median_of(records.iter().filter_map(|r| r.mover_draws)),
            objects_median: med(&|r| f64::from(r.objects)),
            predicated_draws_median: med(&|r| f64::from(r.predicated_draws)),
            predicated_taken_median: med(&|r| f64::from(r.predicated_taken)),
            predicated_taken_max: records
                .iter()
                .map(|r| r.predicated_taken)
                .max()
                .unwrap_or(0),
            predicate_resolves_median: med(&|r| f64::from(r.predicate_resolves)),
            tested_parts_median: med(&|r| f64::from(r.tested_parts)),
            preprocess: None,
        }
    }
}

/// Summary of one camera walk through one scene for all algorithms.
#[derive(Clone, Debug, Default, Serialize)]
pub struct WalkSummary {
    /// Scene name.
    pub scene: String,
    /// Number of objects in the scene.
    pub objects: usize,
    /// Total triangles in the scene.
    pub triangles: u64,
    /// GPU device name.
    pub device: String,
    /// Render resolution, e.g. "1280x720".
    pub size: String,
    /// Frames per algorithm (the largest count over all algorithms).
    pub frames: usize,
    /// Per-algorithm statistics in caller order; serialized as a JSON object
    /// whose keys keep this order.
    #[serde(serialize_with = "serialize_ordered")]
    pub algorithms: Vec<(String, AlgorithmSummary)>,
    /// How many times the interleaved walk ran (`walk --repeat`).
    pub repeats: u32,
    /// Each algorithm's median frame time as a ratio to `vfc`'s and to `oracle`'s (where they
    /// ran): one ratio per repeat (medians of the same repeat), summarized by its median and
    /// its min–max over the repeats.
    #[serde(serialize_with = "serialize_ordered")]
    pub ratios: Vec<(String, Ratios)>,
    /// Moving objects (`walk --movers N`), if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub movers: Option<MoverSummary>,
}

/// What moving objects cost in a walk (`walk --movers N`).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct MoverSummary {
    /// Number of movers.
    pub movers: usize,
    /// Median milliseconds per frame to put the movers' boxes into the hierarchy and update it
    /// (refit, and rebuild when one was due).
    pub refit_ms_median: f64,
    /// The slowest such frame.
    pub refit_ms_max: f64,
    /// Full rebuilds of the hierarchy during the walk.
    pub rebuilds: u32,
    /// The glTF file's animation the movers play (`1 "Walk"`), if any.
    pub animation: Option<String>,
    /// Meshes a glTF animation deforms (skins, morph weights), posed on the CPU every frame.
    pub deformed_meshes: usize,
    /// Median milliseconds per frame to pose them and write their vertices (0 without them).
    pub pose_ms_median: f64,
    /// For each algorithm that also ran on the scene without movers (as `NAME-static`): its
    /// median frame time with movers over its median without, per repeat.
    #[serde(serialize_with = "serialize_ordered")]
    pub vs_static: Vec<(String, Spread)>,
}

/// The [`MoverSummary`] of a walk: `refit_ms` per recorded frame, and for every algorithm
/// `NAME` with records of `NAME-static` too, the ratio of their medians in each repeat.
pub fn mover_summary(
    movers: usize,
    refit_ms: &[f64],
    rebuilds: u32,
    records: &[FrameRecord],
) -> MoverSummary {
    let mut refit = refit_ms.to_vec();
    let refit_ms_max = refit.iter().copied().fold(0.0, f64::max);
    let mut names: Vec<&str> = Vec::new();
    for r in records {
        if let Some(base) = r.algorithm.strip_suffix("-static") {
            if !names.contains(&base) {
                names.push(base);
            }
        }
    }
    let repeats = records.iter().map(|r| r.repeat + 1).max().unwrap_or(1);
    let median_of = |name: &str, repeat: u32| {
        let mut v: Vec<f64> = records
            .iter()
            .filter(|r| r.algorithm == name && r.repeat == repeat)
            .map(|r| r.frame_ms)
            .collect();
        (!v.is_empty()).then(|| crate::app::report::median(&mut v))
    };
    let vs_static = names
        .iter()
        .filter_map(|&name| {
            let mut ratios: Vec<f64> = (0..repeats)
                .filter_map(|k| {
                    let moving = median_of(name, k)?;
                    let fixed = median_of(&format!("{name}-static"), k)?;
                    (fixed > 0.0).then_some(moving / fixed)
                })
                .collect();
            Spread::of(&mut ratios).map(|s| (name.to_string(), s))
        })
        .collect();
    MoverSummary {
        movers,
        refit_ms_median: crate::app::report::median(&mut refit),
        refit_ms_max,
        rebuilds,
        animation: None,
        deformed_meshes: 0,
        pose_ms_median: 0.0,
        vs_static,
    }
}

/// The median and the min–max of one ratio over the repeats.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Spread {
    /// Median over the repeats.
    pub median: f64,
    /// Smallest.
    pub min: f64,
    /// Largest.
    pub max: f64,
}

impl Spread {
    fn of(values: &mut [f64]) -> Option<Spread> {
        if values.is_empty() {
            return None;
        }
        let min = values.iter().copied().fold(f64::INFINITY, f64::min);
        let max = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        Some(Spread {
            median: median(values),
            min,
            max,
        })
    }
}

/// One algorithm's frame-time ratios to the references.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Ratios {
    /// Median frame time / vfc's, over the repeats.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vs_vfc: Option<Spread>,
    /// Median frame time / oracle's, over the repeats.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vs_oracle: Option<Spread>,
    /// For a latency mode (`chcpp@predicated`): median frame time / the same algorithm's
    /// in-frame one (`chcpp`), over the repeats.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vs_in_frame: Option<Spread>,
    /// Median frame time / hiz's, over the repeats (not for hiz itself).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vs_hiz: Option<Spread>,
}

/// Serializes `(name, value)` pairs as a map, keeping their order.
fn serialize_ordered<S: Serializer, T: Serialize>(
    pairs: &[(String, T)],
    serializer: S,
) -> Result<S::Ok, S::Error> {
    let mut map = serializer.serialize_map(Some(pairs.len()))?;
    for (name, summary) in pairs {
        map.serialize_entry(name, summary)?;
    }
    map.end()
}

/// Builds a [`WalkSummary`] from per-frame records.
///
/// Algorithms appear in `algorithm_order` (names without records are skipped),
/// followed by any other algorithms in order of first appearance in `records`.
/// `size` is the render resolution `(width, height)`.
pub fn summarize(
    scene: &str,
    objects: usize,
    triangles: u64,
    device: &str,
    size: (u32, u32),
    records: &[FrameRecord],
    algorithm_order: &[String],
) -> WalkSummary {
    let mut names: Vec<&str> = Vec::new();
    let ordered = algorithm_order.iter().map(String::as_str);
    let seen = records.iter().map(|r| r.algorithm.as_str());
    for name in ordered.chain(seen) {
        if !names.contains(&name) && records.iter().any(|r| r.algorithm == name) {
            names.push(name);
        }
    }
    let repeats = records.iter().map(|r| r.repeat + 1).max().unwrap_or(1);
    let mut frames = 0;
    let algorithms = names
        .iter()
        .map(|&name| {
            let own: Vec<&FrameRecord> = records.iter().filter(|r| r.algorithm == name).collect();
            frames = frames.max(own.len() / repeats as usize);
            (name.to_owned(), AlgorithmSummary::from_records(&own))
        })
        .collect();
    let ratios = names
        .iter()
        .map(|&name| {
            let in_frame = name.split_once('@').map(|(base, _)| base);
            let r = Ratios {
                vs_vfc: ratio_spread(records, name, "vfc", repeats),
                vs_oracle: ratio_spread(records, name, "oracle", repeats),
                vs_in_frame: in_frame.and_then(|base| ratio_spread(records, name, base, repeats)),
                vs_hiz: (name != "hiz")
                    .then(|| ratio_spread(records, name, "hiz", repeats))
                    .flatten(),
            };
            (name.to_owned(), r)
        })
        .collect();
    WalkSummary {
        repeats,
        ratios,
        scene: scene.to_owned(),
        objects,
        triangles,
        device: device.to_owned(),
        size: format!("{}x{}", size.0, size.1),
        frames,
        algorithms,
        movers: None,
    }
}

/// The median frame time of `name` in one repeat.
fn repeat_median(records: &[FrameRecord], name: &str, repeat: u32) -> Option<f64> {
    let mut ms: Vec<f64> = records
        .iter()
        .filter(|r| r.algorithm == name && r.repeat == repeat)
        .map(|r| r.frame_ms)
        .collect();
    (!ms.is_empty()).then(|| median(&mut ms))
}

/// `name`'s median frame time over `reference`'s, per repeat, summarized.
fn ratio_spread(
    records: &[FrameRecord],
    name: &str,
    reference: &str,
    repeats: u32,
) -> Option<Spread> {
    let mut ratios: Vec<f64> = (0..repeats)
        .filter_map(|k| {
            let own = repeat_median(records, name, k)?;
            let base = repeat_median(records, reference, k)?;
            (base > 0.0).then_some(own / base)
        })
        .collect();
    Spread::of(&mut ratios)
}

/// Formats a count-like median: integral values without decimals.
fn fmt_count(v: f64) -> String {
    if v.fract() == 0.0 && v.abs() < 1e15 {
        format!("{v:.0}")
    } else {
        format!("{v:.1}")
    }
}

impl WalkSummary {
    /// Statistics of the named algorithm, if present.
    pub fn get(&self, algorithm: &str) -> Option<&AlgorithmSummary> {
        self.algorithms
            .iter()
            .find(|(name, _)| name == algorithm)
            .map(|(_, s)| s)
    }

    /// Writes the summary as pretty-printed JSON.
    pub fn write_json(&self, path: &Path) -> Result<(), Error> {
        let mut w = BufWriter::new(File::create(path)?);
        serde_json::to_writer_pretty(&mut w, self)
            .map_err(|e| Error::Input(format!("JSON encoding of {}: {e}", path.display())))?;
        writeln!(w)?;
        w.flush()?;
        Ok(())
    }

    /// Fixed-width text table, one row per algorithm. The last column is the
    /// median frame time relative to the `reference` algorithm ("-" if absent).
    pub fn table(&self, reference: Option<&str>) -> String {
        let ref_ms = reference
            .and_then(|r| self.get(r))
            .map(|s| s.frame_ms_median);
        let name_w = self.name_width();
        let mut out = String::new();
        let _ = writeln!(
            out,
            "{} | {} objects, {} triangles | {} | {} | {} frames",
            self.scene, self.objects, self.triangles, self.device, self.size, self.frames
        );
        let header = format!(
            "{:<name_w$} {:>9} {:>9} {:>9} {:>9} {:>9} {:>8} {:>8} {:>8} {:>7} {:>7} {:>7} {:>11} {:>7} {:>8}",
            "algorithm",
            "frame ms",
            "p95 ms",
            "gpu ms",
            "cpu ms",
            "stall ms",
            "queries",
            "wasted",
            "states",
            "binds",
            "draws",
            "objects",
            "triangles",
            "submits",
            "x oracle",
        );
        let _ = writeln!(out, "{header}");
        let _ = writeln!(out, "{}", "-".repeat(header.len()));
        for (name, s) in &self.algorithms {
            let ratio = match ref_ms {
                Some(r) if r > 0.0 => format!("{:.2}", s.frame_ms_median / r),
                _ => "-".to_owned(),
            };
            let _ = writeln!(
                out,
                "{:<name_w$} {:>9.3} {:>9.3} {:>9.3} {:>9.3} {:>9.3} {:>8} {:>8} {:>8} {:>7} {:>7} {:>7} {:>11} {:>7} {:>8}",
                name,
                s.frame_ms_median,
                s.frame_ms_p95,
                s.gpu_ms_median,
                s.cpu_ms_median,
                s.stall_ms_median,
                fmt_count(s.queries_median),
                fmt_count(s.wasted_queries_median),
                fmt_count(s.state_changes_median),
                fmt_count(s.pipeline_binds_median),
                fmt_count(s.draw_calls_median),
                fmt_count(s.objects_median),
                fmt_count(s.triangles_median),
                fmt_count(s.submits_median),
                ratio,
            );
        }
        out.push_str(&self.check_table());
        out.push_str(&self.ratio_table());
        out
    }

    /// The width of the algorithm column: the longest name, at least "algorithm".
    fn name_width(&self) -> usize {
        self.algorithms
            .iter()
            .map(|(n, _)| n.chars().count())
            .max()
            .unwrap_or(0)
            .max("algorithm".len())
    }

    /// Missed objects and pixels per algorithm (`walk --check`), and the preprocessing of
    /// precomputed algorithms; empty when neither applies.
    fn check_table(&self) -> String {
        let w = self.name_width();
        let mut out = String::new();
        for (name, s) in &self.algorithms {
            if s.predicated_draws_median > 0.0 || s.predicate_resolves_median > 0.0 {
                if out.is_empty() {
                    out.push_str(
                        "\npredicated draws per frame (median): sent under predicates, drawn \
                         (predicate true; most in a frame), pass breaks, parts tested on the device \
                         (not queries)\n",
                    );
                }
                let _ = writeln!(
                    out,
                    "  {name:<w$} {} sent, {} drawn (max {}), {} pass breaks, {} parts tested",
                    fmt_count(s.predicated_draws_median),
                    fmt_count(s.predicated_taken_median),
                    s.predicated_taken_max,
                    fmt_count(s.predicate_resolves_median),
                    fmt_count(s.tested_parts_median)
                );
            }
        }
        let mut checked = false;
        for (name, s) in &self.algorithms {
            if let (Some(o), Some(p)) = (s.missed_objects_max, s.missed_pixels_max) {
                if !std::mem::replace(&mut checked, true) {
                    out.push_str(
                        "\nexactness (walk --check): most missed in any frame; drawn objects \
                         that own no pixel (median)\n",
                    );
                }
                let mut at = String::new();
                if let Some(f) = s.missed_pixels_worst_frame {
                    let _ = write!(at, " (the most pixels in frame {f})");
                    if let Some(m) = s.missed_frames {
                        let _ = write!(at, "; misses in {} of {} frames", m.with_a_miss, m.checked);
                    }
                }
                if let Some(e) = s.extra_objects_median {
                    let _ = write!(at, "; {} drawn own no pixel", fmt_count(e));
                    if let Some(p) = s.extra_predicated_objects_median.filter(|&p| p > 0.0) {
                        let _ = write!(at, " ({} of them under true predicates)", fmt_count(p));
                    }
                }
                let _ = writeln!(out, "  {name:<w$} {o} objects, {p} pixels{at}");
            }
        }
        for (name, s) in &self.algorithms {
            if let Some(p) = &s.preprocess {
                let _ = writeln!(
                    out,
                    "\n{name}: {}, {:.1} objects per cell (max {}), {:.1} s preprocessing{}, \
                     {} KiB cache file, {} frames outside the cells",
                    p.sampling(),
                    p.pvs_objects_mean,
                    p.pvs_objects_max,
                    p.preprocess_s,
                    if p.from_cache {
                        " (loaded from cache)"
                    } else {
                        ""
                    },
                    p.file_bytes / 1024,
                    p.frames_outside_cells
                );
            }
        }
        out
    }

    /// Frame-time ratios to vfc and oracle with their spread over the repeats, and to the
    /// in-frame mode and hiz where the walk has them.
    fn ratio_table(&self) -> String {
        let fmt = |s: Option<Spread>| match s {
            Some(s) if self.repeats > 1 => {
                format!("{:.2} [{:.2}-{:.2}]", s.median, s.min, s.max)
            }
            Some(s) => format!("{:.2}", s.median),
            None => "-".to_owned(),
        };
        let w = self.name_width();
        let mut out = format!(
            "\nframe-time ratios over {} repeat(s): median [min-max]\n",
            self.repeats
        );
        let in_frame = self.ratios.iter().any(|(_, r)| r.vs_in_frame.is_some());
        let hiz = self.ratios.iter().any(|(_, r)| r.vs_hiz.is_some());
        for (name, r) in &self.ratios {
            let mut line = format!(
                "  {name:<w$} x vfc {:<20} x oracle {:<20}",
                fmt(r.vs_vfc),
                fmt(r.vs_oracle)
            );
            if in_frame {
                let _ = write!(line, " x in-frame {:<20}", fmt(r.vs_in_frame));
            }
            if hiz {
                let _ = write!(line, " x hiz {}", fmt(r.vs_hiz));
            }
            let _ = writeln!(out, "{}", line.trim_end());
        }
        out
    }
}

/// Scaling table: one row per algorithm, one column per scene scale with the
/// median frame time in ms, and a final `growth` column (last / first scale).
pub fn scaling_table(rows: &[(f32, &WalkSummary)]) -> String {
    let mut names: Vec<&str> = Vec::new();
    for (_, walk) in rows {
        for (name, _) in &walk.algorithms {
            if !names.contains(&name.as_str()) {
                names.push(name);
            }
        }
    }
    let name_w = names
        .iter()
        .map(|n| n.chars().count())
        .max()
        .unwrap_or(0)
        .max("algorithm".len());
    let mut out = String::new();
    let mut header = format!("{:<name_w$}", "algorithm");
    for (scale, _) in rows {
        let _ = write!(header, " {:>10}", format!("x{scale}"));
    }
    let _ = write!(header, " {:>8}", "growth");
    let _ = writeln!(out, "{header}");
    let _ = writeln!(out, "{}", "-".repeat(header.len()));
    for name in names {
        let ms: Vec<Option<f64>> = rows
            .iter()
            .map(|(_, w)| w.get(name).map(|s| s.frame_ms_median))
            .collect();
        let _ = write!(out, "{name:<name_w$}");
        for v in &ms {
            match v {
                Some(v) => {
                    let _ = write!(out, " {v:>10.3}");
                }
                None => {
                    let _ = write!(out, " {:>10}", "-");
                }
            }
        }
        let growth = match (ms.first().copied().flatten(), ms.last().copied().flatten()) {
            (Some(first), Some(last)) if first > 0.0 => format!("{:.2}", last / first),
            _ => "-".to_owned(),
        };
        let _ = writeln!(out, " {growth:>8}");
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeSet;

    fn records() -> Vec<FrameRecord> {
        let mut out = Vec::new();
        for (alg, ms) in [("zeta", 4.0), ("oracle", 2.0), ("alpha", 8.0)] {
            for f in 0..10u32 {
                out.push(FrameRecord {
                    algorithm: alg.into(),
                    frame: f,
                    frame_ms: ms,
                    queries: 100 + f,
                    state_changes: 7,
                    triangles: 1_234_567,
                    ..Default::default()
                });
            }
        }
        out
    }

    fn walk() -> WalkSummary {
        let order = vec!["zeta".to_owned(), "missing".to_owned(), "oracle".to_owned()];
        summarize(
            "city",
            5000,
            9_000_000,
            "Test GPU",
            (1280, 720),
            &records(),
            &order,
        )
    }

    fn keys(v: &serde_json::Value) -> BTreeSet<String> {
        v.as_object().unwrap().keys().cloned().collect()
    }

    #[test]
    fn summary_values() {
        let w = walk();
        assert_eq!(w.frames, 10);
        assert_eq!(w.size, "1280x720");
        let names: Vec<&str> = w.algorithms.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["zeta", "oracle", "alpha"]);
        let z = w.get("zeta").unwrap();
        assert_eq!(z.frame_ms_median, 4.0);
        assert_eq!(z.queries_median, 104.5);
        assert_eq!(z.state_changes_median, 7.0);
        assert_eq!(z.triangles_median, 1_234_567.0);
    }

    #[test]
    fn json_keys_and_order() {
        let dir = std::env::temp_dir().join(format!("coherent_json_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("summary.json");
        walk().write_json(&path).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        let top: BTreeSet<String> = [
            "scene",
            "objects",
            "triangles",
            "device",
            "size",
            "frames",
            "algorithms",
            "repeats",
            "ratios",
        ]
        .map(String::from)
        .into();
        assert_eq!(keys(&v), top);
        let alg_keys: BTreeSet<String> = [
            "frame_ms_median",
            "frame_ms_p95",
            "gpu_ms_median",
            "stall_ms_median",
            "cpu_ms_median",
            "queries_median",
            "wasted_queries_median",
            "state_changes_median",
            "pipeline_binds_median",
            "draw_calls_median",
            "object_draws_median",
            "query_draws_median",
            "triangles_median",
            "submits_median",
            "objects_median",
            "predicated_draws_median",
            "predicated_taken_median",
            "predicated_taken_max",
            "predicate_resolves_median",
            "tested_parts_median",
        ]
        .map(String::from)
        .into();
        let algs = v["algorithms"].as_object().unwrap();
        assert_eq!(algs.len(), 3);
        for a in algs.values() {
            assert_eq!(keys(a), alg_keys);
        }
        assert_eq!(v["size"], "1280x720");
        // serde_json::Map sorts keys without `preserve_order`, so check the raw text.
        let pos = |k: &str| text.find(&format!("\"{k}\": {{")).unwrap();
        assert!(pos("zeta") < pos("oracle") && pos("oracle") < pos("alpha"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_worst_frame_is_the_first_with_the_most_missed_pixels() {
        let mut records = records();
        let frame = |r: &mut FrameRecord, objects, pixels| {
            r.missed_objects = Some(objects);
            r.missed_pixels = Some(pixels);
        };
        for r in records.iter_mut() {
            frame(r, 0, 0);
            // zeta draws frame + 1 objects that own no pixel: 1..=10, median 5.5.
            r.extra_objects = Some(if r.algorithm == "zeta" {
                r.frame + 1
            } else {
                0
            });
            // Two of zeta's are drawn only under true predicates; none of the others'.
            r.extra_predicated_objects = Some(if r.algorithm == "zeta" { 2 } else { 0 });
        }
        let clean = summarize("city", 1, 1, "Test GPU", (64, 64), &records, &[]);
        let z = clean.get("zeta").unwrap();
        assert_eq!(
            (z.missed_pixels_max, z.missed_pixels_worst_frame),
            (Some(0), None)
        );
        let line = |w: &WalkSummary| {
            let t = w.table(None);
            let l = t
                .lines()
                .find(|l| l.starts_with("  zeta") && l.contains("pixels"));
            l.unwrap().split_whitespace().collect::<Vec<_>>().join(" ")
        };
        assert_eq!(
            line(&clean),
            "zeta 0 objects, 0 pixels; 5.5 drawn own no pixel (2 of them under true predicates)"
        );
        assert_eq!(clean.get("oracle").unwrap().extra_objects_median, Some(0.0));
        // zeta misses 40 pixels in frames 3 and 7, fewer elsewhere.
        for (i, px) in [(2, 5), (3, 40), (5, 12), (7, 40)] {
            frame(&mut records[i], 1, px);
        }
        let w = summarize("city", 1, 1, "Test GPU", (64, 64), &records, &[]);
        let z = w.get("zeta").unwrap();
        assert_eq!(
            (z.missed_pixels_max, z.missed_pixels_worst_frame),
            (Some(40), Some(3))
        );
        assert_eq!(
            line(&w),
            "zeta 1 objects, 40 pixels (the most pixels in frame 3); misses in 4 of 10 frames; \
             5.5 drawn own no pixel (2 of them under true predicates)"
        );
        assert_eq!(
            z.missed_frames,
            Some(MissedFrames {
                with_a_miss: 4,
                checked: 10
            })
        );
        assert_eq!(
            w.get("oracle").unwrap().missed_frames.unwrap().with_a_miss,
            0
        );
    }

    #[test]
    fn the_pvs_sampling_names_cells_samples_border_and_views() {
        let mut p = PreprocessSummary {
            cells: 8,
            cell_size: 5.625_000_5,
            samples: 4,
            border: true,
            face_size: 128,
            face_refine: 4,
            ..Default::default()
        };
        assert_eq!(
            p.sampling(),
            "8 cells of 5.625, 4 samples and 8 border points each, 128-pixel views (4x4 rays at far edges)"
        );
        (p.border, p.face_refine) = (false, 1);
        assert_eq!(
            p.sampling(),
            "8 cells of 5.625, 4 samples each, 128-pixel views"
        );
    }

    #[test]
    fn table_has_ratio() {
        let w = walk();
        let t = w.table(Some("oracle"));
        assert!(t.contains("x oracle"));
        let zeta = t.lines().find(|l| l.starts_with("zeta")).unwrap();
        assert!(zeta.trim_end().ends_with("2.00"), "{zeta}");
        let alpha = t.lines().find(|l| l.starts_with("alpha")).unwrap();
        assert!(alpha.trim_end().ends_with("4.00"), "{alpha}");
        let none = w.table(None);
        let zeta = none.lines().find(|l| l.starts_with("zeta")).unwrap();
        assert!(zeta.trim_end().ends_with('-'));
        assert!(w
            .table(Some("nope"))
            .lines()
            .any(|l| l.starts_with("oracle")));
    }

    #[test]
    fn latency_modes_are_compared_with_in_frame_and_hiz() {
        let mut records = Vec::new();
        for repeat in 0..2u32 {
            for (alg, ms) in [
                ("chcpp", 10.0),
                ("chcpp@predicated", 8.0 + repeat as f64),
                ("hiz", 12.0),
                ("oracle", 4.0),
            ] {
                for frame in 0..5u32 {
                    records.push(FrameRecord {
                        algorithm: alg.into(),
                        frame,
                        repeat,
                        frame_ms: ms,
                        ..Default::default()
                    });
                }
            }
        }
        let w = summarize("city", 1, 1, "Test GPU", (64, 64), &records, &[]);
        let ratios = |name: &str| w.ratios.iter().find(|(n, _)| n == name).unwrap().1;
        let p = ratios("chcpp@predicated");
        let in_frame = p.vs_in_frame.unwrap();
        assert_eq!((in_frame.min, in_frame.max), (0.8, 0.9));
        assert_eq!(p.vs_hiz.unwrap().min, 8.0 / 12.0);
        assert!(ratios("chcpp").vs_in_frame.is_none());
        assert!(ratios("hiz").vs_hiz.is_none());
        assert_eq!(ratios("oracle").vs_hiz.unwrap().max, 4.0 / 12.0);
        let table = w.ratio_table();
        let line = table
            .lines()
            .find(|l| l.trim_start().starts_with("chcpp@predicated"))
            .unwrap();
        assert!(line.contains("x in-frame 0.85 [0.80-0.90]"), "{line}");
        assert!(line.contains("x hiz 0.71 [0.67-0.75]"), "{line}");
        // Without latency modes or hiz the table keeps its two columns.
        assert!(!walk().ratio_table().contains("x hiz"));
    }

    #[test]
    fn scaling() {
        let small = walk();
        let mut big = walk();
        for (_, s) in &mut big.algorithms {
            s.frame_ms_median *= 3.0;
        }
        let t = scaling_table(&[(1.0, &small), (4.0, &big)]);
        let zeta = t.lines().find(|l| l.starts_with("zeta")).unwrap();
        assert!(zeta.contains("4.000") && zeta.contains("12.000"));
        assert!(zeta.trim_end().ends_with("3.00"), "{zeta}");
        assert!(t.lines().next().unwrap().contains("growth"));
        assert_eq!(scaling_table(&[]).lines().count(), 2);
    }
}
