//! Nested object-space errors and bounding-sphere radii, bottom-up (Lindstrom & Pascucci 2001, §4).
//!
//! For vertex i the raw error δ_i is the vertical distance between its height and the mean height of
//! the edge it bisects. Nesting makes the active test monotone (a parent is active whenever a child
//! is), so top-down refinement never cracks:
//!   δ_i ← max(δ_i, δ_j) and r_i ← max(‖p_i − p_j‖ + r_j) over the DAG children j (r = 0 at level 1).
//! Corners and the centre are always active: their error is +∞.
//!
//! The computation runs level by level over a row-major grid of [`Record`]s (a mapped scratch file
//! during conversion), rows of one level in parallel. Values are computed in f64 and stored in f32
//! rounded *up*, so the stored nesting inequalities hold exactly when re-evaluated the same way
//! ([`nesting_violation`], used by `verify`).

use rayon::prelude::*;

use crate::error::Result;
use crate::format::terrain::Record;
use crate::layout::hierarchy::{Grid, VertexKind};
use crate::layout::Stored;

/// Rounds to the nearest f32 that is not below `v` (so stored bounds stay conservative).
#[inline]
pub fn f32_up(v: f64) -> f32 {
    let f = v as f32;
    if (f as f64) < v {
        f.next_up()
    } else {
        f
    }
}

/// Euclidean distance in metres between two grid posts with heights.
#[inline(always)]
pub fn distance_m(spacing_m: [f64; 2], a: (u32, u32, f32), b: (u32, u32, f32)) -> f64 {
    let dx = (a.0 as f64 - b.0 as f64) * spacing_m[0];
    let dy = (a.1 as f64 - b.1 as f64) * spacing_m[1];
    let dz = a.2 as f64 - b.2 as f64;
    (dx * dx + dy * dy + dz * dz).sqrt()
}

/// Raw vertical error of `(x, y)` against the midpoint of the edge it bisects.
#[inline(always)]
pub fn raw_error(z: f32, za: f32, zb: f32) -> f64 {
    (z as f64 - 0.5 * (za as f64 + zb as f64)).abs()
}

/// What one level's pass reads and writes: heights, the finished bounds of finer levels, and
/// the slots for this level's results. The whole-grid pass ([`compute_bounds`]) and the passes
/// of sharded conversion (a window around a block, the levels above the blocks: see
/// `preprocess::shard`) run the same arithmetic through this, so their results agree bit for bit.
pub(crate) trait LevelRows {
    /// Height of grid post `(x, y)` (beyond the DEM: its nearest edge post's).
    fn z(&self, x: u32, y: u32) -> f32;
    /// Bounds of the stored finer-level vertex `(x, y)` and whether it is *relevant* (see
    /// `preprocess::shard`), or `None` where the pass does not hold it.
    fn child(&self, x: u32, y: u32) -> Option<([f32; 2], bool)>;
    /// Stores the bounds of `(x, y)`; `relevant` is whether a child was.
    fn set(&self, x: u32, y: u32, error: f32, radius: f32, relevant: bool);
}

/// Heights and bounds (error, radius) shared across threads during one level: heights row-major
/// over the DEM's `width × height` posts (a post beyond them reads as the nearest edge post: the
/// edge-replicating padding, never stored), bounds row-major over the whole grid.
///
/// Within a level every vertex is written by exactly one task (tasks own whole rows), and the
/// bounds read are those of finer levels (children, finished); heights are only read. That is what
/// makes the raw accesses sound.
struct SharedRows {
    z: *const f32,
    width: u32,
    height: u32,
    bounds: *mut [f32; 2],
    side: usize,
}
// SAFETY: the grids outlive the pass that shares them; the type's note says why the accesses
// from several tasks do not alias.
unsafe impl Send for SharedRows {}
// SAFETY: as for Send.
unsafe impl Sync for SharedRows {}

impl LevelRows for SharedRows {
    #[inline(always)]
    fn z(&self, x: u32, y: u32) -> f32 {
        let i = y.min(self.height - 1) as usize * self.width as usize + x.min(self.width - 1) as usize;
        // SAFETY: clamped into the height grid; heights are only read.
        unsafe { self.z.add(i).read() }
    }
    #[inline(always)]
    fn child(&self, x: u32, y: u32) -> Option<([f32; 2], bool)> {
        let i = y as usize * self.side + x as usize;
        // SAFETY: in bounds (callers pass grid positions); see the type's note on aliasing.
        Some((unsafe { self.bounds.add(i).read() }, false))
    }
    #[inline(always)]
    fn set(&self, x: u32, y: u32, error: f32, radius: f32, _relevant: bool) {
        // SAFETY: as above.
        unsafe { self.bounds.add(y as usize * self.side + x as usize).write([error, radius]) }
    }
}

