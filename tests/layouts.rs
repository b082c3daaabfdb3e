//! Cross-checks of every index layout against the bisection hierarchy: bijectivity, waste, the
//! refinement child shortcuts, and the coarse-to-fine order of the hierarchical layouts.

use proptest::prelude::*;
use relief::hierarchy::{split_children, Grid};
use relief::layout::*;

const TILE_SIDES: [u32; 5] = [1, 2, 4, 16, 64];

/// Every layout (tiled with several tile sides) for grid `g`.
fn all_layouts(g: Grid) -> Vec<AnyLayout> {
    let mut v = vec![AnyLayout::RowMajor(RowMajor::new(g))];
    v.extend(TILE_SIDES.iter().map(|&t| AnyLayout::Tiled(Tiled::new(g, t))));
    v.push(AnyLayout::Interleaved(Interleaved::new(g)));
    v.push(AnyLayout::Embedded(Embedded::new(g)));
    v.push(AnyLayout::Hz(Hz::new(g)));
    v
}

fn name(l: &AnyLayout) -> String {
    format!("{}({}) n={}", l.kind(), l.param(), l.grid().n())
}

fn positions(g: Grid) -> impl Iterator<Item = (u32, u32)> {
    let s = g.size();
    (0..s).flat_map(move |y| (0..s).map(move |x| (x, y)))
}

/// Record count in closed form, independent of the implementations.
fn expected_records(kind: LayoutKind, n: u32) -> u64 {
    let q = 1u64 << (2 * n); // 4^n
    match kind {
        LayoutKind::RowMajor | LayoutKind::Tiled | LayoutKind::Hz => ((1u64 << n) + 1).pow(2),
        LayoutKind::Interleaved => 4 + 5 * (q - 1) / 3,
        LayoutKind::Embedded => 5 + 4 * (q - 1) / 3,
    }
}

#[test]
fn index_is_a_bijection_onto_used_slots() {
    for n in 1..=9 {
        let g = Grid::new(n).unwrap();
        for l in all_layouts(g) {
            let records = l.records();
            assert_eq!(records, expected_records(l.kind(), n), "{}", name(&l));
            let mut used = vec![false; records as usize];
            for (x, y) in positions(g) {
                let i = l.index(x, y);
                assert!(i < records, "{}: ({x},{y}) -> {i} >= {records}", name(&l));
                assert!(!used[i as usize], "{}: collision at {i} for ({x},{y})", name(&l));
                used[i as usize] = true;
                assert_eq!(l.coords(i), Some((x, y)), "{}: coords(index({x},{y}))", name(&l));
            }
            let mut unused = 0;
            for (i, &u) in used.iter().enumerate() {
                if !u {
                    assert_eq!(l.coords(i as u64), None, "{}: unused slot {i}", name(&l));
                    unused += 1;
                }
            }
            assert_eq!(unused, records - g.vertices(), "{}", name(&l));
            assert_eq!(l.coords(records), None, "{}", name(&l));
            assert_eq!(l.coords(u64::MAX), None, "{}", name(&l));
        }
    }
}

#[test]
fn waste_ratio_matches_closed_forms() {
    for n in 1..=20 {
        let g = Grid::new(n).unwrap();
        let v = g.vertices() as f64;
        let q = 4f64.powi(n as i32);
        for l in all_layouts(g) {
            let expect = match l.kind() {
                LayoutKind::RowMajor | LayoutKind::Tiled | LayoutKind::Hz => 0.0,
                LayoutKind::Interleaved => (4.0 + 5.0 * (q - 1.0) / 3.0) / v - 1.0,
                LayoutKind::Embedded => (5.0 + 4.0 * (q - 1.0) / 3.0) / v - 1.0,
            };
            assert!((l.waste_ratio() - expect).abs() < 1e-12, "{}", name(&l));
        }
    }
    // Asymptotically 2/3 and 1/3.
    let g = Grid::new(20).unwrap();
    assert!((Interleaved::new(g).waste_ratio() - 2.0 / 3.0).abs() < 1e-5);
    assert!((Embedded::new(g).waste_ratio() - 1.0 / 3.0).abs() < 1e-5);
    // The largest grids still fit the index space in u64.
    let g = Grid::new(31).unwrap();
    assert_eq!(Interleaved::new(g).records(), 4 + 5 * (((1u64 << 62) - 1) / 3));
    assert_eq!(Embedded::new(g).records(), 5 + 4 * (((1u64 << 62) - 1) / 3));
    assert_eq!(Hz::new(g).records(), g.vertices());
}

