//! PNG figures of a camera walk (plotters bitmap backend): frame time per
//! frame, and query / state-change counts per frame, one line per algorithm.
//! Owns the one-time registration of the DejaVu Sans font used for all text.

use std::path::Path;
use std::sync::OnceLock;

use plotters::coord::types::RangedCoordu32;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::FontStyle;

use crate::Error;

/// Where DejaVu Sans is commonly installed, tried in order: Debian and Ubuntu
/// (`fonts-dejavu-core`), Fedora (`dejavu-sans-fonts`, then its older layout), Arch
/// (`ttf-dejavu`), and straight in `truetype/`. The first that exists is registered as the
/// plots' font on first use.
pub const FONT_PATHS: [&str; 5] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu-sans-fonts/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/DejaVuSans.ttf",
];

/// Environment variable naming the TTF file the plots use instead of [`FONT_PATHS`].
pub const FONT_ENV: &str = "COHERENT_FONT";

/// One algorithm's count series: name and `(frame, queries, wasted_queries, state_changes)`
/// points.
pub type CountSeries = (String, Vec<(u32, f64, f64, f64)>);

/// Font family name used in every text style.
const FAMILY: &str = "sans-serif";

/// Line colors assigned to algorithms in order (cycled when exhausted).
const COLORS: [RGBColor; 8] = [
    RGBColor(0, 0, 0),
    RGBColor(0, 70, 220),
    RGBColor(220, 20, 30),
    RGBColor(0, 150, 50),
    RGBColor(240, 130, 0),
    RGBColor(140, 30, 180),
    RGBColor(0, 170, 190),
    RGBColor(140, 90, 40),
];

/// Registers the plots' font once (later calls return the cached outcome): an error when it
/// is missing or does not load. Every plot calls it first; commands that end by writing plots
/// call it before they start, so that a missing font costs a one-line error at once rather
/// than the whole run.
pub fn check_font() -> Result<(), Error> {
    static FONT: OnceLock<Result<(), String>> = OnceLock::new();
    FONT.get_or_init(|| {
        let (path, bytes) = read_font()?;
        let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
        plotters::style::register_font(FAMILY, FontStyle::Normal, bytes)
            .map_err(|_| format!("invalid font file: {path} (the plots need a TTF font)"))
    })
    .clone()
    .map_err(Error::Input)
}

/// The plots' font file: the one `COHERENT_FONT` names, else the first of [`FONT_PATHS`]
/// that is a file. The error says what was looked for.
pub fn font_file() -> Result<String, String> {
    if let Some(path) = std::env::var_os(FONT_ENV) {
        let path = path.to_string_lossy().into_owned();
        return match Path::new(&path).is_file() {
            true => Ok(path),
            false => Err(format!("font not found: {path} (named by {FONT_ENV})")),
        };
    }
    FONT_PATHS
        .iter()
        .find(|p| Path::new(p).is_file())
        .map(|p| p.to_string())
        .ok_or_else(|| {
            format!(
                "font not found: DejaVu Sans, looked for {} (install fonts-dejavu-core, or name \
                 a TTF file in {FONT_ENV})",
                FONT_PATHS.join(", ")
            )
        })
}

/// The plots' font file ([`font_file`]) and its bytes.
fn read_font() -> Result<(String, Vec<u8>), String> {
    let path = font_file()?;
    std::fs::read(&path)
        .map(|b| (path.clone(), b))
        .map_err(|e| format!("cannot read font {path}: {e}"))
}

/// Converts a plotters error into the crate error, naming the output file.
fn plot_err(path: &Path, e: impl std::fmt::Display) -> Error {
    Error::Input(format!("plot {}: {e}", path.display()))
}

