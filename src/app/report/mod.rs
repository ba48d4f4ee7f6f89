//! Benchmark reporting: per-frame records, CSV export and robust statistics.
//! Summaries and tables live in [`summary`], PNG figures in [`plot`].

pub mod plot;
pub mod summary;

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use crate::render::FrameResult;
use crate::Error;

pub use plot::{plot_counts, plot_frametime, CountSeries};
pub use plot::{plot_extra_objects, plot_missed_pixels};
pub use summary::{scaling_table, summarize, AlgorithmSummary, PreprocessSummary, WalkSummary};

/// One frame of one algorithm.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct FrameRecord {
    /// Algorithm name (e.g. "chc++", "oracle").
    pub algorithm: String,
    /// Frame index along the camera path.
    pub frame: u32,
    /// Which repeat of the walk (`walk --repeat`), from 0.
    pub repeat: u32,
    /// CPU wall-clock frame time in milliseconds.
    pub frame_ms: f64,
    /// GPU time of the frame in milliseconds (timestamp queries).
    pub gpu_ms: f64,
    /// Time the CPU spent waiting for query results, in milliseconds.
    pub stall_ms: f64,
    /// CPU time of the frame (traversal, recording, submission; stalls excluded).
    pub cpu_ms: f64,
    /// Occlusion queries issued.
    pub queries: u32,
    /// Queries whose result did not change visibility.
    pub wasted_queries: u32,
    /// Render-state changes (e.g. between query and shading mode).
    pub state_changes: u32,
    /// Pipeline binds recorded.
    pub pipeline_binds: u32,
    /// Draw calls recorded (object draws + query-box draws).
    pub draw_calls: u32,
    /// Draw calls of shaded objects.
    pub object_draws: u32,
    /// Draw calls of query boxes.
    pub query_draws: u32,
    /// Triangles the object draws drew (query boxes not included; draws under a false
    /// predicate submitted but not counted).
    pub triangles: u64,
    /// Objects rendered (the recorder's object draws: one draw per object).
    pub objects: u32,
    /// Queue submissions.
    pub submits: u32,
    /// With `walk --check`: objects that own a pixel of the exact ID pass but were not drawn.
    pub missed_objects: Option<u32>,
    /// With `walk --check`: pixels of the exact ID pass owned by missed objects.
    pub missed_pixels: Option<u64>,
    /// With `walk --check`: drawn objects that own no pixel of the exact ID pass (draws an
    /// exact oracle saves).
    pub extra_objects: Option<u32>,
    /// With `walk --check`: of `extra_objects`, those drawn only under true predicates (the
    /// predicated modes; 0 elsewhere).
    pub extra_predicated_objects: Option<u32>,
    /// With movers (`walk --movers N`): object draws of moving objects (the recorder's count;
    /// part of `object_draws`; under a predicate only where it was true).
    pub mover_draws: Option<u32>,
    /// Object draws recorded under a query's predicate (conditional rendering; part of
    /// `object_draws`).
    pub predicated_draws: u32,
    /// Of those, draws whose predicate was true (read back after the frame; part of
    /// `objects`).
    pub predicated_taken: u32,
    /// Predicate resolves: pass breaks that turn query results into predicates.
    pub predicate_resolves: u32,
    /// Of the queries, multiqueries (several nodes in one query).
    pub multiqueries: u32,
    /// Of the queries, queries of previously visible leaves.
    pub visible_leaf_queries: u32,
    /// Of the queries, queries whose boxes were drawn under another query's predicate.
    pub predicated_queries: u32,
    /// Parts of split nodes decided by the depth part test instead of a query (not queries).
    pub tested_parts: u32,
    /// Of the queries, box tests answered by flags (one instanced draw of a resolve's boxes)
    /// rather than occlusion queries.
    pub flag_tests: u32,
}

impl FrameRecord {
    /// The report row of frame `frame` of `algorithm` (`repeat`: which run of a repeated walk).
    pub fn from_frame(r: &FrameResult, algorithm: &str, frame: u32, repeat: u32) -> FrameRecord {
        FrameRecord {
            algorithm: algorithm.to_string(),
            frame,
            repeat,
            frame_ms: r.frame_ms,
            gpu_ms: r.gpu_ms,
            stall_ms: r.stall_ms,
            cpu_ms: r.cpu_ms,
            queries: r.counts.queries_begun + r.counts.flag_tests,
            wasted_queries: r.counts.queries_visible,
            state_changes: r.counts.state_changes,
            pipeline_binds: r.counts.pipeline_binds,
            draw_calls: r.counts.draw_calls,
            object_draws: r.counts.object_draws + r.counts.indirect_objects,
            query_draws: r.counts.query_draws,
            triangles: r.counts.drawn_triangles(),
            objects: r.counts.drawn_objects(),
            submits: r.counts.submits,
            missed_objects: r.check.map(|c| c.missed_objects),
            missed_pixels: r.check.map(|c| c.missed_pixels),
            extra_objects: r.check.map(|c| c.extra_objects),
            extra_predicated_objects: r.check.map(|c| c.extra_predicated_objects),
            mover_draws: None,
            predicated_draws: r.counts.predicated_objects,
            predicated_taken: r.counts.predicated_objects_taken,
            predicate_resolves: r.counts.predicate_resolves,
            multiqueries: r.counts.multiqueries,
            visible_leaf_queries: r.counts.visible_leaf_queries,
            predicated_queries: r.counts.predicated_queries,
            tested_parts: r.counts.tested_parts,
            flag_tests: r.counts.flag_tests,
        }
    }
}