/// Walks the whole refinement (apex = centre, split = w, s, e, n, recursing into both children)
/// and calls `f(apex, split)` for every pair whose split vertex has children.
fn refinement_walk(g: Grid, mut f: impl FnMut((u32, u32), (u32, u32))) {
    fn walk(g: Grid, i: (u32, u32), j: (u32, u32), f: &mut impl FnMut((u32, u32), (u32, u32))) {
        if g.level(j.0, j.1) == 1 {
            return;
        }
        f(i, j);
        let [l, r] = split_children(i, j);
        walk(g, j, l, f);
        walk(g, j, r, f);
    }
    for j in g.edge_midpoints() {
        walk(g, g.centre(), j, &mut f);
    }
}

#[test]
fn split_children_agree_with_geometry() {
    for n in 1..=8 {
        let g = Grid::new(n).unwrap();
        for l in all_layouts(g) {
            let mut pairs = 0u64;
            refinement_walk(g, |i, j| {
                let got = l.split_children(l.vertex(i.0, i.1), l.vertex(j.0, j.1));
                let want = split_children(i, j).map(|(x, y)| l.vertex(x, y));
                assert_eq!(got, want, "{}: apex {i:?} split {j:?}", name(&l));
                pairs += 1;
            });
            // Each split of a vertex above level 1 is reached once per side: the interior ones
            // twice, the border ones once; level-1 vertices are never split.
            let mut expect = 0u64;
            for (x, y) in positions(g) {
                let lev = g.level(x, y);
                if lev > 1 && lev < g.levels() - 1 {
                    expect += g.dag_parents(x, y).1 as u64;
                }
            }
            // Plus the four root pairs (c, w|s|e|n) when w, s, e, n have children.
            let roots = if n > 1 { 4 } else { 0 };
            assert_eq!(pairs, expect + roots, "{}", name(&l));
        }
    }
    // The initial triangles have corner apexes; the layouts must handle those too.
    let g = Grid::new(4).unwrap();
    let [_, se, _, nw] = g.corners();
    for l in all_layouts(g) {
        for apex in [se, nw] {
            let c = g.centre();
            let got = l.split_children(l.vertex(apex.0, apex.1), l.vertex(c.0, c.1));
            let want = split_children(apex, c).map(|(x, y)| l.vertex(x, y));
            assert_eq!(got, want, "{}", name(&l));
        }
    }
}

#[test]
fn soar_worked_example() {
    for n in 2..=10 {
        let l = Interleaved::new(Grid::new(n).unwrap());
        let v = |i: u64| {
            let (x, y) = l.coords(i).unwrap();
            Vertex { x, y, index: i }
        };
        assert_eq!(l.split_children(v(4), v(6)).map(|c| c.index), [9, 10]);
        assert_eq!(l.split_children(v(6), v(9)).map(|c| c.index), [20, 17]);
        // And the formula itself, independently of the implementation.
        let soar = |i: u64, j: u64| [4 * i - 7 + ((2 * i + j + 2) & 3), 4 * i - 7 + ((2 * i + j + 3) & 3)];
        assert_eq!(soar(4, 6), [9, 10]);
        assert_eq!(soar(6, 9), [20, 17]);
    }
}

/// True if, for every level `L`, all vertices of level `>= L` come before all vertices of level
/// `< L − gap`. `gap = 0`: the file is strictly coarse to fine; `gap = 1`: the two refinement levels
/// of one resolution (`2s + 1`, `2s + 2`) may share a stretch, nothing else may mix.
fn check_coarse_to_fine(l: &impl Layout, gap: u32) -> bool {
    let g = l.grid();
    let top = (g.levels() + 1) as usize; // corners
    let mut max_l = vec![0u64; top + 1];
    let mut min_l = vec![u64::MAX; top + 1];
    for (x, y) in positions(g) {
        let (lev, i) = (g.level(x, y) as usize, l.index(x, y));
        max_l[lev] = max_l[lev].max(i);
        min_l[lev] = min_l[lev].min(i);
    }
    let gap = gap as usize;
    (2 + gap..=top).all(|lv| {
        let max_coarse = (lv..=top).map(|a| max_l[a]).max().unwrap();
        let min_fine = (1..lv - gap).map(|b| min_l[b]).min().unwrap();
        max_coarse < min_fine
    })
}

