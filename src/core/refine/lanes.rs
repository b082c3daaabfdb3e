//! The walk's inner step in SSE lanes (ARCHITECTURE.md, "Refinement: the f32 test"): a split
//! vertex's two children by integer lane arithmetic, and their active and culling tests in f32,
//! both children at once. Every lane does the operations of [`Fast::test`] in the same order, so
//! the answers are that test's (a unit test compares them); other targets run that test per lane.

use crate::format::terrain::Record;
use crate::refine::Fast;

/// A record as four lanes `(z, error, radius, anything)`.
pub type Lanes4 = [f32; 4];

#[inline(always)]
pub fn record_of(r: Lanes4) -> Record {
    Record { z: r[0], error: r[1], radius: r[2] }
}

/// A record as lanes (the fourth zero).
#[inline(always)]
pub fn lanes_of(r: Record) -> Lanes4 {
    [r.z, r.error, r.radius, 0.0]
}

#[cfg(target_arch = "x86_64")]
mod imp {
    use super::*;
    use std::arch::x86_64::*;

    /// A split vertex's two children, packed `x | y << 32`, and their coordinates as lanes
    /// `(x_left, x_right, y_left, y_right)`.
    #[derive(Clone, Copy)]
    pub struct Kids {
        pub left: u64,
        pub right: u64,
        xy: __m128i,
    }

    impl Kids {
        /// Any two vertices, packed, as a pair (for tests).
        #[cfg(test)]
        pub fn of(left: u64, right: u64) -> Kids {
            // SAFETY: SSE2 is part of the x86-64 baseline.
            let xy = unsafe { _mm_shuffle_epi32::<0b11_01_10_00>(_mm_set_epi64x(right as i64, left as i64)) };
            Kids { left, right, xy }
        }
    }

    /// The pair's active test: `bits` (1 left, 2 right active) and what culling needs.
    #[derive(Clone, Copy)]
    pub struct Pair {
        pub bits: u32,
        rel: __m128,
        rz: __m128,
        reach: __m128,
        radius: __m128,
    }

    #[inline(always)]
    fn ld(v: &[f32; 4]) -> __m128 {
        // SAFETY: `Fast` is 16-byte aligned and made of 16-byte rows, so every row is aligned.
        unsafe { _mm_load_ps(v.as_ptr()) }
    }

    /// The children of `split` on `apex`'s side (see
    /// [`crate::layout::hierarchy::split_children_packed`], whose order `ODD_SPLIT` picks):
    /// `split + (d ± rot d) / 2`, `d = apex − split`, `rot (x, y) = (−y, x)`.
    #[inline(always)]
    pub fn children<const ODD_SPLIT: bool>(apex: u64, split: u64) -> Kids {
        // SAFETY: SSE2 is part of the x86-64 baseline; no memory is touched.
        unsafe {
            let a = _mm_cvtsi64_si128(apex as i64);
            let s = _mm_cvtsi64_si128(split as i64);
            let d = _mm_sub_epi32(a, s);
            let dd = _mm_shuffle_epi32::<0b01_00_01_00>(d);
            // (dy, dx, dy, dx) with lanes 0 and 3 negated: (−dy, dx, dy, −dx), so that dd + rot
            // holds d + rot d in lanes 0–1 and d − rot d in lanes 2–3. Below the root triangles
            // no component exceeds 2³⁰ (a leg is at most half the grid's side), so nothing wraps.
            let flip = _mm_set_epi32(-1, 0, 0, -1);
            let rot = _mm_sub_epi32(_mm_xor_si128(_mm_shuffle_epi32::<0b00_01_00_01>(d), flip), flip);
            let half = _mm_srai_epi32::<1>(_mm_add_epi32(dd, rot));
            let c = _mm_add_epi32(_mm_shuffle_epi32::<0b01_00_01_00>(s), half);
            let c = if ODD_SPLIT { c } else { _mm_shuffle_epi32::<0b01_00_11_10>(c) };
            Kids {
                left: _mm_cvtsi128_si64(c) as u64,
                right: _mm_cvtsi128_si64(_mm_unpackhi_epi64(c, c)) as u64,
                xy: _mm_shuffle_epi32::<0b11_01_10_00>(c),
            }
        }
    }

