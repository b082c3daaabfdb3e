//! Bit interleaving (Morton / Z-order codes) shared by the hierarchical layouts.
//!
//! `encode(a, b)` puts the bits of `a` in the even positions and those of `b` in the odd positions
//! of the result; `decode` inverts it. Both use the classic "magic mask" spreading: each step
//! moves the upper half of every group away from the lower half, halving the group size.

/// Spreads the low 32 bits of `v` into the even bit positions of a `u64`.
#[inline(always)]
pub(crate) fn spread(v: u32) -> u64 {
    let mut v = v as u64;
    v = (v | (v << 16)) & 0x0000_FFFF_0000_FFFF;
    v = (v | (v << 8)) & 0x00FF_00FF_00FF_00FF;
    v = (v | (v << 4)) & 0x0F0F_0F0F_0F0F_0F0F;
    v = (v | (v << 2)) & 0x3333_3333_3333_3333;
    v = (v | (v << 1)) & 0x5555_5555_5555_5555;
    v
}

/// Gathers the even bit positions of `v` into a `u32` (inverse of [`spread`]).
#[inline(always)]
pub(crate) fn compact(v: u64) -> u32 {
    let mut v = v & 0x5555_5555_5555_5555;
    v = (v | (v >> 1)) & 0x3333_3333_3333_3333;
    v = (v | (v >> 2)) & 0x0F0F_0F0F_0F0F_0F0F;
    v = (v | (v >> 4)) & 0x00FF_00FF_00FF_00FF;
    v = (v | (v >> 8)) & 0x0000_FFFF_0000_FFFF;
    v = (v | (v >> 16)) & 0x0000_0000_FFFF_FFFF;
    v as u32
}

/// Morton code with `even` in the even bits and `odd` in the odd bits.
#[inline(always)]
pub(crate) fn encode(even: u32, odd: u32) -> u64 {
    spread(even) | (spread(odd) << 1)
}

/// Inverse of [`encode`]: `(even, odd)`.
#[inline(always)]
pub(crate) fn decode(z: u64) -> (u32, u32) {
    (compact(z), compact(z >> 1))
}

/// `(4^k − 1) / 3 = 1 + 4 + … + 4^(k−1)` (the number of nodes in the first `k` levels of a full
/// quadtree), for `0 <= k <= 32`.
#[inline(always)]
pub(crate) fn quad_sum(k: u32) -> u64 {
    // Branch-free: the low 2k bits of ...0101.
    (((1u128 << (2 * k)) - 1) as u64) & 0x5555_5555_5555_5555
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encode_decode_round_trip() {
        let mut s = 0x9E37_79B9_7F4A_7C15u64;
        for _ in 0..10_000 {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let (a, b) = (s as u32, (s >> 32) as u32);
            let z = encode(a, b);
            assert_eq!(decode(z), (a, b));
            // Bit by bit.
            for i in 0..32 {
                assert_eq!((z >> (2 * i)) & 1, (a as u64 >> i) & 1);
                assert_eq!((z >> (2 * i + 1)) & 1, (b as u64 >> i) & 1);
            }
        }
        assert_eq!(encode(u32::MAX, u32::MAX), u64::MAX);
    }

    #[test]
    fn quad_sums() {
        let mut acc = 0u64;
        for k in 0..=31u32 {
            assert_eq!(quad_sum(k), acc, "k = {k}");
            acc += 1u64 << (2 * k);
        }
        assert_eq!(quad_sum(32), u64::MAX / 3);
    }
}
