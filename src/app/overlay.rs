//! The viewer's on-screen overlay, drawn on the CPU: a built-in 5×7 bitmap font for the stats
//! panel, and the query visualization of the CHC++ paper as a top-down map of the scene whose
//! boxes are colored by how the culler classified them this frame.

use crate::gpu::swapchain::Panel;
use crate::scene::Aabb;

/// Glyph rows (top first), 5 bits each, most significant bit left.
fn glyph(c: char) -> [u8; 7] {
    match c.to_ascii_uppercase() {
        '0' => [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E],
        '1' => [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E],
        '2' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F],
        '3' => [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E],
        '4' => [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02],
        '5' => [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E],
        '6' => [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E],
        '7' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E],
        '9' => [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C],
        'A' => [0x0E, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'B' => [0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E],
        'C' => [0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E],
        'D' => [0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C],
        'E' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F],
        'F' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10],
        'G' => [0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F],
        'H' => [0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'I' => [0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E],
        'J' => [0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C],
        'K' => [0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11],
        'L' => [0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F],
        'M' => [0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11],
        'N' => [0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11],
        'O' => [0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'P' => [0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10],
        'Q' => [0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D],
        'R' => [0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11],
        'S' => [0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E],
        'T' => [0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04],
        'U' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'V' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04],
        'W' => [0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A],
        'X' => [0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11],
        'Y' => [0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04],
        'Z' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F],
        '.' => [0, 0, 0, 0, 0, 0x0C, 0x0C],
        ':' => [0, 0x0C, 0x0C, 0, 0x0C, 0x0C, 0],
        '-' => [0, 0, 0, 0x1F, 0, 0, 0],
        '+' => [0, 0x04, 0x04, 0x1F, 0x04, 0x04, 0],
        '/' => [0, 0x01, 0x02, 0x04, 0x08, 0x10, 0],
        '=' => [0, 0, 0x1F, 0, 0x1F, 0, 0],
        '(' => [0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02],
        ')' => [0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08],
        '[' => [0x0E, 0x08, 0x08, 0x08, 0x08, 0x08, 0x0E],
        ']' => [0x0E, 0x02, 0x02, 0x02, 0x02, 0x02, 0x0E],
        ',' => [0, 0, 0, 0, 0x0C, 0x04, 0x08],
        '_' => [0, 0, 0, 0, 0, 0, 0x1F],
        '%' => [0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03],
        ' ' => [0; 7],
        _ => [0x0E, 0x11, 0x01, 0x02, 0x04, 0, 0x04],
    }
}

/// Text color of the stats panel (pure white, so tests can find it).
pub const TEXT: [u8; 4] = [255, 255, 255, 255];
/// Background of the stats panel (pure black).
pub const BACKGROUND: [u8; 4] = [0, 0, 0, 255];

/// Lays out `lines` in white on a black panel at (`x`, `y`), each glyph pixel `scale`² pixels.
pub fn text_panel(lines: &[String], x: u32, y: u32, scale: u32) -> Panel {
    let scale = scale.max(1);
    let (cw, ch) = (6 * scale, 9 * scale);
    let cols = lines.iter().map(|l| l.chars().count()).max().unwrap_or(0) as u32;
    let width = cols * cw + 2 * scale + 2;
    let height = lines.len() as u32 * ch + 2 * scale;
    let mut rgba = BACKGROUND.repeat((width * height) as usize);
    for (row, line) in lines.iter().enumerate() {
        for (col, c) in line.chars().enumerate() {
            let bits = glyph(c);
            let ox = 2 + scale + col as u32 * cw;
            let oy = scale + row as u32 * ch + scale;
            for (gy, bits_row) in bits.iter().enumerate() {
                for gx in 0..5u32 {
                    if bits_row & (0x10 >> gx) == 0 {
                        continue;
                    }
                    for sy in 0..scale {
                        for sx in 0..scale {
                            let px = ox + gx * scale + sx;
                            let py = oy + gy as u32 * scale + sy;
                            if px < width && py < height {
                                let i = ((py * width + px) * 4) as usize;
                                rgba[i..i + 4].copy_from_slice(&TEXT);
                            }
                        }
                    }
                }
            }
        }
    }
    Panel {
        x,
        y,
        width,
        height,
        rgba,
    }
}

/// How the culler treated a box this frame (the classes of the CHC++ paper's visualization).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Class {
    /// Outside the view frustum.
    FrustumCulled,
    /// Covered by a query that came back invisible.
    QueryCulled,
    /// Drawn.
    Rendered,
    /// Part of multiquery number `n` (one color each).
    Multiquery(u32),
}

/// Color of a class on the map.
pub fn class_color(c: Class) -> [u8; 4] {
    match c {
        Class::FrustumCulled => [70, 70, 90, 255],
        Class::QueryCulled => [220, 40, 40, 255],
        Class::Rendered => [40, 210, 60, 255],
        Class::Multiquery(n) => {
            const PALETTE: [[u8; 4]; 6] = [
                [250, 200, 30, 255],
                [40, 160, 255, 255],
                [230, 80, 230, 255],
                [255, 140, 20, 255],
                [30, 230, 230, 255],
                [160, 100, 255, 255],
            ];
            PALETTE[n as usize % PALETTE.len()]
        }
    }
}

/// A top-down map (x right, z down) of `world` in a `size`×`size` panel at (`x`, `y`): each box
/// filled in its class color, later boxes over earlier ones, and the eye as a white square.
pub fn map_panel(
    world: &Aabb,
    boxes: &[(Aabb, Class)],
    eye: glam::Vec3,
    x: u32,
    y: u32,
    size: u32,
) -> Panel {
    let size = size.max(8);
    let mut rgba = [20u8, 20, 24, 255].repeat((size * size) as usize);
    let span = (world.max.x - world.min.x)
        .max(world.max.z - world.min.z)
        .max(1e-3);
    let border = 2.0;
    let scale = (size as f32 - 2.0 * border) / span;
    let to_px = |wx: f32, wz: f32| -> (f32, f32) {
        (
            border + (wx - world.min.x) * scale,
            border + (wz - world.min.z) * scale,
        )
    };
    let mut fill = |x0: f32, z0: f32, x1: f32, z1: f32, color: [u8; 4]| {
        let (ax, az) = to_px(x0, z0);
        let (bx, bz) = to_px(x1, z1);
        let (ax, bx) = (ax.floor().max(0.0) as u32, (bx.ceil() as u32).min(size));
        let (az, bz) = (az.floor().max(0.0) as u32, (bz.ceil() as u32).min(size));
        for py in az..bz.max(az + 1).min(size) {
            for px in ax..bx.max(ax + 1).min(size) {
                let i = ((py * size + px) * 4) as usize;
                rgba[i..i + 4].copy_from_slice(&color);
            }
        }
    };
    for (b, c) in boxes {
        fill(b.min.x, b.min.z, b.max.x, b.max.z, class_color(*c));
    }
    let r = 2.0 / scale;
    fill(
        eye.x - r,
        eye.z - r,
        eye.x + r,
        eye.z + r,
        [255, 255, 255, 255],
    );
    Panel {
        x,
        y,
        width: size,
        height: size,
        rgba,
    }
}