/// The nested error and radius of `(x, y)` from its own raw error and its stored children's
/// records (general form, any vertex; the reference that the specialised level loops must match).
#[cfg(test)]
fn nested(
    grid: Grid,
    stored: &Stored,
    spacing_m: [f64; 2],
    get: impl Fn(u32, u32) -> Record,
    x: u32,
    y: u32,
) -> (f64, f64) {
    let me = get(x, y);
    let (mut err, mut rad) = match grid.split_edge(x, y) {
        Some([a, b]) => (raw_error(me.z, get(a.0, a.1).z, get(b.0, b.1).z), 0.0f64),
        None => (f64::INFINITY, 0.0),
    };
    let (children, count) = grid.dag_children(x, y);
    for &(cx, cy) in children[..count].iter().filter(|c| stored.contains(c.0, c.1)) {
        let c = get(cx, cy);
        err = err.max(c.error as f64);
        rad = rad.max(distance_m(spacing_m, (x, y, me.z), (cx, cy, c.z)) + c.radius as f64);
    }
    (err, rad)
}

/// Folds child `(cx, cy)` into the running error, radius and relevance of `(x, y, z)`, if it is
/// stored (`cx ≤ kmax.0`, `cy ≤ kmax.1`: the stored rectangle of the children's level) and held
/// by the pass. A null child is never active, so its parent need not contain it.
#[inline(always)]
fn fold_child<R: LevelRows>(
    spacing_m: [f64; 2],
    rows: &R,
    kmax: (u32, u32),
    me: (u32, u32, f32),
    (cx, cy): (u32, u32),
    acc: &mut (f64, f64, bool),
) {
    if cx > kmax.0 || cy > kmax.1 {
        return;
    }
    let Some(([error, radius], relevant)) = rows.child(cx, cy) else { return };
    acc.0 = acc.0.max(error as f64);
    acc.1 = acc.1.max(distance_m(spacing_m, me, (cx, cy, rows.z(cx, cy))) + radius as f64);
    acc.2 |= relevant;
}

/// The first `x ≥ lo` of the progression `x0, x0 + stride, …`.
#[inline(always)]
fn first_from(x0: u32, stride: u32, lo: u32) -> u32 {
    if lo <= x0 {
        x0
    } else {
        x0 + (lo - x0).div_ceil(stride) * stride
    }
}