/// Column names of the CSV written by [`write_frames_csv`], in order.
pub const CSV_HEADER: [&str; 30] = [
    "algorithm",
    "frame",
    "repeat",
    "frame_ms",
    "gpu_ms",
    "stall_ms",
    "queries",
    "wasted_queries",
    "state_changes",
    "pipeline_binds",
    "draw_calls",
    "object_draws",
    "query_draws",
    "triangles",
    "objects",
    "submits",
    "missed_objects",
    "missed_pixels",
    "extra_objects",
    "extra_predicated_objects",
    "mover_draws",
    "predicated_draws",
    "predicated_taken",
    "predicate_resolves",
    "multiqueries",
    "visible_leaf_queries",
    "predicated_queries",
    "tested_parts",
    "flag_tests",
    "cpu_ms",
];

/// Quotes a CSV field if it contains a separator, quote or line break.
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_owned()
    }
}

/// A CSV field for an optional figure: empty when it was not measured.
fn optional<T: ToString>(v: Option<T>) -> String {
    v.map(|v| v.to_string()).unwrap_or_default()
}

/// Writes one CSV row per record, preceded by a header of the field names.
pub fn write_frames_csv(path: &Path, records: &[FrameRecord]) -> Result<(), Error> {
    let mut w = BufWriter::new(File::create(path)?);
    writeln!(w, "{}", CSV_HEADER.join(","))?;
    for r in records {
        writeln!(
            w,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            csv_field(&r.algorithm),
            r.frame,
            r.repeat,
            r.frame_ms,
            r.gpu_ms,
            r.stall_ms,
            r.queries,
            r.wasted_queries,
            r.state_changes,
            r.pipeline_binds,
            r.draw_calls,
            r.object_draws,
            r.query_draws,
            r.triangles,
            r.objects,
            r.submits,
            optional(r.missed_objects),
            optional(r.missed_pixels),
            optional(r.extra_objects),
            optional(r.extra_predicated_objects),
            optional(r.mover_draws),
            r.predicated_draws,
            r.predicated_taken,
            r.predicate_resolves,
            r.multiqueries,
            r.visible_leaf_queries,
            r.predicated_queries,
            r.tested_parts,
            r.flag_tests,
            r.cpu_ms
        )?;
    }
    w.flush()?;
    Ok(())
}

/// Sorts `values` ascending with all NaNs moved to the end and returns the
/// number of non-NaN values.
fn sort_finite_prefix(values: &mut [f64]) -> usize {
    values.sort_unstable_by(|a, b| a.is_nan().cmp(&b.is_nan()).then(a.total_cmp(b)));
    values.iter().take_while(|v| !v.is_nan()).count()
}

/// Median of `values` (NaNs ignored; 0 if there are no numbers). Reorders `values`.
pub fn median(values: &mut [f64]) -> f64 {
    percentile(values, 50.0)
}

/// Percentile `p` in `[0, 100]` of `values` with linear interpolation between
/// closest ranks. NaNs are ignored, an empty input yields 0. Reorders `values`.
pub fn percentile(values: &mut [f64], p: f64) -> f64 {
    let n = sort_finite_prefix(values);
    if n == 0 {
        return 0.0;
    }
    let p = if p.is_nan() {
        50.0
    } else {
        p.clamp(0.0, 100.0)
    };
    let rank = p / 100.0 * (n - 1) as f64;
    let lo = rank.floor() as usize;
    let hi = rank.ceil() as usize;
    let t = rank - lo as f64;
    if lo == hi {
        values[lo]
    } else {
        values[lo] + (values[hi] - values[lo]) * t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_header_and_rows() {
        let dir = std::env::temp_dir().join(format!("coherent_csv_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("frames.csv");
        let records: Vec<FrameRecord> = (0..5)
            .map(|i| FrameRecord {
                algorithm: if i % 2 == 0 { "chc++" } else { "a,b" }.into(),
                frame: i,
                frame_ms: 1.5 * i as f64,
                triangles: 1_000_000,
                ..Default::default()
            })
            .collect();
        write_frames_csv(&path, &records).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(
            lines[0],
            "algorithm,frame,repeat,frame_ms,gpu_ms,stall_ms,queries,wasted_queries,state_changes,\
             pipeline_binds,draw_calls,object_draws,query_draws,triangles,objects,submits,\
             missed_objects,missed_pixels,extra_objects,extra_predicated_objects,mover_draws,predicated_draws,predicated_taken,\
             predicate_resolves,multiqueries,visible_leaf_queries,predicated_queries,tested_parts,flag_tests,cpu_ms"
        );
        assert_eq!(lines.len(), 1 + records.len());
        assert_eq!(
            lines[1],
            "chc++,0,0,0,0,0,0,0,0,0,0,0,0,1000000,0,0,,,,,,0,0,0,0,0,0,0,0,0"
        );
        assert!(lines[2].starts_with("\"a,b\",1,0,1.5,"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn median_and_percentile() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), 2.5);
        assert_eq!(median(&mut []), 0.0);
        assert_eq!(median(&mut [f64::NAN, f64::NAN]), 0.0);
        assert_eq!(median(&mut [f64::NAN, 5.0, -f64::NAN, 1.0, 3.0]), 3.0);
        let mut v: Vec<f64> = (1..=101).rev().map(f64::from).collect();
        assert_eq!(percentile(&mut v, 0.0), 1.0);
        assert_eq!(percentile(&mut v, 95.0), 96.0);
        assert_eq!(percentile(&mut v, 100.0), 101.0);
        assert_eq!(percentile(&mut [10.0, 20.0], 25.0), 12.5);
        assert_eq!(percentile(&mut [7.0], 95.0), 7.0);
    }
}