    /// [`Fast::test`] without culling for both children at `level`, records `l` and `r`.
    #[inline(always)]
    pub fn pair(f: &Fast, kids: &Kids, l: Lanes4, r: Lanes4, level: u32) -> Pair {
        let lv = level as usize & 63;
        // SAFETY: SSE2 is part of the x86-64 baseline; the loads read `Fast`'s aligned rows.
        unsafe {
            let q = _mm_sub_epi32(kids.xy, _mm_load_si128(f.origin.as_ptr().cast()));
            let rel = _mm_sub_ps(_mm_mul_ps(_mm_cvtepi32_ps(q), ld(&f.spacing)), ld(&f.frac));
            let sq = _mm_mul_ps(rel, rel);
            let sxy = _mm_add_ps(sq, _mm_movehl_ps(sq, sq));
            let (a, b) = (_mm_loadu_ps(l.as_ptr()), _mm_loadu_ps(r.as_ptr()));
            let ze = _mm_unpacklo_ps(a, b); // (z_l, z_r, e_l, e_r)
            let radius = _mm_unpackhi_ps(a, b); // (r_l, r_r, …)
            let rz = _mm_sub_ps(ze, ld(&f.eye_z));
            let d2 = _mm_add_ps(sxy, _mm_mul_ps(rz, rz));
            let e = _mm_movehl_ps(ze, ze);
            let own = _mm_add_ps(_mm_mul_ps(ld(&f.kappa), e), radius);
            let reach = _mm_add_ps(_mm_mul_ps(own, ld(&f.grow[lv])), ld(&f.mu[lv]));
            // reach² > d² and κδ + r > 0, false for NaN, as the scalar test.
            let on = _mm_and_ps(_mm_cmpgt_ps(_mm_mul_ps(reach, reach), d2), _mm_cmpgt_ps(own, _mm_setzero_ps()));
            let bits = (_mm_movemask_ps(on) & 3) as u32;
            Pair { bits, rel, rz, reach, radius }
        }
    }

    /// Culls an active pair against the planes in `mask`: for each child, whether it lies wholly
    /// outside one of them, and the planes it does not lie wholly inside of (its children's
    /// mask). One plane at a time, for both children at once: deep in the tree a mask seldom
    /// holds more than one.
    #[inline(always)]
    pub fn cull(f: &Fast, p: &Pair, level: u32, mask: u8) -> [(bool, u8); 2] {
        let lv = level as usize & 63;
        // SAFETY: as in `pair`.
        unsafe {
            let rc = _mm_add_ps(_mm_add_ps(p.radius, _mm_mul_ps(ld(&f.eps[lv]), p.reach)), ld(&f.mu[lv]));
            let neg_rc = _mm_xor_ps(rc, _mm_set1_ps(-0.0));
            let (x, y, z) = (p.rel, _mm_movehl_ps(p.rel, p.rel), p.rz);
            let (mut below, mut keep_l, mut keep_r) = (0i32, mask, mask);
            let mut left = mask;
            while left != 0 {
                let k = left.trailing_zeros() as usize;
                left &= left - 1;
                let [nx, ny, nz] = &f.planes[k & 7];
                let s = _mm_add_ps(_mm_add_ps(_mm_mul_ps(ld(nx), x), _mm_mul_ps(ld(ny), y)), _mm_mul_ps(ld(nz), z));
                below |= _mm_movemask_ps(_mm_cmplt_ps(s, neg_rc));
                let above = _mm_movemask_ps(_mm_cmpgt_ps(s, rc));
                keep_l &= !(((above & 1) as u8) << k);
                keep_r &= !((((above >> 1) & 1) as u8) << k);
            }
            [(below & 1 != 0, keep_l), (below & 2 != 0, keep_r)]
        }
    }
}

#[cfg(not(target_arch = "x86_64"))]
mod imp {
    use super::*;
    use crate::layout::hierarchy::{split_children_packed, unpack};

    #[derive(Clone, Copy)]
    pub struct Kids {
        pub left: u64,
        pub right: u64,
    }

    impl Kids {
        #[cfg(test)]
        pub fn of(left: u64, right: u64) -> Kids {
            Kids { left, right }
        }
    }

    #[derive(Clone, Copy)]
    pub struct Pair {
        pub bits: u32,
        recs: [Record; 2],
        kids: [u64; 2],
        level: u32,
    }

    #[inline(always)]
    pub fn children<const ODD_SPLIT: bool>(apex: u64, split: u64) -> Kids {
        let [left, right] = split_children_packed::<ODD_SPLIT>(apex, split);
        Kids { left, right }
    }

    #[inline(always)]
    pub fn pair(f: &Fast, kids: &Kids, l: Lanes4, r: Lanes4, level: u32) -> Pair {
        let recs = [record_of(l), record_of(r)];
        let on = |k: u64, rec: Record| {
            let (x, y) = unpack(k);
            matches!(f.test::<false>(x, y, level, rec, 0), crate::lod::Test::Active { .. })
        };
        let bits = on(kids.left, recs[0]) as u32 | (on(kids.right, recs[1]) as u32) << 1;
        Pair { bits, recs, kids: [kids.left, kids.right], level }
    }

    #[inline(always)]
    pub fn cull(f: &Fast, p: &Pair, _level: u32, mask: u8) -> [(bool, u8); 2] {
        std::array::from_fn(|k| {
            let (x, y) = unpack(p.kids[k]);
            match f.test::<true>(x, y, p.level, p.recs[k], mask) {
                crate::lod::Test::Active { mask } => (false, mask),
                _ => (true, 0),
            }
        })
    }
}