#[test]
fn hierarchical_layouts_are_coarse_to_fine() {
    for n in 1..=8 {
        let g = Grid::new(n).unwrap();
        // Interleaved: strictly by level.
        assert!(check_coarse_to_fine(&Interleaved::new(g), 0), "interleaved n={n}");
        // Embedded and hz: levels 2s + 1 and 2s + 2 (one resolution) may mix, nothing else.
        assert!(check_coarse_to_fine(&Embedded::new(g), 1), "embedded n={n}");
        assert!(check_coarse_to_fine(&Hz::new(g), 1), "hz n={n}");
        if n >= 2 {
            // ...and they really do mix, so the weaker statement is the exact one.
            assert!(!check_coarse_to_fine(&Embedded::new(g), 0), "embedded n={n}");
            assert!(!check_coarse_to_fine(&Hz::new(g), 0), "hz n={n}");
        }
        // Non-hierarchical layouts are not coarse to fine.
        if n >= 3 {
            assert!(!check_coarse_to_fine(&RowMajor::new(g), 1));
            assert!(!check_coarse_to_fine(&Tiled::new(g, 4), 1));
        }
    }
}

#[test]
fn hz_prefixes_are_subsampled_grids() {
    for n in 1..=8 {
        let g = Grid::new(n).unwrap();
        let l = Hz::new(g);
        for (x, y) in positions(g) {
            // The first (2^j + 1)² records hold exactly the grid at step N / 2^j.
            let j = n - (x | y).trailing_zeros().min(n);
            assert!(l.index(x, y) < ((1u64 << j) + 1).pow(2));
            if j > 0 {
                assert!(l.index(x, y) >= ((1u64 << (j - 1)) + 1).pow(2));
            }
        }
    }
}

fn large_layouts(n: u32) -> Vec<AnyLayout> {
    let g = Grid::new(n).unwrap();
    vec![
        AnyLayout::RowMajor(RowMajor::new(g)),
        AnyLayout::Tiled(Tiled::new(g, 16)),
        AnyLayout::Tiled(Tiled::new(g, 1 << 15)),
        AnyLayout::Interleaved(Interleaved::new(g)),
        AnyLayout::Embedded(Embedded::new(g)),
        AnyLayout::Hz(Hz::new(g)),
    ]
}

/// A grid position from two fractions, snapped to a power-of-two step so that coarse levels,
/// borders and corners are hit often.
fn snapped(g: Grid, fx: f64, fy: f64, snap: u32) -> (u32, u32) {
    let m = g.max_coord();
    let step = 1u32 << snap.min(g.n());
    let s = |f: f64| ((f * m as f64) as u32).min(m) / step * step;
    (s(fx), s(fy))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4000))]

    #[test]
    fn random_positions_round_trip(n in 1u32..=31, fx in 0.0f64..=1.0, fy in 0.0f64..=1.0,
                                   snap in 0u32..32) {
        let g = Grid::new(n).unwrap();
        let (x, y) = snapped(g, fx, fy, snap);
        for l in large_layouts(n) {
            let i = l.index(x, y);
            prop_assert!(i < l.records());
            prop_assert_eq!(l.coords(i), Some((x, y)), "{}", name(&l));
        }
    }

    #[test]
    fn random_refinement_pairs_agree(n in 2u32..=31, fa in 0.0f64..1.0, fb in 0.0f64..1.0,
                                      ft in 0.0f64..1.0, kind in 0u32..3, which in 0usize..2) {
        let g = Grid::new(n).unwrap();
        // A split vertex with children, other than the centre (whose parents are corners):
        // a square centre at step 2^t, t <= n − 2, or an edge midpoint at step 2^t, 1 <= t <= n − 1.
        let centre = kind == 0;
        let t = if centre { (ft * (n - 1) as f64) as u32 } else { 1 + (ft * (n - 1) as f64) as u32 };
        let cells = 1u64 << (n - t - 1); // squares of side 2^(t+1) per row
        let odd = |f: f64| ((2 * ((f * cells as f64) as u64) + 1) << t) as u32;
        let even = |f: f64| ((2 * ((f * (cells + 1) as f64) as u64)) << t) as u32;
        let (x, y) = match kind {
            0 => (odd(fa), odd(fb)),
            1 => (odd(fa), even(fb)),
            _ => (even(fa), odd(fb)),
        };
        prop_assert!(g.level(x, y) > 1 && g.level(x, y) < g.levels(), "{x},{y}");
        let (ps, np) = g.dag_parents(x, y);
        let apex = ps[which % np];
        for l in large_layouts(n) {
            let got = l.split_children(l.vertex(apex.0, apex.1), l.vertex(x, y));
            let want = split_children(apex, (x, y)).map(|(cx, cy)| l.vertex(cx, cy));
            prop_assert_eq!(got, want, "{}", name(&l));
        }
    }

    #[test]
    fn random_indices_invert(n in 1u32..=31, f in 0.0f64..1.0) {
        // coords of an arbitrary slot is either None or a position that indexes back to it.
        for l in large_layouts(n) {
            let i = ((l.records() as f64) * f) as u64;
            if let Some((x, y)) = l.coords(i) {
                prop_assert_eq!(l.index(x, y), i, "{}", name(&l));
            }
        }
    }
}