/// Draws one line chart of `(frame, value)` series into `area`.
fn draw_chart(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    caption: &str,
    y_desc: &str,
    series: &[(&str, Vec<(u32, f64)>)],
) -> Result<(), String> {
    let (max_x, max_y) = extent(series, 0.0);
    let top = if max_y > 0.0 { max_y * 1.1 } else { 1.0 };

    let width = area.dim_in_pixel().0;
    let mut chart = ChartBuilder::on(area)
        .caption(caption, (FAMILY, title_size(caption, width, 26)))
        .margin(16)
        .x_label_area_size(56)
        .y_label_area_size(84)
        .build_cartesian_2d(0u32..max_x, 0.0..top)
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc("frame")
        .y_desc(y_desc)
        .axis_desc_style((FAMILY, 20))
        .label_style((FAMILY, 16))
        .bold_line_style(RGBColor(215, 215, 215))
        .light_line_style(RGBColor(242, 242, 242))
        .axis_style(BLACK.stroke_width(1))
        .x_labels(12)
        .y_labels(10)
        .y_label_formatter(&|v: &f64| {
            if top >= 20.0 {
                format!("{v:.0}")
            } else if top >= 2.0 {
                format!("{v:.1}")
            } else {
                format!("{v:.3}")
            }
        })
        .draw()
        .map_err(|e| e.to_string())?;

    draw_lines(&mut chart, series, 0.0, (18, 12))
}

/// Frame-time plot (1280x720): one line per algorithm of frame time in ms over
/// the frame index, with axis labels, `title` and a legend.
pub fn plot_frametime(
    path: &Path,
    title: &str,
    series: &[(String, Vec<(u32, f64)>)],
) -> Result<(), Error> {
    plot_lines(path, title, "frame time [ms]", series)
}

/// Line plot (1280x720) of any per-frame value: one line per series over the frame index,
/// with `title`, the y axis named `y_desc`, and a legend.
pub fn plot_lines(
    path: &Path,
    title: &str,
    y_desc: &str,
    series: &[(String, Vec<(u32, f64)>)],
) -> Result<(), Error> {
    plot_one(path, series, |root, lines| {
        draw_chart(root, title, y_desc, lines)
    })
}

/// A 1280x720 PNG of `series`, drawn by `draw` onto the white image.
fn plot_one(
    path: &Path,
    series: &[(String, Vec<(u32, f64)>)],
    draw: impl FnOnce(
        &DrawingArea<BitMapBackend<'_>, Shift>,
        &[(&str, Vec<(u32, f64)>)],
    ) -> Result<(), String>,
) -> Result<(), Error> {
    check_font()?;
    let root = BitMapBackend::new(path, (1280, 720)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| plot_err(path, e))?;
    let lines: Vec<(&str, Vec<(u32, f64)>)> = series
        .iter()
        .map(|(name, pts)| (name.as_str(), pts.clone()))
        .collect();
    draw(&root, &lines).map_err(|e| plot_err(path, e))?;
    root.present().map_err(|e| plot_err(path, e))
}

/// A title font size that fits `title` into `width` pixels (DejaVu Sans averages about 0.55
/// of its size per character).
fn title_size(title: &str, width: u32, largest: u32) -> u32 {
    let chars = title.chars().count().max(1) as f64;
    ((f64::from(width) - 40.0) / (0.56 * chars)).clamp(12.0, f64::from(largest)) as u32
}

/// Missed-pixels plot (1280x720): per frame, the pixels owned by objects an algorithm did not
/// draw (the pop of the latency modes), one line per algorithm.
pub fn plot_missed_pixels(
    path: &Path,
    title: &str,
    series: &[(String, Vec<(u32, f64)>)],
) -> Result<(), Error> {
    plot_lines(path, title, "missed pixels", series)
}

/// Extra-objects plot (1280x720): per frame, the drawn objects that own no pixel of the exact
/// ID pass (what an exact culler would not draw), one line per algorithm, on a log scale (so
/// that VFC's thousands and an occlusion culler's tens are both readable; zero is drawn at the
/// bottom edge).
pub fn plot_extra_objects(
    path: &Path,
    title: &str,
    series: &[(String, Vec<(u32, f64)>)],
) -> Result<(), Error> {
    let caption = format!("{title} (log)");
    plot_one(path, series, |root, lines| {
        draw_log_chart(root, &caption, "objects owning no pixel", lines)
    })
}

