//! Filling nodata/void samples from valid neighbours, and padding to the (2^n + 1)² grid.
//!
//! Each void sample takes the inverse-distance-weighted mean of the nearest valid sample in each
//! of the four axis directions (left, right, down, up), in the spirit of GDAL's `FillNodata`
//! without its smoothing. A pass fills every void that sees a valid sample along its row or
//! column; a second pass fills the rest (every row then holds valid samples), so two passes always
//! suffice once the DEM has one valid sample. Memory stays O(width) per thread: the accumulators
//! live in a caller-provided grid (during conversion, the not-yet-computed bounds scratch).

use rayon::prelude::*;

/// Raw pointers for the column sweeps, in which tasks own disjoint column ranges.
struct Cols {
    z: *const f32,
    acc: *mut [f32; 2],
}
// SAFETY: the pointers are into grids the sweep borrows for its whole run; tasks touch disjoint
// columns of `acc` and only read `z` (see `at`).
unsafe impl Send for Cols {}
// SAFETY: as for Send.
unsafe impl Sync for Cols {}

impl Cols {
    /// Height and accumulator of grid index `i`.
    ///
    /// # Safety
    /// `i` in bounds; the caller owns the column of `i` in `acc` (no other live reference).
    #[inline(always)]
    #[allow(clippy::mut_from_ref, reason = "disjoint columns; see the safety contract")]
    unsafe fn at(&self, i: usize) -> (f32, &mut [f32; 2]) {
        // SAFETY: the caller's contract above.
        unsafe { (*self.z.add(i), &mut *self.acc.add(i)) }
    }
}

/// Adds a valid sample `value` at `distance` posts to the accumulator `[Σ w·z, Σ w]`.
#[inline(always)]
fn accumulate(acc: &mut [f32; 2], value: f32, distance: usize) {
    let w = 1.0 / distance as f32;
    acc[0] += w * value;
    acc[1] += w;
}

