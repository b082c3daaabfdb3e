//! The 2-factor layout (Sajadi et al. 2009, §6, extending P. Diaz-Gutierrez & M. Gopi,
//! "Quadrilateral and tetrahedral mesh stripification using 2-factor partitioning of the dual
//! graph", The Visual Computer 21, 2005): order nodes so that cheap (near, alike) pairs are
//! adjacent on disk.
//!
//! - Proximity graph: each node joined to its [`TwoFactorOptions::neighbours`] nearest nodes,
//!   weighted by distance (or, at the finest level, by normal deviation). We also join the nodes
//!   in Hilbert order into one cycle: it guarantees that a 2-factor exists (the cycle is one), so
//!   the matching below never fails, and the optimum can only be cheaper than that cycle.
//! - Inflated graph (the paper's Figure 4): a node of degree d becomes d *duplicates*, one per
//!   incident edge, and d − 2 *dopes*, each joined to every duplicate at cost 0; an original edge
//!   joins the two duplicates it owns. In a perfect matching the dopes take d − 2 duplicates, so
//!   exactly two of the node's edges are matched across: a perfect matching of the inflated graph
//!   is a 2-factor of the original, and a minimum-weight one ([`super::matching`]) is a
//!   minimum-weight 2-factor.
//! - The 2-factor is a set of cycles; each is cut at its heaviest edge, and the paths are chained
//!   greedily, each next path entered at the endpoint nearest the current end.
//! - Hierarchy: a set larger than [`TwoFactorOptions::leaf_triangles`] is split into at most
//!   [`TwoFactorOptions::fanout`] clusters by Lloyd's algorithm (k-means, seeds spread along the
//!   Hilbert order), the clusters' centroids are ordered as above, and each cluster is laid out
//!   recursively in that order. So no matching sees more than `max(fanout, leaf_triangles)` nodes
//!   (12 by default): an inflated graph of at most 12 · (2 · 11 − 2) = 240 vertices, in practice
//!   about 100, which keeps the O(n³) matching cheap. Within a leaf the weights switch to normal
//!   deviation (the angle between triangle normals, plus 1% of the distance to break ties on flat
//!   ground), which groups triangles facing one way for the pages' normal cones.

use std::sync::atomic::{AtomicU64, Ordering};

use rayon::prelude::*;

use super::hilbert::hilbert_order;
use super::matching::{min_weight_perfect_matching, MatchingError};
use crate::error::{Error, Result};

/// Parameters of the hierarchical 2-factor layout.
#[derive(Clone, Copy, Debug)]
pub struct TwoFactorOptions {
    /// Clusters per level (Lloyd's k): also the most nodes a cluster-level matching orders.
    pub fanout: usize,
    /// A cluster of at most this many triangles is ordered directly, by normal deviation.
    pub leaf_triangles: usize,
    /// Nearest neighbours per node in the proximity graph.
    pub neighbours: usize,
    /// Lloyd iterations per split (fewer when the assignment settles).
    pub lloyd_iterations: usize,
}

impl Default for TwoFactorOptions {
    fn default() -> Self {
        TwoFactorOptions { fanout: 8, leaf_triangles: 12, neighbours: 3, lloyd_iterations: 6 }
    }
}

/// Cost quantum: weights are scaled so that the largest is about 2^24 before matching (exact
/// integer duals); ties below that resolution are broken arbitrarily.
const COST_SCALE: f64 = (1 << 24) as f64;

/// A minimum-weight 2-factor of the graph (`nodes`, `edges` as (u, v, cost)): the indices of the
/// chosen edges, two at every node. Fails when the graph has none (e.g. a node of degree < 2).
pub fn min_two_factor(nodes: usize, edges: &[(usize, usize, i64)]) -> std::result::Result<Vec<usize>, MatchingError> {
    let mut incident = vec![Vec::new(); nodes];
    for (k, &(u, v, _)) in edges.iter().enumerate() {
        if u >= nodes || v >= nodes || u == v {
            return Err(MatchingError::BadEdge { edge: k, u, v, vertices: nodes });
        }
        incident[u].push(k);
        incident[v].push(k);
    }
    if let Some(v) = (0..nodes).find(|&v| incident[v].len() < 2) {
        let _ = v;
        return Err(MatchingError::NoPerfectMatching { vertices: nodes, matched: 0 });
    }
    // Node v's duplicates are first[v] .. first[v] + d, its dopes the d − 2 after them.
    let mut first = Vec::with_capacity(nodes);
    let mut total = 0;
    for inc in &incident {
        first.push(total);
        total += 2 * inc.len() - 2;
    }
    // The duplicate of edge k at its end v.
    let dup = |v: usize, k: usize| first[v] + incident[v].iter().position(|&e| e == k).expect("incident edge");
    let mut inflated = Vec::new();
    for (k, &(u, v, c)) in edges.iter().enumerate() {
        inflated.push((dup(u, k), dup(v, k), c));
    }
    for v in 0..nodes {
        let d = incident[v].len();
        for dope in 0..d - 2 {
            for i in 0..d {
                inflated.push((first[v] + d + dope, first[v] + i, 0));
            }
        }
    }
    let mate = min_weight_perfect_matching(total, &inflated)?;
    Ok((0..edges.len()).filter(|&k| mate[dup(edges[k].0, k)] == dup(edges[k].1, k)).collect())
}

