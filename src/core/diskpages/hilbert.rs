//! The Hilbert layout: triangles in the order of their centroids along a 3D Hilbert curve
//! (D. Hilbert, "Über die stetige Abbildung einer Linie auf ein Flächenstück", Math. Ann. 38,
//! 1891; the n-dimensional index by J. Skilling, "Programming the Hilbert curve", AIP Conf. Proc.
//! 707, 2004: axes → "transposed" index by inverse undo of the excess work, then Gray decoding).
//! A space-filling curve is the cache-oblivious baseline the 2-factor layout is compared with
//! (Sajadi et al. §2.1). The raster layout is simply the input order ([`raster_order`]).

/// Bits per axis of the centroid grid (3 × 21 = 63-bit keys).
pub const BITS: u32 = 21;

/// The input order: triangle `k` at position `k`.
pub fn raster_order(triangles: usize) -> Vec<u32> {
    (0..triangles as u32).collect()
}

/// Hilbert index of grid cell `axes` (each `< 2^bits`, `bits ≤ 21`): consecutive indices are
/// face-adjacent cells.
pub fn hilbert_index(axes: [u32; 3], bits: u32) -> u64 {
    debug_assert!((1..=BITS).contains(&bits));
    let mut x = axes;
    let top = 1u32 << (bits - 1);
    // Inverse undo: per bit plane from the top, reflect or swap the lower bits.
    let mut q = top;
    while q > 1 {
        let p = q - 1;
        for i in 0..3 {
            if x[i] & q != 0 {
                x[0] ^= p;
            } else {
                let t = (x[0] ^ x[i]) & p;
                x[0] ^= t;
                x[i] ^= t;
            }
        }
        q >>= 1;
    }
    // Gray encode.
    for i in 1..3 {
        x[i] ^= x[i - 1];
    }
    let mut t = 0;
    let mut q = top;
    while q > 1 {
        if x[2] & q != 0 {
            t ^= q - 1;
        }
        q >>= 1;
    }
    for v in &mut x {
        *v ^= t;
    }
    // Interleave: bit b of axis 0, 1, 2, from the top plane down.
    let mut key = 0u64;
    for b in (0..bits).rev() {
        for v in x {
            key = (key << 1) | ((v >> b) & 1) as u64;
        }
    }
    key
}

/// Hilbert keys of `points` quantised to a `2^BITS` grid over their bounding box.
pub fn hilbert_keys(points: &[[f64; 3]]) -> Vec<u64> {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in points {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    // One scale for all axes keeps the curve's cells cubes (a flat terrain stays flat).
    let side = (0..3).map(|k| hi[k] - lo[k]).fold(0.0f64, f64::max);
    let cells = ((1u64 << BITS) - 1) as f64;
    let scale = if side > 0.0 { cells / side } else { 0.0 };
    points
        .iter()
        .map(|p| {
            let axes = [0, 1, 2].map(|k| (((p[k] - lo[k]) * scale).clamp(0.0, cells)) as u32);
            hilbert_index(axes, BITS)
        })
        .collect()
}

/// Indices of `points` sorted by Hilbert key (ties keep the input order).
pub fn hilbert_order(points: &[[f64; 3]]) -> Vec<u32> {
    let keys = hilbert_keys(points);
    let mut order: Vec<u32> = (0..points.len() as u32).collect();
    order.sort_by_key(|&i| keys[i as usize]);
    order
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_curve_visits_every_cell_once_through_faces() {
        for bits in 1..=4u32 {
            let side = 1u32 << bits;
            let mut cell_at = vec![None; 1 << (3 * bits)];
            for x in 0..side {
                for y in 0..side {
                    for z in 0..side {
                        let k = hilbert_index([x, y, z], bits) as usize;
                        assert!(cell_at[k].is_none(), "index {k} twice");
                        cell_at[k] = Some([x, y, z]);
                    }
                }
            }
            let cells: Vec<[u32; 3]> = cell_at.into_iter().map(|c| c.expect("every index used")).collect();
            for w in cells.windows(2) {
                let d: u32 = (0..3).map(|k| w[0][k].abs_diff(w[1][k])).sum();
                assert_eq!(d, 1, "bits {bits}: {:?} → {:?} not face-adjacent", w[0], w[1]);
            }
        }
    }

    #[test]
    fn orders_are_permutations() {
        let pts: Vec<[f64; 3]> = (0..500).map(|i| [(i * 37 % 101) as f64, (i * 11 % 53) as f64, 0.5]).collect();
        let mut o = hilbert_order(&pts);
        o.sort_unstable();
        assert_eq!(o, raster_order(500));
        assert_eq!(hilbert_order(&[[1.0; 3]; 3]), vec![0, 1, 2]);
    }
}