#[cfg(test)]
use imp::Kids;
pub use imp::{children, cull, pair};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;
    use crate::layout::hierarchy::{pack, split_children_packed};
    use crate::lod::metric::Isotropic;
    use crate::lod::Test;
    use crate::refine::{RefineOptions, View};
    use glam::DVec3;

    fn rng(seed: u64) -> impl FnMut() -> u64 {
        let mut s = seed;
        move || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            s >> 11
        }
    }

    /// The lane children are the packed rule's, both orders, up to the largest legs.
    #[test]
    fn lane_children_equal_the_packed_rule() {
        let mut rnd = rng(3);
        for k in 0..100_000u64 {
            let h = 1i64 << (1 + rnd() % 29);
            // A leg along an axis or a diagonal, from a split vertex that keeps the children on
            // the largest grid.
            let (dx, dy) = match rnd() % 8 {
                0 => (h, 0),
                1 => (-h, 0),
                2 => (0, h),
                3 => (0, -h),
                4 => (h / 2, h / 2),
                5 => (-h / 2, h / 2),
                6 => (h / 2, -h / 2),
                _ => (-h / 2, -h / 2),
            };
            let m = 1i64 << 31;
            let sx = h + (rnd() as i64 % (m - 2 * h)).abs();
            let sy = h + (rnd() as i64 % (m - 2 * h)).abs();
            let (a, s) = (pack((sx + dx) as u32, (sy + dy) as u32), pack(sx as u32, sy as u32));
            let (want, got) = if k % 2 == 0 {
                (split_children_packed::<true>(a, s), children::<true>(a, s))
            } else {
                (split_children_packed::<false>(a, s), children::<false>(a, s))
            };
            assert_eq!([got.left, got.right], want, "apex {a:x} split {s:x}");
        }
    }

    /// The lanes answer as the one-vertex f32 test, active and culled, for vertices near and far,
    /// on and off the sphere and plane boundaries, at the largest coordinates, and for corrupt
    /// (NaN) records.
    #[test]
    fn the_lanes_equal_the_single_test() {
        let camera =
            Camera::new(DVec3::new(5000.0, -300.0, 900.0), DVec3::new(5200.0, 4000.0, 0.0), DVec3::Z, 60.0, 1920, 1080)
                .unwrap();
        let view =
            View::new(&camera, &RefineOptions::default(), Isotropic, [25.0, 31.5], [12800.0, 16000.0], [-50.0, 2500.0]);
        let f = &view.fast;
        let mut rnd = rng(7);
        let mut seen = [0usize; 3];
        for k in 0..200_000u64 {
            let mut pos = || -> u64 {
                let r = rnd();
                match k % 4 {
                    // The largest coordinates (the origin's offset must stay exact).
                    0 => pack(u32::MAX - (r % 7) as u32, (1u32 << 31) + (r % 5) as u32),
                    _ => pack((r % 1025) as u32, ((r >> 20) % 1025) as u32),
                }
            };
            let (l, r) = (pos(), pos());
            let mut rec = || {
                let v = rnd();
                let z = (v % 2600) as f32 - 50.0;
                let error = ((v >> 12) % 4000) as f32 * 0.05;
                let radius = ((v >> 24) % 3000) as f32;
                match v % 97 {
                    0 => [z, f32::NAN, radius, 0.0],
                    2 | 3 => [z, 0.0, 0.0, 0.0],
                    1 => [f32::NAN, error, radius, 0.0],
                    _ => [z, error, radius, f32::from_bits(v as u32)],
                }
            };
            let (rl, rr) = (rec(), rec());
            let level = (rnd() % 40) as u32;
            let mask = (rnd() % 32) as u8;
            let p = pair(f, &Kids::of(l, r), rl, rr, level);
            let culled = cull(f, &p, level, mask);
            for (lane, (v, rec)) in [(l, rl), (r, rr)].into_iter().enumerate() {
                let (x, y) = crate::layout::hierarchy::unpack(v);
                let active = matches!(f.test::<false>(x, y, level, record_of(rec), 0), Test::Active { .. });
                assert_eq!(p.bits >> lane & 1 == 1, active, "{x} {y} {rec:?} at level {level}");
                if active {
                    let want = f.test::<true>(x, y, level, record_of(rec), mask);
                    let got = match culled[lane] {
                        (true, _) => Test::Culled,
                        (false, mask) => Test::Active { mask },
                    };
                    assert_eq!(got, want, "{x} {y} {rec:?} at level {level}, mask {mask:b}");
                    seen[1 + (got == Test::Culled) as usize] += 1;
                } else {
                    seen[0] += 1;
                }
            }
        }
        // Every answer occurs often enough for the comparison to mean something.
        assert!(seen.iter().all(|&n| n > 10_000), "{seen:?}");
    }
}