/// Orders `points` (one per node, in a spatially coherent order such as Hilbert's) by a
/// minimum 2-factor of their proximity graph, costs from `cost(i, j)` (≥ 0); returns positions
/// into `points`.
fn order_by_two_factor(
    points: &[[f64; 3]],
    neighbours: usize,
    cost: impl Fn(usize, usize) -> f64,
) -> Result<Vec<usize>> {
    let m = points.len();
    if m <= 2 {
        return Ok((0..m).collect());
    }
    let dist2 = |i: usize, j: usize| (0..3).map(|k| (points[i][k] - points[j][k]).powi(2)).sum::<f64>();
    let mut pairs: Vec<(usize, usize)> = (0..m).map(|i| (i.min((i + 1) % m), i.max((i + 1) % m))).collect();
    let mut near: Vec<usize> = Vec::with_capacity(m);
    for i in 0..m {
        near.clear();
        near.extend((0..m).filter(|&j| j != i));
        near.sort_by(|&a, &b| dist2(i, a).total_cmp(&dist2(i, b)));
        for &j in near.iter().take(neighbours) {
            pairs.push((i.min(j), i.max(j)));
        }
    }
    pairs.sort_unstable();
    pairs.dedup();
    let costs: Vec<f64> = pairs.iter().map(|&(i, j)| cost(i, j)).collect();
    let top = costs.iter().copied().fold(0.0f64, f64::max);
    let scale = if top > 0.0 { COST_SCALE / top } else { 0.0 };
    let edges: Vec<(usize, usize, i64)> =
        pairs.iter().zip(&costs).map(|(&(i, j), &c)| (i, j, (c * scale).round() as i64)).collect();
    let chosen = min_two_factor(m, &edges).map_err(|e| Error::Layout(format!("2-factor of {m} nodes: {e}")))?;
    // Two neighbours per node along the cycles.
    let mut next = vec![[usize::MAX; 2]; m];
    for &k in &chosen {
        let (u, v, _) = edges[k];
        for (a, b) in [(u, v), (v, u)] {
            let slot = if next[a][0] == usize::MAX { 0 } else { 1 };
            next[a][slot] = b;
        }
    }
    let cost_of = |a: usize, b: usize| {
        let (i, j) = (a.min(b), a.max(b));
        edges[pairs.binary_search(&(i, j)).expect("a chosen edge")].2
    };
    // Each cycle cut at its heaviest edge, as a path.
    let mut seen = vec![false; m];
    let mut paths: Vec<Vec<usize>> = Vec::new();
    for s in 0..m {
        if seen[s] {
            continue;
        }
        let mut cycle = vec![s];
        seen[s] = true;
        let (mut prev, mut at) = (s, next[s][0]);
        while at != s {
            seen[at] = true;
            cycle.push(at);
            let step = if next[at][0] == prev { next[at][1] } else { next[at][0] };
            prev = at;
            at = step;
        }
        let len = cycle.len();
        let cut = (0..len).max_by_key(|&i| cost_of(cycle[i], cycle[(i + 1) % len])).unwrap_or(0);
        cycle.rotate_left((cut + 1) % len);
        paths.push(cycle);
    }
    // Chain: start with the path holding node 0 (the first in Hilbert order), then always the
    // path with the endpoint nearest the current end.
    let mut order = Vec::with_capacity(m);
    let mut current = paths.swap_remove(paths.iter().position(|p| p.contains(&0)).unwrap_or(0));
    if current.last() == Some(&0) {
        current.reverse();
    }
    order.extend_from_slice(&current);
    while !paths.is_empty() {
        let end = *order.last().expect("non-empty");
        let (best, flip) = (0..paths.len())
            .flat_map(|p| [(p, false), (p, true)])
            .min_by(|&(p, fa), &(q, fb)| {
                let ea = if fa { *paths[p].last().unwrap() } else { paths[p][0] };
                let eb = if fb { *paths[q].last().unwrap() } else { paths[q][0] };
                dist2(end, ea).total_cmp(&dist2(end, eb))
            })
            .expect("a path left");
        let mut p = paths.swap_remove(best);
        if flip {
            p.reverse();
        }
        order.extend_from_slice(&p);
    }
    Ok(order)
}