/// Count plot (1280x1200) of `(frame, queries, wasted, state_changes)` series: queries,
/// wasted queries and state changes per frame, one panel each, on log scales (so that CHC's
/// hundreds and CHC++'s few are both readable; zero is drawn at the bottom edge).
pub fn plot_counts(path: &Path, title: &str, series: &[CountSeries]) -> Result<(), Error> {
    check_font()?;
    let root = BitMapBackend::new(path, (1280, 1200)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| plot_err(path, e))?;
    let body = root
        .margin(8, 0, 0, 0)
        .titled(title, (FAMILY, title_size(title, 1280, 28)))
        .map_err(|e| plot_err(path, e))?;
    let panels = body.split_evenly((3, 1));
    let pick = |f: fn(&(u32, f64, f64, f64)) -> f64| -> Vec<(&str, Vec<(u32, f64)>)> {
        series
            .iter()
            .map(|(name, pts)| (name.as_str(), pts.iter().map(|p| (p.0, f(p))).collect()))
            .collect()
    };
    type Column = fn(&(u32, f64, f64, f64)) -> f64;
    let charts: [(&str, &str, Column); 3] = [
        ("occlusion queries per frame (log)", "queries", |p| p.1),
        (
            "wasted queries per frame (log; result: visible)",
            "wasted",
            |p| p.2,
        ),
        ("state changes per frame (log)", "state changes", |p| p.3),
    ];
    for (area, (caption, y, f)) in panels.iter().zip(charts) {
        draw_log_chart(area, caption, y, &pick(f)).map_err(|e| plot_err(path, e))?;
    }
    root.present().map_err(|e| plot_err(path, e))
}

/// One line chart of `(frame, count)` series on a log scale from 0.5 (zero is drawn there).
fn draw_log_chart(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    caption: &str,
    y_desc: &str,
    series: &[(&str, Vec<(u32, f64)>)],
) -> Result<(), String> {
    let (max_x, max_y) = extent(series, 1.0);
    let mut chart = ChartBuilder::on(area)
        .caption(caption, (FAMILY, 22))
        .margin(12)
        .x_label_area_size(44)
        .y_label_area_size(84)
        .build_cartesian_2d(0u32..max_x, (0.5..max_y * 2.0).log_scale())
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc("frame")
        .y_desc(y_desc)
        .axis_desc_style((FAMILY, 18))
        .label_style((FAMILY, 15))
        .bold_line_style(RGBColor(215, 215, 215))
        .light_line_style(RGBColor(242, 242, 242))
        .y_label_formatter(&|v: &f64| format!("{v:.0}"))
        .draw()
        .map_err(|e| e.to_string())?;
    draw_lines(&mut chart, series, 0.5, (15, 8))
}

/// The largest frame (at least 1) and the largest finite value (at least `least`) of `series`.
fn extent(series: &[(&str, Vec<(u32, f64)>)], least: f64) -> (u32, f64) {
    let points = || series.iter().flat_map(|(_, pts)| pts.iter());
    let max_x = points().map(|p| p.0).max().unwrap_or(0).max(1);
    let max_y = points()
        .map(|p| p.1)
        .filter(|v| v.is_finite())
        .fold(least, f64::max);
    (max_x, max_y)
}

