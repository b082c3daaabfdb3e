//! Many georeferenced DEM tiles read as one DEM: each tile placed on one grid by its
//! georeferencing, gaps as nodata, every post taken from the first tile (in the order given)
//! that covers it, so that tiles sharing their edge posts (SRTM's 1° tiles share a row and a
//! column with each neighbour) or overlapping give each post once.
//!
//! Every tile must be in the first tile's CRS, with its posting, on its grid (offsets a whole
//! number of posts); otherwise a one-line error names the tile that differs. Tiles are opened
//! one at a time, twice: once for their headers, once to stream their samples, so memory stays
//! that of one tile's reader and the number of open files one.

use std::path::{Path, PathBuf};

use super::{DemInfo, DemSource, Run, SourceSpacing, MAX_RUN};
use crate::error::{Error, Result};
use crate::georef::{CrsKind, Georef};

/// A tile's place on the mosaic's grid, in posts: columns `x0..x0 + width` (west to east) and
/// rows `y0..y0 + height` counted from the north, as DEM rows are.
#[derive(Clone, Debug)]
struct Placed {
    path: PathBuf,
    x0: u32,
    y0: u32,
    width: u32,
    height: u32,
}

impl Placed {
    fn rows(&self) -> std::ops::Range<u32> {
        self.y0..self.y0 + self.height
    }
    #[cfg(test)]
    fn cols(&self) -> std::ops::Range<u32> {
        self.x0..self.x0 + self.width
    }
}

/// The mosaic of `paths` (at least one), each opened with the same [`super::OpenOptions`].
pub struct Mosaic {
    tiles: Vec<Placed>,
    open: super::OpenOptions,
    info: DemInfo,
}

/// Relative tolerance for "the same posting" and "on the same grid" (coordinates in the file
/// are decimal numbers that round).
const SAME: f64 = 1e-6;

impl Mosaic {
    pub fn open(paths: &[PathBuf], open: super::OpenOptions) -> Result<Mosaic> {
        let Some(first_path) = paths.first() else {
            return Err(Error::InvalidArgument("a mosaic needs at least one tile".into()));
        };
        let mut infos = Vec::with_capacity(paths.len());
        for p in paths {
            let info = super::open_with(p, open)?.info().clone();
            let Some(g) = info.georef else {
                return Err(Error::bad_dem(p, "not georeferenced, so it cannot be placed in a mosaic"));
            };
            infos.push((p, info, g));
        }
        let (_, first, g0) = &infos[0];
        let name = |p: &Path| p.display().to_string();
        // Post offsets of each tile's north-west post from the first tile's.
        let mut placed = Vec::with_capacity(infos.len());
        let (mut x_min, mut y_min, mut x_max, mut y_max) = (i64::MAX, i64::MAX, i64::MIN, i64::MIN);
        for (p, info, g) in &infos {
            if (g.kind, g.epsg, g.unit) != (g0.kind, g0.epsg, g0.unit) {
                return Err(Error::bad_dem(
                    *p,
                    format!("its CRS {} differs from {} of {}", describe(g), describe(g0), name(first_path)),
                ));
            }
            if (0..2).any(|k| (g.step[k] - g0.step[k]).abs() > SAME * g0.step[k]) {
                return Err(Error::bad_dem(
                    *p,
                    format!(
                        "its posting {} x {} differs from {} x {} of {}",
                        g.step[0],
                        g.step[1],
                        g0.step[0],
                        g0.step[1],
                        name(first_path)
                    ),
                ));
            }
            // North-west post: column 0 of row 0 (the origin is the south-west one).
            let nw = [g.origin[0], g.origin[1] + f64::from(info.height - 1) * g.step[1]];
            let nw0 = [g0.origin[0], g0.origin[1] + f64::from(first.height - 1) * g0.step[1]];
            let off = [(nw[0] - nw0[0]) / g0.step[0], (nw0[1] - nw[1]) / g0.step[1]];
            let whole = off.map(f64::round);
            if (0..2).any(|k| (off[k] - whole[k]).abs() > 1e-3) || whole.iter().any(|v| v.abs() > 4e9) {
                return Err(Error::bad_dem(
                    *p,
                    format!(
                        "its posts are off the grid of {} by {:.4} x {:.4} posts",
                        name(first_path),
                        off[0] - whole[0],
                        off[1] - whole[1]
                    ),
                ));
            }
            let (x, y) = (whole[0] as i64, whole[1] as i64);
            x_min = x_min.min(x);
            y_min = y_min.min(y);
            x_max = x_max.max(x + i64::from(info.width));
            y_max = y_max.max(y + i64::from(info.height));
            placed.push((p.to_path_buf(), x, y, info.width, info.height));
        }
        let (width, height) = (x_max - x_min, y_max - y_min);
        let (width, height) = super::check_dimensions(first_path, width as u64, height as u64)?;
        let tiles: Vec<Placed> = placed
            .into_iter()
            .map(|(path, x, y, width, height)| Placed {
                path,
                x0: (x - x_min) as u32,
                y0: (y - y_min) as u32,
                width,
                height,
            })
            .collect();
        // The first tile's origin moved to the mosaic's south-west post.
        let south_rows = f64::from(height) - f64::from(tiles[0].y0 + tiles[0].height);
        let georef = Georef {
            origin: [g0.origin[0] - f64::from(tiles[0].x0) * g0.step[0], g0.origin[1] - south_rows * g0.step[1]],
            ..*g0
        };
        let spacing = match first.spacing {
            Some(SourceSpacing::Degrees { x, y, .. }) => {
                // Degrees become metres at the mosaic's centre latitude, not the first tile's.
                let centre_lat_deg = georef.origin[1] + f64::from(height - 1) * georef.step[1] / 2.0;
                Some(SourceSpacing::Degrees { x, y, centre_lat_deg })
            }
            s => s,
        };
        let info = DemInfo {
            format: first.format,
            width,
            height,
            spacing,
            nodata: first.nodata,
            sample_type: format!("{} (mosaic of {} tiles)", first.sample_type, tiles.len()),
            georef: Some(georef),
        };
        Ok(Mosaic { tiles, open, info })
    }

