//! Image files: RGBA8 pixels read back from the GPU written as PNGs. Shared by the renderer, the
//! GI runs and the viewer, so none of them imports another for it.

use std::path::Path;

use crate::error::{Error, Result};

/// Writes RGBA8 pixels (rows bottom-up as rendered with a flipped viewport are already top-down
/// in memory) to a PNG.
pub fn save_rgba_png(path: &Path, w: u32, h: u32, pixels: Vec<u8>) -> Result<()> {
    let img = image::RgbaImage::from_raw(w, h, pixels)
        .ok_or_else(|| Error::Input("pixel buffer does not match the image size".into()))?;
    img.save(path)
        .map_err(|e| Error::Input(format!("{}: cannot write PNG: {e}", path.display())))
}