/// One row of one level: the vertices, their split edges and their children are known from the
/// level alone, so this avoids the general classification of [`nested`] (same arithmetic, same
/// results; a test compares the two). Only the level's stored vertices (`x ≤ xmax`) with
/// `x_lo ≤ x ≤ x_hi` are computed; returns how many.
#[inline(always)]
#[allow(clippy::too_many_arguments, reason = "internal; each argument is a distinct input")]
pub(crate) fn level_row<R: LevelRows>(
    grid: Grid,
    stored: &Stored,
    spacing_m: [f64; 2],
    rows: &R,
    level: u32,
    y: u32,
    (x_lo, x_hi): (u32, u32),
) -> u64 {
    let m = grid.max_coord();
    let odd = level % 2 == 1;
    let step = 1u32 << ((level - 1) / 2);
    let half = step / 2; // children of an edge midpoint are half a step away diagonally
    let xmax = stored.max_at(level).0.min(x_hi);
    let kmax = if level > 1 { stored.max_at(level - 1) } else { (0, 0) };
    let mut count = 0u64;
    let mut finish = |x: u32, acc: (f64, f64, bool)| {
        let err = if (x, y) == grid.centre() { f64::INFINITY } else { acc.0 };
        rows.set(x, y, f32_up(err), f32_up(acc.1), acc.2);
        count += 1;
    };
    let fold =
        |me: (u32, u32, f32), c: (u32, u32), acc: &mut (f64, f64, bool)| fold_child(spacing_m, rows, kmax, me, c, acc);
    if odd && (y / step).is_multiple_of(2) {
        // Midpoints of horizontal edges: x = step, 3·step, …
        let mut x = first_from(step, 2 * step, x_lo);
        while x < m && x <= xmax {
            let z = rows.z(x, y);
            let mut acc = (raw_error(z, rows.z(x - step, y), rows.z(x + step, y)), 0.0, false);
            if half > 0 {
                if y < m {
                    fold((x, y, z), (x + half, y + half), &mut acc);
                    fold((x, y, z), (x - half, y + half), &mut acc);
                }
                if y > 0 {
                    fold((x, y, z), (x - half, y - half), &mut acc);
                    fold((x, y, z), (x + half, y - half), &mut acc);
                }
            }
            finish(x, acc);
            x += 2 * step;
        }
    } else if odd {
        // Midpoints of vertical edges: x = 0, 2·step, …, 2^n.
        let mut x = first_from(0, 2 * step, x_lo);
        while x <= m && x <= xmax {
            let z = rows.z(x, y);
            let mut acc = (raw_error(z, rows.z(x, y - step), rows.z(x, y + step)), 0.0, false);
            if half > 0 {
                if x < m {
                    fold((x, y, z), (x + half, y + half), &mut acc);
                    fold((x, y, z), (x + half, y - half), &mut acc);
                }
                if x > 0 {
                    fold((x, y, z), (x - half, y + half), &mut acc);
                    fold((x, y, z), (x - half, y - half), &mut acc);
                }
            }
            finish(x, acc);
            x += 2 * step;
        }
    } else {
        // Square centres: x = step, 3·step, …; they bisect the diagonal joining the corner whose
        // coordinates are even multiples of 2·step with the one whose are odd multiples.
        let mut x = first_from(step, 2 * step, x_lo);
        while x < m && x <= xmax {
            let z = rows.z(x, y);
            let rising = (((x - step) / (2 * step)) + ((y - step) / (2 * step))).is_multiple_of(2);
            let (za, zb) = if rising {
                (rows.z(x - step, y - step), rows.z(x + step, y + step))
            } else {
                (rows.z(x - step, y + step), rows.z(x + step, y - step))
            };
            let mut acc = (raw_error(z, za, zb), 0.0, false);
            fold((x, y, z), (x + step, y), &mut acc);
            fold((x, y, z), (x, y + step), &mut acc);
            fold((x, y, z), (x - step, y), &mut acc);
            fold((x, y, z), (x, y - step), &mut acc);
            finish(x, acc);
            x += 2 * step;
        }
    }
    count
}

/// The rows of `level` (stored ones, `y ≤ ymax`) that hold vertices: edge midpoints lie on every
/// row that is a multiple of step, square centres on odd multiples.
pub(crate) fn level_rows(grid: Grid, stored: &Stored, level: u32) -> impl Iterator<Item = u32> {
    let step = 1u32 << ((level - 1) / 2);
    let ymax = stored.max_at(level).1;
    let (first, stride) = if level % 2 == 1 { (0, step) } else { (step, 2 * step) };
    (first..grid.size().min(ymax + 1)).step_by(stride as usize)
}

/// Computes error and radius (`bounds[i] = [error, radius]`, row-major over the whole grid) for
/// every stored vertex of `grid` over a DEM of `width × height` posts (see [`Stored`]) from its
/// heights `z` (row-major, `width` per row; beyond the DEM a post has its nearest edge post's
/// height). The bounds of null vertices are left as they are (zero in a fresh grid). Heights and
/// bounds live in separate arrays so that, during conversion, the mapped height pages are written
/// once and only read afterwards. `progress` is called with the number of vertices finished after
/// each row.
#[allow(clippy::too_many_arguments, reason = "internal; each argument is a distinct input")]
pub fn compute_bounds(
    grid: Grid,
    spacing_m: [f64; 2],
    z: &[f32],
    [width, height]: [u32; 2],
    bounds: &mut [[f32; 2]],
    progress: &(dyn Fn(u64) + Sync),
    check_cancel: &(dyn Fn() -> Result<()> + Sync),
) -> Result<()> {
    let side = grid.size();
    assert!(width >= 1 && height >= 1 && width <= side && height <= side, "DEM larger than its grid");
    assert!(z.len() as u64 == width as u64 * height as u64 && bounds.len() as u64 == grid.vertices());
    let stored = Stored::new(grid, width, height);
    let shared = SharedRows { z: z.as_ptr(), width, height, bounds: bounds.as_mut_ptr(), side: side as usize };
    for level in 1..=grid.levels() {
        let rows: Vec<u32> = level_rows(grid, &stored, level).collect();
        rows.par_iter().try_for_each(|&y| -> Result<()> {
            check_cancel()?;
            progress(level_row(grid, &stored, spacing_m, &shared, level, y, (0, u32::MAX)));
            Ok(())
        })?;
    }
    for (x, y) in grid.corners() {
        shared.set(x, y, f32::INFINITY, 0.0, false);
    }
    Ok(())
}

