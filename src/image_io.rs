//! Image files: RGBA8 pixels read back from the GPU written as PNGs. Shared by the renderer, the
//! GI runs and the viewer, so none of them imports another for it.

use std::path::Path;

use crate::error::{Error, Result};

/// Checks, before any work, that `path` can name a PNG to write: its extension is `.png` (any
/// case), and its folder exists or is created.
pub fn prepare_png_path(path: &Path) -> Result<()> {
    let png = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    if !png {
        return Err(Error::Input(format!(
            "{}: the image is written as PNG, so its name must end in .png",
            path.display()
        )));
    }
    match path.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => std::fs::create_dir_all(dir)
            .map_err(|e| Error::Input(format!("{}: cannot create the folder: {e}", dir.display()))),
        _ => Ok(()),
    }
}

/// Writes RGBA8 pixels (rows bottom-up as rendered with a flipped viewport are already top-down
/// in memory) to a PNG.
pub fn save_rgba_png(path: &Path, w: u32, h: u32, pixels: Vec<u8>) -> Result<()> {
    let img = image::RgbaImage::from_raw(w, h, pixels)
        .ok_or_else(|| Error::Input("pixel buffer does not match the image size".into()))?;
    img.save(path)
        .map_err(|e| Error::Input(format!("{}: cannot write PNG: {e}", path.display())))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_paths_are_checked_and_their_folders_made() {
        let dir = std::env::temp_dir().join(format!("coherent-png-path-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let err = prepare_png_path(&dir.join("frame"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("must end in .png"), "{err}");
        assert!(prepare_png_path(&dir.join("frame.jpg")).is_err());
        assert!(!dir.exists(), "nothing is made for a refused name");
        prepare_png_path(&dir.join("a/b/frame.PNG")).unwrap();
        assert!(dir.join("a/b").is_dir());
        prepare_png_path(Path::new("frame.png")).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