/// The hierarchical 2-factor layout of triangles with these centroids and unit normals: a
/// permutation of `0..n` (position → triangle). `placed` is called with the number of triangles
/// laid out so far (for a progress bar; from several threads).
pub fn two_factor_order(
    centroids: &[[f64; 3]],
    normals: &[[f64; 3]],
    options: &TwoFactorOptions,
    placed: &(dyn Fn(u64) + Sync),
) -> Result<Vec<u32>> {
    if centroids.len() != normals.len() {
        return Err(Error::InvalidArgument("one normal per centroid".into()));
    }
    if options.fanout < 2 || options.leaf_triangles < 1 {
        return Err(Error::InvalidArgument("2-factor layout: fanout ≥ 2 and leaf size ≥ 1".into()));
    }
    let start = hilbert_order(centroids);
    let ctx = Ctx { centroids, normals, options, placed, done: AtomicU64::new(0) };
    ctx.lay_out(&start)
}

struct Ctx<'a> {
    centroids: &'a [[f64; 3]],
    normals: &'a [[f64; 3]],
    options: &'a TwoFactorOptions,
    placed: &'a (dyn Fn(u64) + Sync),
    done: AtomicU64,
}

impl Ctx<'_> {
    fn lay_out(&self, items: &[u32]) -> Result<Vec<u32>> {
        crate::sys::cancel::check()?;
        if items.len() <= self.options.leaf_triangles {
            return self.leaf(items);
        }
        let clusters = self.lloyd(items);
        let centres: Vec<[f64; 3]> = clusters.iter().map(|c| self.mean(c)).collect();
        let order = order_by_two_factor(&centres, self.options.neighbours, |i, j| dist(centres[i], centres[j]))?;
        let parts: Vec<Vec<u32>> = order.par_iter().map(|&c| self.lay_out(&clusters[c])).collect::<Result<_>>()?;
        Ok(parts.concat())
    }

    /// The finest level: triangles ordered by normal deviation (1% of the distance breaks ties).
    fn leaf(&self, items: &[u32]) -> Result<Vec<u32>> {
        let pts: Vec<[f64; 3]> = items.iter().map(|&t| self.centroids[t as usize]).collect();
        let span = pts.iter().flat_map(|a| pts.iter().map(move |b| dist(*a, *b))).fold(0.0f64, f64::max);
        let order = order_by_two_factor(&pts, self.options.neighbours, |i, j| {
            let (a, b) = (self.normals[items[i] as usize], self.normals[items[j] as usize]);
            let cos = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]).clamp(-1.0, 1.0);
            let tie = if span > 0.0 { 0.01 * dist(pts[i], pts[j]) / span } else { 0.0 };
            cos.acos() / std::f64::consts::PI + tie
        })?;
        let n = self.done.fetch_add(items.len() as u64, Ordering::Relaxed) + items.len() as u64;
        (self.placed)(n);
        Ok(order.into_iter().map(|i| items[i]).collect())
    }

    fn mean(&self, items: &[u32]) -> [f64; 3] {
        let mut s = [0.0; 3];
        for &t in items {
            for (sum, c) in s.iter_mut().zip(self.centroids[t as usize]) {
                *sum += c;
            }
        }
        s.map(|v| v / items.len().max(1) as f64)
    }

    /// Lloyd's algorithm with `fanout` seeds spread along `items` (Hilbert-ordered); clusters
    /// keep the items' order. When the points cannot be separated (all equal), contiguous
    /// chunks of the Hilbert order stand in, so the recursion always shrinks.
    fn lloyd(&self, items: &[u32]) -> Vec<Vec<u32>> {
        let k = self.options.fanout.min(items.len());
        let mut centres: Vec<[f64; 3]> =
            (0..k).map(|j| self.centroids[items[(2 * j + 1) * items.len() / (2 * k)] as usize]).collect();
        let mut assign = vec![0u8; items.len()];
        for round in 0..self.options.lloyd_iterations.max(1) {
            let mut changed = false;
            for (a, &t) in assign.iter_mut().zip(items) {
                let p = self.centroids[t as usize];
                let best = (0..k).min_by(|&x, &y| dist2(p, centres[x]).total_cmp(&dist2(p, centres[y]))).unwrap_or(0);
                changed |= *a as usize != best;
                *a = best as u8;
            }
            if round > 0 && !changed {
                break;
            }
            let mut sums = vec![([0.0f64; 3], 0usize); k];
            for (&a, &t) in assign.iter().zip(items) {
                let (s, n) = &mut sums[a as usize];
                for (sum, c) in s.iter_mut().zip(self.centroids[t as usize]) {
                    *sum += c;
                }
                *n += 1;
            }
            for (c, (s, n)) in centres.iter_mut().zip(sums) {
                if n > 0 {
                    *c = s.map(|v| v / n as f64);
                }
            }
        }
        let mut clusters = vec![Vec::new(); k];
        for (&a, &t) in assign.iter().zip(items) {
            clusters[a as usize].push(t);
        }
        clusters.retain(|c| !c.is_empty());
        if clusters.len() < 2 {
            let chunk = items.len().div_ceil(k);
            clusters = items.chunks(chunk).map(<[u32]>::to_vec).collect();
        }
        clusters
    }
}