/// Checks the stored bounds of `(x, y)` against its raw error and its children, recomputed exactly
/// as [`compute_bounds`] does. Returns a description of the first violated inequality.
///
/// A null vertex (not in `stored`) must be all zero; a stored one need not contain its null
/// children (they are never active).
pub fn nesting_violation(
    grid: Grid,
    stored: &Stored,
    spacing_m: [f64; 2],
    get: impl Fn(u32, u32) -> Record,
    x: u32,
    y: u32,
) -> Option<String> {
    let me = get(x, y);
    if !stored.contains(x, y) {
        if bytemuck::bytes_of(&me).iter().any(|&b| b != 0) {
            return Some(format!("({x}, {y}): a null (unstored) vertex with a non-zero record {me:?}"));
        }
        return None;
    }
    if !me.z.is_finite() {
        return Some(format!("({x}, {y}): height {} is not finite", me.z));
    }
    let always_active = grid.kind(x, y) == VertexKind::Corner || (x, y) == grid.centre();
    if always_active && me.error != f32::INFINITY {
        return Some(format!("({x}, {y}): corner/centre error {} is not +inf", me.error));
    }
    if me.radius.is_nan() || me.radius < 0.0 || me.error.is_nan() {
        return Some(format!("({x}, {y}): error {} / radius {} invalid", me.error, me.radius));
    }
    if let Some([a, b]) = grid.split_edge(x, y) {
        let raw = raw_error(me.z, get(a.0, a.1).z, get(b.0, b.1).z);
        if (me.error as f64) < raw {
            return Some(format!("({x}, {y}): error {} below its raw error {raw}", me.error));
        }
    }
    let (children, count) = grid.dag_children(x, y);
    for &(cx, cy) in children[..count].iter().filter(|c| stored.contains(c.0, c.1)) {
        let c = get(cx, cy);
        if me.error < c.error {
            return Some(format!("({x}, {y}): error {} below child ({cx}, {cy})'s {}", me.error, c.error));
        }
        let need = distance_m(spacing_m, (x, y, me.z), (cx, cy, c.z)) + c.radius as f64;
        if (me.radius as f64) < need {
            return Some(format!(
                "({x}, {y}): radius {} does not contain child ({cx}, {cy})'s sphere ({need})",
                me.radius
            ));
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid_with(n: u32, f: impl Fn(u32, u32) -> f32) -> (Grid, Vec<Record>) {
        let g = Grid::new(n).unwrap();
        let s = g.size();
        let recs = (0..s)
            .flat_map(|y| (0..s).map(move |x| (x, y)))
            .map(|(x, y)| Record { z: f(x, y), error: 0.0, radius: 0.0 })
            .collect();
        (g, recs)
    }

    fn run(g: Grid, spacing: [f64; 2], recs: &mut [Record]) {
        let z: Vec<f32> = recs.iter().map(|r| r.z).collect();
        let mut bounds = vec![[0.0f32; 2]; z.len()];
        compute_bounds(g, spacing, &z, [g.size(), g.size()], &mut bounds, &|_| {}, &|| Ok(())).unwrap();
        for (r, [e, rad]) in recs.iter_mut().zip(bounds) {
            (r.error, r.radius) = (e, rad);
        }
    }

    #[test]
    fn level_loops_match_the_general_definition() {
        // Rough pseudo-random terrain with non-square posts; every stored value must equal the
        // general recomputation from its children (bit for bit).
        let (g, mut recs) = grid_with(6, |x, y| {
            let h = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
            (h.wrapping_mul(6364136223846793005) >> 40) as f32 / 1000.0
        });
        let spacing = [3.0, 7.5];
        run(g, spacing, &mut recs);
        let s = g.size() as usize;
        let get = |x: u32, y: u32| recs[y as usize * s + x as usize];
        for y in 0..g.size() {
            for x in 0..g.size() {
                if g.kind(x, y) == VertexKind::Corner {
                    continue;
                }
                let (e, r) = nested(g, &Stored::all(g), spacing, get, x, y);
                let e = if (x, y) == g.centre() { f64::INFINITY } else { e };
                assert_eq!((get(x, y).error, get(x, y).radius), (f32_up(e), f32_up(r)), "({x},{y})");
                assert_eq!(nesting_violation(g, &Stored::all(g), spacing, get, x, y), None);
            }
        }
    }

    #[test]
    fn planar_terrain_has_zero_error_but_positive_radii() {
        let (g, mut recs) = grid_with(4, |x, y| 3.0 * x as f32 - 2.0 * y as f32);
        run(g, [1.0, 1.0], &mut recs);
        let s = g.size() as usize;
        for y in 0..g.size() {
            for x in 0..g.size() {
                let r = recs[y as usize * s + x as usize];
                let special = g.kind(x, y) == VertexKind::Corner || (x, y) == g.centre();
                if special {
                    assert_eq!(r.error, f32::INFINITY);
                } else {
                    assert_eq!(r.error, 0.0, "plane at ({x},{y})");
                }
                if g.level(x, y) == 1 || g.kind(x, y) == VertexKind::Corner {
                    assert_eq!(r.radius, 0.0);
                } else {
                    assert!(r.radius > 0.0);
                }
                assert_eq!(
                    nesting_violation(g, &Stored::all(g), [1.0, 1.0], |a, b| recs[b as usize * s + a as usize], x, y),
                    None
                );
            }
        }
    }

    #[test]
    fn spike_error_propagates_to_every_ancestor() {
        // A 10 m spike at a finest-level vertex: its raw error is 10, and every DAG ancestor's
        // nested error must be at least 10.
        let (g, mut recs) = grid_with(3, |x, y| if (x, y) == (3, 2) { 10.0 } else { 0.0 });
        run(g, [2.0, 2.0], &mut recs);
        let s = g.size() as usize;
        let at = |x: u32, y: u32| recs[y as usize * s + x as usize];
        assert_eq!(g.level(3, 2), 1);
        assert_eq!(at(3, 2).error, 10.0);
        let mut frontier = vec![(3u32, 2u32)];
        while let Some((x, y)) = frontier.pop() {
            assert!(at(x, y).error >= 10.0, "ancestor ({x},{y})");
            let (ps, np) = g.dag_parents(x, y);
            frontier.extend_from_slice(&ps[..np]);
        }
        // Vertices whose descendants do not include the spike, and whose split edges do not touch
        // it, stay exact zero.
        assert_eq!(at(1, 0).error, 0.0);
    }

    #[test]
    fn radius_of_level_two_vertex_is_distance_to_farthest_child() {
        let (g, mut recs) = grid_with(2, |_, _| 0.0);
        run(g, [3.0, 4.0], &mut recs);
        let s = g.size() as usize;
        // (1,1) is a square centre at step 1: children (0,1), (2,1), (1,0), (1,2) at 3 m and 4 m.
        assert_eq!(recs[s + 1].radius, 4.0);
    }

    /// A DEM smaller than its grid: the stored vertices' bounds are the general definition's
    /// over stored children, with heights beyond the DEM those of its edge; null vertices stay
    /// zero; the nesting check passes everywhere.
    #[test]
    fn a_smaller_dem_computes_only_its_stored_vertices() {
        let g = Grid::new(6).unwrap();
        let (w, h) = (40u32, 21u32);
        let dem = |x: u32, y: u32| ((x * 7 + y * 13) % 29) as f32 * 0.7 + (x as f32 * 0.3).sin() * 5.0;
        let z: Vec<f32> = (0..h).flat_map(|y| (0..w).map(move |x| dem(x, y))).collect();
        let mut bounds = vec![[0.0f32; 2]; g.vertices() as usize];
        let spacing = [2.0, 3.0];
        compute_bounds(g, spacing, &z, [w, h], &mut bounds, &|_| {}, &|| Ok(())).unwrap();
        let stored = Stored::new(g, w, h);
        let s = g.size() as usize;
        let get = |x: u32, y: u32| {
            let [error, radius] = bounds[y as usize * s + x as usize];
            let z = if stored.contains(x, y) { dem(x.min(w - 1), y.min(h - 1)) } else { 0.0 };
            Record { z, error, radius }
        };
        let clamped = |x: u32, y: u32| Record { z: dem(x.min(w - 1), y.min(h - 1)), ..get(x, y) };
        let mut nulls = 0;
        for y in 0..g.size() {
            for x in 0..g.size() {
                assert_eq!(nesting_violation(g, &stored, spacing, get, x, y), None, "({x},{y})");
                if !stored.contains(x, y) {
                    assert_eq!(bounds[y as usize * s + x as usize], [0.0, 0.0]);
                    nulls += 1;
                } else if g.kind(x, y) != VertexKind::Corner {
                    let (e, r) = nested(g, &stored, spacing, clamped, x, y);
                    let e = if (x, y) == g.centre() { f64::INFINITY } else { e };
                    assert_eq!((get(x, y).error, get(x, y).radius), (f32_up(e), f32_up(r)), "({x},{y})");
                }
            }
        }
        assert_eq!(nulls as u64, g.vertices() - stored.count());
        assert!(nulls > 3000, "{nulls}");
    }
}
