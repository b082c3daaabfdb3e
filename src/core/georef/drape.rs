//! Where a draped image lies on a terrain: a world file's placement (north-up images only) and
//! the texture coordinates of grid posts it gives. Shared by the native renderer and the web
//! viewer, which both sample an image at `u = a0 + a1·x`, `v = b0 + b1·y`.

use crate::georef::{CrsKind, Georef};

/// The world-file extensions GIS tools use beside an image with extension `ext` (lower case),
/// most specific first: `.pgw`/`.jgw`, then `.pngw`/`.jpgw`, then `.wld`.
pub fn world_file_extensions(ext: &str) -> [String; 3] {
    let short = match ext {
        "png" => "pgw",
        "jpg" | "jpeg" => "jgw",
        _ => "wld",
    };
    [short.to_string(), format!("{ext}w"), "wld".to_string()]
}

/// A world file's text (A D B E C F) as a placement `[x0, dx, y0, dy]`: the CRS coordinates of the
/// upper-left pixel's centre and the pixel size (positive; rows go south). The message says what
/// is wrong.
pub fn parse_world_file(text: &str) -> Result<[f64; 4], &'static str> {
    let v: Vec<f64> = text.split_whitespace().filter_map(|t| t.parse().ok()).collect();
    if v.len() != 6 || !v.iter().all(|x| x.is_finite()) {
        return Err("a world file has six numbers (A D B E C F)");
    }
    let [a, d, b, e, c, f] = [v[0], v[1], v[2], v[3], v[4], v[5]];
    if d != 0.0 || b != 0.0 {
        return Err("a rotated image is not supported (its world file has rotation terms)");
    }
    if !(a > 0.0 && e < 0.0) {
        return Err("the image must be north up: pixel width > 0, height < 0");
    }
    Ok([c, a, f, -e])
}

/// Texture coordinates of grid posts, `[a0, a1, b0, b1]` (0..1 over the image, v down), and
/// whether u wraps (a world image on a geographic terrain), for a `width × height` image placed
/// by `placement` (`None`: stretched over the DEM's posts, `valid_window` of the terrain's
/// header) on a terrain placed by `georef`. `None` when a placement needs a CRS the terrain has
/// not.
pub fn uv_of_grid(
    width: u32,
    height: u32,
    placement: Option<[f64; 4]>,
    valid_window: [u32; 4],
    georef: Option<Georef>,
) -> Option<([f32; 4], bool)> {
    let (w, ht) = (width as f64, height as f64);
    let Some([x0, dx, y0, dy]) = placement else {
        // The image spans the DEM's posts (first to last post, pixel edges at the ends).
        let [_, _, x1, y1] = valid_window;
        let (sx, sy) = ((x1.max(2) - 1) as f64, (y1.max(2) - 1) as f64);
        return Some(([0.0, (1.0 / sx) as f32, 1.0, (-1.0 / sy) as f32], false));
    };
    let g = georef?;
    let (left, top) = (x0 - 0.5 * dx, y0 + 0.5 * dy);
    let (span_x, span_y) = (w * dx, ht * dy);
    let uv = [
        ((g.origin[0] - left) / span_x) as f32,
        (g.step[0] / span_x) as f32,
        ((top - g.origin[1]) / span_y) as f32,
        (-g.step[1] / span_y) as f32,
    ];
    let wraps = g.kind == CrsKind::Geographic && (span_x - 360.0).abs() < 1e-6 * 360.0;
    Some((uv, wraps))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn world_files_are_read_and_rotated_or_south_up_ones_refused() {
        assert_eq!(parse_world_file("0.5\n0\n0\n-0.25\n10.25\n50.125\n"), Ok([10.25, 0.5, 50.125, 0.25]));
        assert!(parse_world_file("1 0 0 -1 0").unwrap_err().contains("six numbers"));
        assert!(parse_world_file("1 0.1 0 -1 0 0").unwrap_err().contains("rotated"));
        assert!(parse_world_file("1 0 0 1 0 0").unwrap_err().contains("north up"));
        assert_eq!(world_file_extensions("jpg"), ["jgw", "jpgw", "wld"]);
    }
}