fn dist2(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]).powi(2)).sum()
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    dist2(a, b).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Least cost over all edge subsets in which every node has degree 2 (None: no 2-factor).
    fn brute_force(n: usize, edges: &[(usize, usize, i64)]) -> Option<i64> {
        let mut best = None;
        for mask in 0u32..1 << edges.len() {
            let mut degree = vec![0; n];
            let mut cost = 0;
            for (k, &(u, v, c)) in edges.iter().enumerate() {
                if mask >> k & 1 == 1 {
                    degree[u] += 1;
                    degree[v] += 1;
                    cost += c;
                }
            }
            if degree.iter().all(|&d| d == 2) {
                best = Some(best.map_or(cost, |b: i64| b.min(cost)));
            }
        }
        best
    }

    fn graph() -> impl Strategy<Value = (usize, Vec<(usize, usize, i64)>)> {
        (3usize..=7, prop::collection::vec((any::<bool>(), 0i64..6), 21)).prop_map(|(n, draws)| {
            let mut edges = Vec::new();
            let mut k = 0;
            for u in 0..n {
                for v in u + 1..n {
                    let (keep, c) = draws[k];
                    k += 1;
                    if keep || n <= 4 {
                        edges.push((u, v, c));
                    }
                }
            }
            (n, edges)
        })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(400))]
        #[test]
        fn two_factor_cost_is_the_brute_force_optimum((n, edges) in graph()) {
            match (min_two_factor(n, &edges), brute_force(n, &edges)) {
                (Ok(chosen), Some(best)) => {
                    let mut degree = vec![0; n];
                    for &k in &chosen {
                        degree[edges[k].0] += 1;
                        degree[edges[k].1] += 1;
                    }
                    prop_assert!(degree.iter().all(|&d| d == 2), "degrees {:?}", degree);
                    prop_assert_eq!(chosen.iter().map(|&k| edges[k].2).sum::<i64>(), best);
                }
                (Err(_), None) => {}
                (got, want) => prop_assert!(false, "2-factor {:?}, brute force {:?}", got, want),
            }
        }
    }

    fn cloud(n: usize, seed: u64) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
        let mut s = seed;
        let mut r = move || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let pts = (0..n).map(|_| [r(), r(), r() * 0.1]).collect();
        let nrm = (0..n)
            .map(|_| {
                let v = [r() - 0.5, r() - 0.5, 1.0];
                let l = (v[0] * v[0] + v[1] * v[1] + 1.0f64).sqrt();
                v.map(|c| c / l)
            })
            .collect();
        (pts, nrm)
    }

    #[test]
    fn the_order_is_a_permutation() {
        for (n, seed) in [(0, 1), (1, 2), (2, 3), (5, 4), (13, 5), (100, 6), (2000, 7)] {
            let (pts, nrm) = cloud(n, seed);
            let mut order = two_factor_order(&pts, &nrm, &TwoFactorOptions::default(), &|_| {}).unwrap();
            order.sort_unstable();
            assert_eq!(order, (0..n as u32).collect::<Vec<_>>(), "n = {n}");
        }
        // Coincident points cannot be separated by Lloyd: the chunk fallback still terminates.
        let same = vec![[1.0, 2.0, 3.0]; 300];
        let mut order = two_factor_order(&same, &same, &TwoFactorOptions::default(), &|_| {}).unwrap();
        order.sort_unstable();
        assert_eq!(order, (0..300).collect::<Vec<_>>());
    }

    #[test]
    fn the_order_is_more_local_than_random() {
        // Mean step between consecutive centroids: far below that of the input (random) order.
        let (pts, nrm) = cloud(3000, 9);
        let order = two_factor_order(&pts, &nrm, &TwoFactorOptions::default(), &|_| {}).unwrap();
        let step = |o: &[u32]| o.windows(2).map(|w| dist(pts[w[0] as usize], pts[w[1] as usize])).sum::<f64>();
        let raster: Vec<u32> = (0..3000).collect();
        assert!(step(&order) * 5.0 < step(&raster), "{} vs {}", step(&order), step(&raster));
    }
}
