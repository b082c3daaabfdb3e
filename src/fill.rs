//! Filling nodata/void samples from valid neighbours, and padding to the (2^n + 1)² grid.
//!
//! Each void sample takes the inverse-distance-weighted mean of the nearest valid sample in each
//! of the four axis directions (left, right, down, up), in the spirit of GDAL's `FillNodata`
//! without its smoothing. A pass fills every void that sees a valid sample along its row or
//! column; a second pass fills the rest (every row then holds valid samples), so two passes always
//! suffice once the DEM has one valid sample. Memory stays O(width) per thread: the record's
//! `error` and `radius` fields serve as accumulators (they are computed only afterwards).

use rayon::prelude::*;

use crate::format::Record;

/// A row-major record grid of `side` columns, of which the window `[0, width) × [0, height)` holds
/// the DEM. Raw access for the column sweeps, which own disjoint column ranges.
struct Cols {
    ptr: *mut Record,
    side: usize,
}
unsafe impl Send for Cols {}
unsafe impl Sync for Cols {}

impl Cols {
    #[inline(always)]
    fn at(&self, x: usize, y: usize) -> *mut Record {
        // SAFETY: callers stay inside the grid; tasks own disjoint column ranges.
        unsafe { self.ptr.add(y * self.side + x) }
    }
}

#[inline(always)]
fn accumulate(r: &mut Record, value: f32, distance: usize) {
    let w = 1.0 / distance as f32;
    r.error += w * value;
    r.radius += w;
}

/// Fills every NaN height in the window; returns how many were filled. The window must contain at
/// least one finite height (checked by the caller), else this returns 0 fills and leaves NaNs.
pub fn fill_voids(records: &mut [Record], side: usize, width: usize, height: usize) -> u64 {
    let mut filled = 0u64;
    for _pass in 0..2 {
        // Reset accumulators.
        records.par_chunks_mut(side).take(height).for_each(|row| {
            for r in &mut row[..width] {
                r.error = 0.0;
                r.radius = 0.0;
            }
        });
        // Rows: nearest valid to the left and to the right.
        records.par_chunks_mut(side).take(height).for_each(|row| {
            let row = &mut row[..width];
            let mut last: Option<(usize, f32)> = None;
            for (x, r) in row.iter_mut().enumerate() {
                if r.z.is_nan() {
                    if let Some((lx, v)) = last {
                        accumulate(r, v, x - lx);
                    }
                } else {
                    last = Some((x, r.z));
                }
            }
            last = None;
            for (x, r) in row.iter_mut().enumerate().rev() {
                if r.z.is_nan() {
                    if let Some((lx, v)) = last {
                        accumulate(r, v, lx - x);
                    }
                } else {
                    last = Some((x, r.z));
                }
            }
        });
        // Columns: sweep down and up over blocks of columns, one block per task.
        let cols = Cols { ptr: records.as_mut_ptr(), side };
        let block = 256;
        (0..width.div_ceil(block)).into_par_iter().for_each(|b| {
            let (x0, x1) = (b * block, ((b + 1) * block).min(width));
            let mut last: Vec<Option<(usize, f32)>> = vec![None; x1 - x0];
            for sweep_up in [false, true] {
                last.iter_mut().for_each(|l| *l = None);
                for k in 0..height {
                    let y = if sweep_up { height - 1 - k } else { k };
                    for x in x0..x1 {
                        // SAFETY: this task owns columns x0..x1.
                        let r = unsafe { &mut *cols.at(x, y) };
                        if r.z.is_nan() {
                            if let Some((ly, v)) = last[x - x0] {
                                accumulate(r, v, ly.abs_diff(y));
                            }
                        } else {
                            last[x - x0] = Some((y, r.z));
                        }
                    }
                }
            }
        });
        // Resolve.
        let this_pass: u64 = records
            .par_chunks_mut(side)
            .take(height)
            .map(|row| {
                let mut n = 0;
                for r in &mut row[..width] {
                    if r.z.is_nan() && r.radius > 0.0 {
                        r.z = r.error / r.radius;
                        n += 1;
                    }
                    r.error = 0.0;
                    r.radius = 0.0;
                }
                n
            })
            .sum();
        filled += this_pass;
        if this_pass == 0 {
            break;
        }
    }
    filled
}

/// Minimum and maximum height over the window `[0, width) × [0, height)`.
pub fn height_range(records: &[Record], side: usize, width: usize, height: usize) -> (f64, f64) {
    records
        .par_chunks(side)
        .take(height)
        .map(|row| {
            row[..width]
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), r| (lo.min(r.z as f64), hi.max(r.z as f64)))
        })
        .reduce(|| (f64::INFINITY, f64::NEG_INFINITY), |a, b| (a.0.min(b.0), a.1.max(b.1)))
}

/// Replicates the window's last column eastward and its last row northward to fill the grid.
pub fn pad(records: &mut [Record], side: usize, width: usize, height: usize) {
    records.par_chunks_mut(side).take(height).for_each(|row| {
        let edge = row[width - 1].z;
        for r in &mut row[width..] {
            *r = Record { z: edge, error: 0.0, radius: 0.0 };
        }
    });
    let (head, tail) = records.split_at_mut(height * side);
    let last = &head[(height - 1) * side..];
    tail.par_chunks_mut(side).for_each(|row| row.copy_from_slice(last));
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(rows: &[&[f32]], side: usize) -> Vec<Record> {
        let mut v = vec![Record::default(); side * side];
        for (y, row) in rows.iter().enumerate() {
            for (x, &z) in row.iter().enumerate() {
                v[y * side + x].z = z;
            }
        }
        v
    }

    #[test]
    fn single_void_takes_inverse_distance_mean() {
        let n = f32::NAN;
        let mut g = grid(&[&[1.0, 2.0, 3.0], &[4.0, n, 6.0], &[7.0, 8.0, 9.0]], 3);
        assert_eq!(fill_voids(&mut g, 3, 3, 3), 1);
        // Neighbours 4, 6, 2, 8 all at distance 1.
        assert_eq!(g[4].z, 5.0);
        assert!(g.iter().all(|r| r.error == 0.0 && r.radius == 0.0));
    }

    #[test]
    fn weights_fall_with_distance() {
        let n = f32::NAN;
        let mut g = grid(&[&[0.0, n, n, 30.0]], 4);
        // Only one row: columns see nothing (height 1), rows give the weighted mean.
        assert_eq!(fill_voids(&mut g, 4, 4, 1), 2);
        assert!((g[1].z - 10.0).abs() < 1e-5, "{}", g[1].z); // (0/1 + 30/2) / (1 + 1/2)
        assert!((g[2].z - 20.0).abs() < 1e-5, "{}", g[2].z);
    }

    #[test]
    fn isolated_void_block_needs_the_second_pass() {
        // A valid sample only at (0,0): pass 1 fills row 0 and column 0, pass 2 the rest.
        let n = f32::NAN;
        let mut g = grid(&[&[5.0, n, n], &[n, n, n], &[n, n, n]], 3);
        assert_eq!(fill_voids(&mut g, 3, 3, 3), 8);
        assert!(g.iter().all(|r| r.z == 5.0));
    }

    #[test]
    fn padding_replicates_edges() {
        let mut g = grid(&[&[1.0, 2.0], &[3.0, 4.0]], 3);
        pad(&mut g, 3, 2, 2);
        let z: Vec<f32> = g.iter().map(|r| r.z).collect();
        assert_eq!(z, vec![1.0, 2.0, 2.0, 3.0, 4.0, 4.0, 3.0, 4.0, 4.0]);
    }
}