/// Draws `series` into `chart`, one colored line each (finite values, raised to `floor`),
/// and their legend in the upper right with `(font size, margin)`.
fn draw_lines<'a, Y: Ranged<ValueType = f64>>(
    chart: &mut ChartContext<'a, BitMapBackend<'a>, Cartesian2d<RangedCoordu32, Y>>,
    series: &[(&str, Vec<(u32, f64)>)],
    floor: f64,
    (font, margin): (u32, u32),
) -> Result<(), String> {
    for (i, (name, pts)) in series.iter().enumerate() {
        let color = COLORS[i % COLORS.len()];
        let line = pts
            .iter()
            .filter(|p| p.1.is_finite())
            .map(|&(x, y)| (x, y.max(floor)));
        chart
            .draw_series(LineSeries::new(line, color.stroke_width(2)))
            .map_err(|e| e.to_string())?
            .label(*name)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 24, y)], color.stroke_width(3))
            });
    }
    if !series.is_empty() {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .label_font((FAMILY, font))
            .background_style(WHITE.mix(0.9))
            .border_style(BLACK)
            .margin(margin)
            .draw()
            .map_err(|e| e.to_string())?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::TempDir;
    use std::path::PathBuf;

    /// Where a test writes its plots: `REPORT_PLOT_DIR` when it is set (kept, to look at),
    /// else a temp dir that is removed when the second value drops.
    fn out_dir(test: &str) -> (PathBuf, Option<TempDir>) {
        match std::env::var_os("REPORT_PLOT_DIR") {
            Some(dir) => {
                std::fs::create_dir_all(&dir).unwrap();
                (PathBuf::from(dir), None)
            }
            None => {
                let tmp = TempDir::new(&format!("plot-{test}"));
                (tmp.to_path_buf(), Some(tmp))
            }
        }
    }

    /// Synthetic walk: per algorithm `(frame, ms, queries, state changes)`.
    #[allow(clippy::type_complexity)]
    fn walk(n: u32) -> Vec<(String, Vec<(u32, f64, f64, f64)>)> {
        let names = [
            "oracle",
            "view-frustum",
            "stop-and-wait",
            "chc",
            "chc++",
            "hierarchical",
        ];
        names
            .iter()
            .enumerate()
            .map(|(k, name)| {
                let k = k as f64;
                let pts = (0..n)
                    .map(|f| {
                        let t = f64::from(f) / 40.0;
                        let ms =
                            2.0 + k * 1.3 + (t + k).sin().abs() * (1.0 + k) + 0.3 * (7.0 * t).cos();
                        (
                            f,
                            ms,
                            200.0 * k + 150.0 * (t * 0.7).sin().abs(),
                            4.0 * k + (t * 2.0).cos().abs() * 3.0 * k,
                        )
                    })
                    .collect();
                (name.to_string(), pts)
            })
            .collect()
    }

    /// `path` holds a PNG of some size (a plot, not an empty image).
    fn assert_png(path: &Path) {
        let size = std::fs::metadata(path).unwrap().len();
        assert!(size > 10 * 1024, "png too small: {size}");
    }

    #[test]
    fn frametime_png() {
        let (dir, _tmp) = out_dir("frametime_png");
        let path = dir.join("frametime.png");
        let series: Vec<(String, Vec<(u32, f64)>)> = walk(600)
            .into_iter()
            .map(|(n, pts)| (n, pts.into_iter().map(|p| (p.0, p.1)).collect()))
            .collect();
        plot_frametime(&path, "city walk, 1280x720", &series).unwrap();
        assert_png(&path);
    }

    #[test]
    fn counts_png() {
        let (dir, _tmp) = out_dir("counts_png");
        let path = dir.join("counts.png");
        let series: Vec<CountSeries> = walk(600)
            .into_iter()
            .map(|(n, pts)| {
                (
                    n,
                    pts.into_iter()
                        .map(|p| (p.0, p.2, p.2 * 0.3, p.3))
                        .collect(),
                )
            })
            .collect();
        plot_counts(&path, "city walk: queries and state changes", &series).unwrap();
        assert_png(&path);
    }

    #[test]
    fn extra_objects_png() {
        let (dir, _tmp) = out_dir("extra_objects_png");
        let path = dir.join("extra_objects.png");
        let series: Vec<_> = walk(600)
            .into_iter()
            .enumerate()
            .map(|(k, (n, pts))| {
                // The oracle (first) draws no object that owns no pixel: its zeros lie on
                // the bottom edge.
                let scale = if k == 0 {
                    0.0
                } else {
                    10f64.powi(k as i32 % 4)
                };
                (n, pts.into_iter().map(|p| (p.0, p.1 * scale)).collect())
            })
            .collect();
        plot_extra_objects(&path, "city walk: drawn objects that own no pixel", &series).unwrap();
        assert_png(&path);
    }

    #[test]
    fn empty_series_do_not_panic() {
        let (dir, _tmp) = out_dir("empty_series_do_not_panic");
        plot_frametime(&dir.join("empty1.png"), "empty", &[]).unwrap();
        plot_frametime(
            &dir.join("empty2.png"),
            "no points",
            &[("a".into(), vec![])],
        )
        .unwrap();
        plot_frametime(
            &dir.join("zero.png"),
            "zero",
            &[("a".into(), vec![(0, 0.0), (5, f64::NAN)])],
        )
        .unwrap();
        plot_counts(&dir.join("empty3.png"), "empty", &[]).unwrap();
        plot_extra_objects(&dir.join("empty5.png"), "empty", &[]).unwrap();
        plot_counts(
            &dir.join("empty4.png"),
            "one",
            &[("a".into(), vec![(3, 0.0, 0.0, 0.0)])],
        )
        .unwrap();
        assert!(dir.join("empty1.png").exists());
    }
}