    /// Columns of row `row` (north-counted) that no tile before `k` covers, within `cols`, as
    /// half-open ranges in order.
    fn own_spans(&self, k: usize, row: u32, cols: std::ops::Range<u32>, out: &mut Vec<(u32, u32)>) {
        out.clear();
        out.push((cols.start, cols.end));
        for t in &self.tiles[..k] {
            if !t.rows().contains(&row) {
                continue;
            }
            let (a, b) = (t.x0, t.x0 + t.width);
            let mut next = Vec::with_capacity(out.len() + 1);
            for &(s, e) in out.iter() {
                if b <= s || a >= e {
                    next.push((s, e));
                    continue;
                }
                if s < a {
                    next.push((s, a));
                }
                if b < e {
                    next.push((b, e));
                }
            }
            *out = next;
            if out.is_empty() {
                return;
            }
        }
    }
}

fn describe(g: &Georef) -> String {
    match g.kind {
        CrsKind::Unknown => "(not stated)".into(),
        _ => g.crs_label(),
    }
}

impl DemSource for Mosaic {
    fn info(&self) -> &DemInfo {
        &self.info
    }

    fn read(&mut self, sink: &mut dyn FnMut(Run<'_>) -> Result<()>) -> Result<()> {
        self.read_window([0, 0, self.info.width, self.info.height], sink)
    }

    fn read_window(&mut self, window: [u32; 4], sink: &mut dyn FnMut(Run<'_>) -> Result<()>) -> Result<()> {
        let [wx0, wr0, wx1, wr1] = window;
        let mut spans = Vec::new();
        for k in 0..self.tiles.len() {
            let t = self.tiles[k].clone();
            // A tile the window does not touch is not opened (sharded conversion reads windows).
            if t.x0 >= wx1 || t.x0 + t.width <= wx0 || t.y0 >= wr1 || t.y0 + t.height <= wr0 {
                continue;
            }
            let mut source = super::open_with(&t.path, self.open)?;
            let info = source.info();
            if (info.width, info.height) != (t.width, t.height) {
                return Err(Error::bad_dem(&t.path, "changed while the mosaic was read"));
            }
            source.read(&mut |run: Run<'_>| {
                let end = run.x0 as u64 + run.values.len() as u64;
                if run.row >= t.height || end > u64::from(t.width) {
                    return Err(Error::bad_dem(&t.path, "reader produced samples outside the tile"));
                }
                let (row, x0) = (t.y0 + run.row, t.x0 + run.x0);
                self.own_spans(k, row, x0..x0 + run.values.len() as u32, &mut spans);
                for &(s, e) in &spans {
                    let values = &run.values[(s - x0) as usize..(e - x0) as usize];
                    sink(Run { row, x0: s, values })?;
                }
                Ok(())
            })?;
        }
        // Gaps: posts no tile covers, as nodata.
        let nan = vec![f64::NAN; MAX_RUN];
        let all = self.tiles.len();
        for row in wr0..wr1.min(self.info.height) {
            self.own_spans(all, row, 0..self.info.width, &mut spans);
            for &(s, e) in &spans {
                let mut x = s;
                while x < e {
                    let n = (e - x).min(MAX_RUN as u32);
                    sink(Run { row, x0: x, values: &nan[..n as usize] })?;
                    x += n;
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mosaic(tiles: &[(u32, u32, u32, u32)]) -> Mosaic {
        let tiles: Vec<Placed> = tiles
            .iter()
            .map(|&(x0, y0, width, height)| Placed { path: PathBuf::from("t"), x0, y0, width, height })
            .collect();
        let info = DemInfo {
            format: crate::dem::DemFormat::GeoTiff,
            width: 10,
            height: 10,
            spacing: None,
            nodata: None,
            sample_type: String::new(),
            georef: None,
        };
        Mosaic { tiles, open: Default::default(), info }
    }

    /// Every post is owned by exactly one tile or by the gaps.
    #[test]
    fn overlapping_tiles_give_each_post_once() {
        let m = mosaic(&[(0, 0, 6, 6), (5, 0, 5, 6), (0, 5, 6, 3), (7, 7, 3, 3)]);
        let mut spans = Vec::new();
        for row in 0..10 {
            let mut owners = [0u32; 10];
            for k in 0..=m.tiles.len() {
                let cols = if k < m.tiles.len() {
                    if !m.tiles[k].rows().contains(&row) {
                        continue;
                    }
                    m.tiles[k].cols()
                } else {
                    0..10
                };
                m.own_spans(k, row, cols, &mut spans);
                for &(s, e) in &spans {
                    for x in s..e {
                        owners[x as usize] += 1;
                    }
                }
            }
            assert_eq!(owners, [1; 10], "row {row}");
        }
    }
}
