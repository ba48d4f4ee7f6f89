//! What the measuring examples share: their positional arguments (each has a default, and one
//! that does not parse is an error that names it instead of being replaced by the default) and
//! the median they report.

use anyhow::{bail, Context, Result};

/// The arguments after the program name; `--help` (or `-h`) prints `usage` and returns `None`,
/// more than `most` arguments is an error.
pub fn args(usage: &str, most: usize) -> Result<Option<Vec<String>>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.iter().any(|a| a == "--help" || a == "-h") {
        println!("{usage}");
        return Ok(None);
    }
    if args.len() > most {
        bail!("{} arguments, at most {most}; {usage}", args.len());
    }
    Ok(Some(args))
}

/// Argument `i` (0-based) parsed as `T`, or `default` when it is absent.
pub fn number<T: std::str::FromStr>(
    args: &[String],
    i: usize,
    what: &str,
    default: T,
) -> Result<T> {
    match args.get(i) {
        None => Ok(default),
        Some(a) => a
            .parse()
            .ok()
            .with_context(|| format!("{what}: {a:?} is not a number")),
    }
}

/// Argument `i` as an image size `WxH`, or `default` when it is absent.
pub fn size(args: &[String], i: usize, default: (u32, u32)) -> Result<(u32, u32)> {
    match args.get(i) {
        None => Ok(default),
        Some(a) => a
            .split_once('x')
            .and_then(|(w, h)| Some((w.parse().ok()?, h.parse().ok()?)))
            .with_context(|| format!("size: {a:?} is not WxH (for example 640x360)")),
    }
}

/// The median (the upper one of an even count); 0 for no values.
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(0.0)
}