/// Fills every NaN height in the window `[0, width) × [0, height)` of the row-major grid `z`
/// (`side` columns); returns how many were filled. `acc` is scratch of the same shape; it must be
/// all zero on entry and is all zero on return. With no finite height in the window nothing is
/// filled (the caller rejects such DEMs first).
pub fn fill_voids(z: &mut [f32], acc: &mut [[f32; 2]], side: usize, width: usize, height: usize) -> u64 {
    let mut filled = 0u64;
    for _pass in 0..2 {
        // Rows: nearest valid to the left and to the right.
        z.par_chunks(side).zip(acc.par_chunks_mut(side)).take(height).for_each(|(zr, ar)| {
            let (zr, ar) = (&zr[..width], &mut ar[..width]);
            let mut last: Option<(usize, f32)> = None;
            for x in 0..width {
                if zr[x].is_nan() {
                    if let Some((lx, v)) = last {
                        accumulate(&mut ar[x], v, x - lx);
                    }
                } else {
                    last = Some((x, zr[x]));
                }
            }
            last = None;
            for x in (0..width).rev() {
                if zr[x].is_nan() {
                    if let Some((lx, v)) = last {
                        accumulate(&mut ar[x], v, lx - x);
                    }
                } else {
                    last = Some((x, zr[x]));
                }
            }
        });
        // Columns: sweep down and up over blocks of columns, one block per task.
        let cols = Cols { z: z.as_ptr(), acc: acc.as_mut_ptr() };
        let block = 256;
        (0..width.div_ceil(block)).into_par_iter().for_each(|b| {
            let (x0, x1) = (b * block, ((b + 1) * block).min(width));
            let mut last: Vec<Option<(usize, f32)>> = vec![None; x1 - x0];
            for sweep_up in [false, true] {
                last.iter_mut().for_each(|l| *l = None);
                for k in 0..height {
                    let y = if sweep_up { height - 1 - k } else { k };
                    for x in x0..x1 {
                        // SAFETY: in bounds; this task owns columns x0..x1 of `acc`, and `z` is
                        // only read in this phase.
                        let (zv, a) = unsafe { cols.at(y * side + x) };
                        if zv.is_nan() {
                            if let Some((ly, v)) = last[x - x0] {
                                accumulate(a, v, ly.abs_diff(y));
                            }
                        } else {
                            last[x - x0] = Some((y, zv));
                        }
                    }
                }
            }
        });
        // Resolve, and clear the accumulators.
        let this_pass: u64 = z
            .par_chunks_mut(side)
            .zip(acc.par_chunks_mut(side))
            .take(height)
            .map(|(zr, ar)| {
                let mut n = 0;
                for (zv, a) in zr[..width].iter_mut().zip(&mut ar[..width]) {
                    if zv.is_nan() && a[1] > 0.0 {
                        *zv = a[0] / a[1];
                        n += 1;
                    }
                    *a = [0.0, 0.0];
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
pub fn height_range(z: &[f32], side: usize, width: usize, height: usize) -> (f64, f64) {
    z.par_chunks(side)
        .take(height)
        .map(|row| {
            row[..width]
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| (lo.min(v as f64), hi.max(v as f64)))
        })
        .reduce(|| (f64::INFINITY, f64::NEG_INFINITY), |a, b| (a.0.min(b.0), a.1.max(b.1)))
}

/// Replicates the window's last column eastward and its last row northward to fill the grid.
pub fn pad(z: &mut [f32], side: usize, width: usize, height: usize) {
    z.par_chunks_mut(side).take(height).for_each(|row| {
        let edge = row[width - 1];
        row[width..].fill(edge);
    });
    let (head, tail) = z.split_at_mut(height * side);
    let last = &head[(height - 1) * side..];
    tail.par_chunks_mut(side).for_each(|row| row.copy_from_slice(last));
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(rows: &[&[f32]], side: usize) -> Vec<f32> {
        let mut v = vec![0.0; side * side];
        for (y, row) in rows.iter().enumerate() {
            v[y * side..y * side + row.len()].copy_from_slice(row);
        }
        v
    }

    fn fill(z: &mut [f32], side: usize, width: usize, height: usize) -> u64 {
        let mut acc = vec![[0.0f32; 2]; z.len()];
        let n = fill_voids(z, &mut acc, side, width, height);
        assert!(acc.iter().all(|a| *a == [0.0, 0.0]), "accumulators cleared");
        n
    }

    #[test]
    fn single_void_takes_inverse_distance_mean() {
        let n = f32::NAN;
        let mut g = grid(&[&[1.0, 2.0, 3.0], &[4.0, n, 6.0], &[7.0, 8.0, 9.0]], 3);
        assert_eq!(fill(&mut g, 3, 3, 3), 1);
        // Neighbours 4, 6, 2, 8 all at distance 1.
        assert_eq!(g[4], 5.0);
    }

    #[test]
    fn weights_fall_with_distance() {
        let n = f32::NAN;
        let mut g = grid(&[&[0.0, n, n, 30.0]], 4);
        // Only one row: columns see nothing (height 1), rows give the weighted mean.
        assert_eq!(fill(&mut g, 4, 4, 1), 2);
        assert!((g[1] - 10.0).abs() < 1e-5, "{}", g[1]); // (0/1 + 30/2) / (1 + 1/2)
        assert!((g[2] - 20.0).abs() < 1e-5, "{}", g[2]);
    }

    #[test]
    fn isolated_void_block_needs_the_second_pass() {
        // A valid sample only at (0,0): pass 1 fills row 0 and column 0, pass 2 the rest.
        let n = f32::NAN;
        let mut g = grid(&[&[5.0, n, n], &[n, n, n], &[n, n, n]], 3);
        assert_eq!(fill(&mut g, 3, 3, 3), 8);
        assert!(g.iter().all(|&z| z == 5.0));
    }

    #[test]
    fn padding_replicates_edges() {
        let mut g = grid(&[&[1.0, 2.0], &[3.0, 4.0]], 3);
        pad(&mut g, 3, 2, 2);
        assert_eq!(g, vec![1.0, 2.0, 2.0, 3.0, 4.0, 4.0, 3.0, 4.0, 4.0]);
        assert_eq!(height_range(&g, 3, 2, 2), (1.0, 4.0));
    }
}
