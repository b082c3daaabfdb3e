//! Minimum-weight perfect matching on general graphs: Edmonds' blossom algorithm in its
//! primal–dual form (J. Edmonds, "Paths, trees, and flowers", Canad. J. Math. 17, 1965, and
//! "Maximum matching and a polyhedron with 0,1-vertices", J. Res. NBS 69B, 1965), with the O(n³)
//! bookkeeping of H. N. Gabow, "Implementation of algorithms for maximum matching on nonbipartite
//! graphs" (PhD thesis, Stanford, 1973) and E. L. Lawler, *Combinatorial Optimization: Networks
//! and Matroids* (1976), ch. 6: per top-level blossom pair the least-slack edge between them, and
//! per blossom the child holding each vertex, so a stage costs O(n²).
//!
//! The solver finds a maximum-weight matching on integer weights. The 2-factor layout wants a
//! minimum-cost *perfect* matching, which is reduced to it: weights `K − cost` with `K` large
//! enough that one more matched edge always outweighs any cost difference, so the maximum-weight
//! matching has maximum cardinality and, among those, the least cost. When that matching leaves a
//! vertex unmatched, no perfect matching exists ([`MatchingError::NoPerfectMatching`]).
//!
//! Dual variables are kept doubled (`slack(u, v) = y_u + y_v − 2 w(u, v)`), so every quantity
//! stays an integer: all vertices of one alternating tree share the parity of its exposed root,
//! which makes the slack of an edge between two S-blossoms even and its half exact.

use std::collections::VecDeque;

const NONE: usize = usize::MAX;
const NO_EDGE: [u32; 2] = [u32::MAX, u32::MAX];

/// Why no minimum-weight perfect matching could be returned.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum MatchingError {
    #[error("no perfect matching: at most {matched} of {vertices} vertices can be matched")]
    NoPerfectMatching { vertices: usize, matched: usize },
    #[error("edge {edge} ({u}, {v}) is not between two distinct vertices below {vertices}")]
    BadEdge { edge: usize, u: usize, v: usize, vertices: usize },
    #[error("edge costs span {span}, too wide for exact integer duals on {vertices} vertices")]
    CostsTooWide { span: i64, vertices: usize },
}

/// The partner of every vertex in a perfect matching of least total cost on the graph with
/// `vertices` vertices and `edges` (`u`, `v`, cost; costs may be negative and tie; of parallel
/// edges the cheapest counts).
pub fn min_weight_perfect_matching(
    vertices: usize,
    edges: &[(usize, usize, i64)],
) -> Result<Vec<usize>, MatchingError> {
    for (k, &(u, v, _)) in edges.iter().enumerate() {
        if u >= vertices || v >= vertices || u == v {
            return Err(MatchingError::BadEdge { edge: k, u, v, vertices });
        }
    }
    if vertices == 0 {
        return Ok(Vec::new());
    }
    let (lo, hi) = edges.iter().fold((i64::MAX, i64::MIN), |(lo, hi), e| (lo.min(e.2), hi.max(e.2)));
    if edges.is_empty() {
        return Err(MatchingError::NoPerfectMatching { vertices, matched: 0 });
    }
    // K > (n/2)·span: a matching with one more edge weighs more than any with fewer. Duals reach
    // about 2K and are doubled again in slacks, so K must stay well inside i64.
    let span = hi.checked_sub(lo).ok_or(MatchingError::CostsTooWide { span: i64::MAX, vertices })?;
    let k = (vertices as i64 / 2)
        .checked_mul(span)
        .and_then(|x| x.checked_add(1))
        .filter(|&k| k < i64::MAX / 16)
        .ok_or(MatchingError::CostsTooWide { span, vertices })?;
    let weighted: Vec<(usize, usize, i64)> = edges.iter().map(|&(u, v, c)| (u, v, k - (c - lo))).collect();
    let mate = max_weight_matching(vertices, &weighted);
    let matched = mate.iter().filter(|&&m| m != NONE).count();
    if matched < vertices {
        return Err(MatchingError::NoPerfectMatching { vertices, matched });
    }
    Ok(mate)
}

/// A maximum-weight matching (not necessarily perfect) for positive integer weights: each
/// vertex's partner, or `usize::MAX` when unmatched. Edges of weight ≤ 0 are ignored (never
/// worth matching); of parallel edges the heaviest counts.
pub fn max_weight_matching(vertices: usize, edges: &[(usize, usize, i64)]) -> Vec<usize> {
    let mut s = Solver::new(vertices, edges);
    while s.stage() {}
    s.mate.truncate(vertices);
    s.mate
}

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Label {
    Free,
    S,
    T,
}

/// Nodes are vertices `0..n` and blossoms `n..2n` (slots reused after an expansion).
struct Solver {
    n: usize,
    /// Slots in use are below this: `n` plus the highest blossom slot taken, plus one.
    nodes: usize,
    /// `n × n`, 0 for no edge.
    weight: Vec<i64>,
    adjacency: Vec<Vec<usize>>,
    /// `2n × 2n`: for two nodes the least-slack edge between them as (vertex in the first,
    /// vertex in the second). Within one pair of top-level blossoms every vertex's dual moves by
    /// the same amount, so the least-slack edge stays the least-slack one until they merge.
    rep: Vec<[u32; 2]>,
    /// Per node: the vertex at the other end of its matched edge (a blossom: its base's).
    mate: Vec<usize>,
    /// Per node: the top-level node holding it.
    top: Vec<usize>,
    /// Per blossom: its children around the odd cycle, the base's child first; children
    /// `2i + 1` and `2i + 2` are matched to each other.
    children: Vec<Vec<usize>>,
    /// `2n × n`: the child of a blossom that holds a vertex (a vertex holds itself).
    child_of: Vec<usize>,
    in_use: Vec<bool>,
    label: Vec<Label>,
    /// Per T-node: the S-vertex whose tight edge labelled it.
    tree_from: Vec<usize>,
    /// Doubled duals of vertices; blossom duals in the same unit.
    dual: Vec<i64>,
    /// Per top-level node: the S-vertex with the least-slack edge into it.
    best_from: Vec<usize>,
    queue: VecDeque<usize>,
    mark: Vec<u32>,
    stamp: u32,
}

impl Solver {
    fn new(n: usize, edges: &[(usize, usize, i64)]) -> Solver {
        let slots = 2 * n.max(1);
        let mut weight = vec![0i64; n * n];
        for &(u, v, w) in edges {
            if w > 0 && u != v && u < n && v < n && w > weight[u * n + v] {
                weight[u * n + v] = w;
                weight[v * n + u] = w;
            }
        }
        let mut adjacency = vec![Vec::new(); n];
        let mut rep = vec![NO_EDGE; slots * slots];
        let mut max_w = 0;
        for u in 0..n {
            for v in 0..n {
                let w = weight[u * n + v];
                if w > 0 {
                    adjacency[u].push(v);
                    rep[u * slots + v] = [u as u32, v as u32];
                    max_w = max_w.max(w);
                }
            }
        }
        let mut child_of = vec![NONE; slots * n];
        for v in 0..n {
            child_of[v * n + v] = v;
        }
        let mut top: Vec<usize> = (0..slots).collect();
        top[n..].fill(NONE);
        let mut dual = vec![0; slots];
        dual[..n].fill(max_w);
        Solver {
            n,
            nodes: n,
            weight,
            adjacency,
            rep,
            mate: vec![NONE; slots],
            top,
            children: vec![Vec::new(); slots],
            child_of,
            in_use: vec![false; slots],
            label: vec![Label::Free; slots],
            tree_from: vec![NONE; slots],
            dual,
            best_from: vec![NONE; slots],
            queue: VecDeque::new(),
            mark: vec![0; slots],
            stamp: 0,
        }
    }

    fn slots(&self) -> usize {
        2 * self.n.max(1)
    }

    fn rep(&self, x: usize, y: usize) -> Option<(usize, usize)> {
        let e = self.rep[x * self.slots() + y];
        (e != NO_EDGE).then_some((e[0] as usize, e[1] as usize))
    }

    fn slack(&self, u: usize, v: usize) -> i64 {
        self.dual[u] + self.dual[v] - 2 * self.weight[u * self.n + v]
    }

    /// Slack of the least-slack edge between nodes `x` and `y` (which must have one).
    fn rep_slack(&self, x: usize, y: usize) -> i64 {
        let (a, b) = self.rep(x, y).expect("an edge between the nodes");
        self.slack(a, b)
    }

    /// Whether node `x` is a live top-level node.
    fn is_top(&self, x: usize) -> bool {
        self.top[x] == x && (x < self.n || self.in_use[x])
    }

    /// Offers S-vertex `u`'s edge into top-level node `x` as its least-slack candidate.
    fn offer(&mut self, u: usize, x: usize) {
        if self.rep(u, x).is_some() {
            let b = self.best_from[x];
            if b == NONE || self.rep_slack(u, x) < self.rep_slack(b, x) {
                self.best_from[x] = u;
            }
        }
    }

    fn recompute_best(&mut self, x: usize) {
        self.best_from[x] = NONE;
        for u in 0..self.n {
            if self.top[u] != x && self.label[self.top[u]] == Label::S {
                self.offer(u, x);
            }
        }
    }

    /// Queues every vertex of node `x` for scanning (it has just become S).
    fn enqueue(&mut self, x: usize) {
        if x < self.n {
            self.queue.push_back(x);
        } else {
            for i in 0..self.children[x].len() {
                self.enqueue(self.children[x][i]);
            }
        }
    }

    fn set_top(&mut self, x: usize, b: usize) {
        self.top[x] = b;
        if x >= self.n {
            for i in 0..self.children[x].len() {
                self.set_top(self.children[x][i], b);
            }
        }
    }

    /// Position of `child` in blossom `b`'s cycle, after reversing the cycle's direction if
    /// needed so that the position is even (the even way round is the alternating path to it).
    fn even_position(&mut self, b: usize, child: usize) -> usize {
        let cycle = &mut self.children[b];
        let pos = cycle.iter().position(|&c| c == child).expect("child of the blossom");
        if pos % 2 == 1 {
            cycle[1..].reverse();
            cycle.len() - pos
        } else {
            pos
        }
    }

    /// Matches node `x` to node `y` along their least-slack (tight) edge, re-matching inside
    /// `x` so that the endpoint's child becomes its base.
    fn rematch(&mut self, x: usize, y: usize) {
        let (a, b) = self.rep(x, y).expect("a tight edge to rematch along");
        self.mate[x] = b;
        if x < self.n {
            return;
        }
        let entry = self.child_of[x * self.n + a];
        let pos = self.even_position(x, entry);
        for i in 0..pos {
            let (c, d) = (self.children[x][i], self.children[x][i ^ 1]);
            self.rematch(c, d);
        }
        self.rematch(entry, y);
        self.children[x].rotate_left(pos);
    }

    /// Flips the alternating path from top-level S-node `x` to its tree's root, after `x` was
    /// matched to `y`.
    fn augment_from(&mut self, mut x: usize, mut y: usize) {
        loop {
            let t = if self.mate[x] == NONE { NONE } else { self.top[self.mate[x]] };
            self.rematch(x, y);
            if t == NONE {
                return;
            }
            let s = self.top[self.tree_from[t]];
            self.rematch(t, s);
            x = s;
            y = t;
        }
    }

    /// The nearest common S-ancestor of S-nodes `x` and `y`, or `NONE` in different trees.
    fn meet(&mut self, mut x: usize, mut y: usize) -> usize {
        self.stamp += 1;
        while x != NONE || y != NONE {
            if x != NONE {
                if self.mark[x] == self.stamp {
                    return x;
                }
                self.mark[x] = self.stamp;
                x = if self.mate[x] == NONE { NONE } else { self.top[self.tree_from[self.top[self.mate[x]]]] };
            }
            std::mem::swap(&mut x, &mut y);
        }
        NONE
    }

    /// Shrinks the odd cycle closed by tight edge (u, v) through the common ancestor `lca`.
    fn make_blossom(&mut self, u: usize, lca: usize, v: usize) {
        let n = self.n;
        let b = (n..self.slots()).find(|&b| !self.in_use[b]).expect("at most n/2 blossoms are nested");
        self.in_use[b] = true;
        self.nodes = self.nodes.max(b + 1);
        self.dual[b] = 0;
        self.mate[b] = self.mate[lca];
        self.label[b] = Label::S;
        let mut cycle = std::mem::take(&mut self.children[b]);
        cycle.clear();
        cycle.push(lca);
        for (side, start) in [(0, self.top[u]), (1, self.top[v])] {
            let from = cycle.len();
            let mut x = start;
            while x != lca {
                cycle.push(x);
                let y = self.top[self.mate[x]];
                cycle.push(y);
                self.enqueue(y);
                x = self.top[self.tree_from[y]];
            }
            if side == 0 {
                // u's side runs from the ancestor down to u, so the cycle continues u → v.
                cycle[from..].reverse();
            }
        }
        self.children[b] = cycle;
        self.set_top(b, b);
        let slots = self.slots();
        for z in 0..self.nodes {
            self.rep[b * slots + z] = NO_EDGE;
            self.rep[z * slots + b] = NO_EDGE;
        }
        self.child_of[b * n..(b + 1) * n].fill(NONE);
        for i in 0..self.children[b].len() {
            let c = self.children[b][i];
            for z in 0..self.nodes {
                if self.rep(c, z).is_some() && (self.rep(b, z).is_none() || self.rep_slack(c, z) < self.rep_slack(b, z))
                {
                    self.rep[b * slots + z] = self.rep[c * slots + z];
                    self.rep[z * slots + b] = self.rep[z * slots + c];
                }
            }
            for w in 0..n {
                if self.child_of[c * n + w] != NONE {
                    self.child_of[b * n + w] = c;
                }
            }
        }
        self.recompute_best(b);
    }

    /// Dissolves top-level T-blossom `b` (its dual has reached 0): the children on the even path
    /// from its entry to its base stay in the tree (T, S, …, T), the others become free.
    fn expand(&mut self, b: usize) {
        for i in 0..self.children[b].len() {
            let c = self.children[b][i];
            self.set_top(c, c);
        }
        let (entry_vertex, _) = self.rep(b, self.tree_from[b]).expect("the edge that labelled the blossom");
        let entry = self.child_of[b * self.n + entry_vertex];
        let pos = self.even_position(b, entry);
        for i in (0..pos).step_by(2) {
            let (t, s) = (self.children[b][i], self.children[b][i + 1]);
            self.tree_from[t] = self.rep(s, t).expect("a cycle edge").0;
            self.label[t] = Label::T;
            self.label[s] = Label::S;
            self.best_from[t] = NONE;
            self.recompute_best(s);
            self.enqueue(s);
        }
        self.label[entry] = Label::T;
        self.tree_from[entry] = self.tree_from[b];
        self.best_from[entry] = NONE;
        for i in pos + 1..self.children[b].len() {
            let c = self.children[b][i];
            self.label[c] = Label::Free;
            self.recompute_best(c);
        }
        self.in_use[b] = false;
        self.top[b] = NONE;
        self.label[b] = Label::Free;
    }

    /// Tight edge (u, v) from S-vertex `u`: grow the tree, shrink a blossom, or augment (true).
    fn tight(&mut self, u: usize, v: usize) -> bool {
        let (x, y) = (self.top[u], self.top[v]);
        match self.label[y] {
            Label::Free => {
                // Exposed nodes are all S roots, so a free node is matched.
                self.tree_from[y] = u;
                self.label[y] = Label::T;
                let z = self.top[self.mate[y]];
                self.best_from[y] = NONE;
                self.best_from[z] = NONE;
                self.label[z] = Label::S;
                self.enqueue(z);
                false
            }
            Label::S => {
                let lca = self.meet(x, y);
                if lca == NONE {
                    self.augment_from(x, y);
                    self.augment_from(y, x);
                    true
                } else {
                    self.make_blossom(u, lca, v);
                    false
                }
            }
            Label::T => false,
        }
    }

    /// One stage: grow alternating trees from every exposed node, adjusting duals, until an
    /// augmenting path is found (true) or no exposed vertex can gain (false: optimal).
    fn stage(&mut self) -> bool {
        self.label[..self.nodes].fill(Label::Free);
        self.best_from[..self.nodes].fill(NONE);
        self.queue.clear();
        for x in 0..self.nodes {
            if self.is_top(x) && self.mate[x] == NONE {
                self.tree_from[x] = NONE;
                self.label[x] = Label::S;
                self.enqueue(x);
            }
        }
        if self.queue.is_empty() {
            return false;
        }
        loop {
            while let Some(u) = self.queue.pop_front() {
                if self.label[self.top[u]] != Label::S {
                    continue;
                }
                for k in 0..self.adjacency[u].len() {
                    let v = self.adjacency[u][k];
                    if self.top[u] == self.top[v] {
                        continue;
                    }
                    if self.slack(u, v) == 0 {
                        if self.tight(u, v) {
                            return true;
                        }
                    } else {
                        self.offer(u, self.top[v]);
                    }
                }
            }
            let mut delta = i64::MAX;
            for b in self.n..self.nodes {
                if self.is_top(b) && self.label[b] == Label::T {
                    delta = delta.min(self.dual[b]);
                }
            }
            for x in 0..self.nodes {
                let u = self.best_from[x];
                if !self.is_top(x) || u == NONE || self.top[u] == x {
                    continue;
                }
                match self.label[x] {
                    Label::Free => delta = delta.min(self.rep_slack(u, x)),
                    Label::S => {
                        let s = self.rep_slack(u, x);
                        debug_assert!(s % 2 == 0, "S–S slack {s} is odd");
                        delta = delta.min(s / 2);
                    }
                    Label::T => {}
                }
            }
            let least_s_dual = (0..self.n).filter(|&u| self.label[self.top[u]] == Label::S).map(|u| self.dual[u]).min();
            if least_s_dual.is_none_or(|d| d <= delta) {
                // An exposed vertex's dual would reach 0 first: no augmentation gains any more.
                return false;
            }
            for u in 0..self.n {
                match self.label[self.top[u]] {
                    Label::S => self.dual[u] -= delta,
                    Label::T => self.dual[u] += delta,
                    Label::Free => {}
                }
            }
            for b in self.n..self.nodes {
                if self.is_top(b) {
                    match self.label[b] {
                        Label::S => self.dual[b] += delta,
                        Label::T => self.dual[b] -= delta,
                        Label::Free => {}
                    }
                }
            }
            for x in 0..self.nodes {
                let u = self.best_from[x];
                if self.is_top(x) && u != NONE && self.top[u] != x && self.label[x] != Label::T {
                    if let Some((a, b)) = self.rep(u, x) {
                        if self.slack(a, b) == 0 && self.tight(a, b) {
                            return true;
                        }
                    }
                }
            }
            for b in self.n..self.nodes {
                if self.is_top(b) && self.label[b] == Label::T && self.dual[b] == 0 {
                    self.expand(b);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Least total cost over all perfect matchings by enumeration (None: there is none).
    pub(crate) fn brute_force(n: usize, edges: &[(usize, usize, i64)]) -> Option<i64> {
        let mut cost = vec![None::<i64>; n * n];
        for &(u, v, c) in edges {
            for (a, b) in [(u, v), (v, u)] {
                let e = &mut cost[a * n + b];
                *e = Some(e.map_or(c, |x| x.min(c)));
            }
        }
        fn go(n: usize, cost: &[Option<i64>], used: &mut Vec<bool>) -> Option<i64> {
            let Some(u) = (0..n).find(|&u| !used[u]) else { return Some(0) };
            used[u] = true;
            let mut best = None;
            for v in u + 1..n {
                if let (false, Some(c)) = (used[v], cost[u * n + v]) {
                    used[v] = true;
                    if let Some(rest) = go(n, cost, used) {
                        best = Some(best.map_or(c + rest, |b: i64| b.min(c + rest)));
                    }
                    used[v] = false;
                }
            }
            used[u] = false;
            best
        }
        go(n, &cost, &mut vec![false; n])
    }

    fn total(mate: &[usize], edges: &[(usize, usize, i64)]) -> i64 {
        let mut sum = 0;
        for (u, &v) in mate.iter().enumerate() {
            assert_eq!(mate[v], u, "matching is symmetric");
            if u < v {
                sum +=
                    edges.iter().filter(|e| (e.0, e.1) == (u, v) || (e.0, e.1) == (v, u)).map(|e| e.2).min().unwrap();
            }
        }
        sum
    }

    fn graph() -> impl Strategy<Value = (usize, Vec<(usize, usize, i64)>)> {
        (1usize..=10, 0.2f64..=1.0, prop::collection::vec((0u32..1000, -3i64..8), 100)).prop_map(
            |(n, density, draws)| {
                let mut edges = Vec::new();
                let mut k = 0;
                for u in 0..n {
                    for v in u + 1..n {
                        let (p, c) = draws[k % draws.len()];
                        k += 1;
                        if (p as f64) < density * 1000.0 {
                            edges.push((u, v, c));
                        }
                    }
                }
                (n, edges)
            },
        )
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(3000))]
        #[test]
        fn optimal_against_brute_force((n, edges) in graph()) {
            let want = brute_force(n, &edges);
            match (min_weight_perfect_matching(n, &edges), want) {
                (Ok(mate), Some(best)) => prop_assert_eq!(total(&mate, &edges), best),
                (Err(MatchingError::NoPerfectMatching { .. }), None) => {}
                (got, want) => prop_assert!(false, "solver {:?}, brute force {:?}", got, want),
            }
        }
    }

    /// Least total cost of a perfect matching by an independent implementation (the
    /// `integer-blossom` crate, a dev-dependency only): its maximum-weight matching on the dense
    /// matrix of `K − (cost − lo)` (0: no edge), K as in our reduction. None: not perfect.
    fn independent(n: usize, edges: &[(usize, usize, i64)]) -> Option<i64> {
        let lo = edges.iter().map(|e| e.2).min()?;
        let hi = edges.iter().map(|e| e.2).max()?;
        let k = (n as i64 / 2) * (hi - lo) + 1;
        let mut w = vec![0i64; n * n];
        for &(u, v, c) in edges {
            let (a, b) = (u.min(v), u.max(v));
            w[a * n + b] = w[a * n + b].max(k - (c - lo));
        }
        let mate = integer_blossom::max_weight_matching(&w, n);
        let mut sum = 0;
        for (u, m) in mate.iter().enumerate() {
            let v = (*m)?;
            if u < v {
                sum += k - w[u * n + v] + lo;
            }
        }
        Some(sum)
    }

    /// Sparse graphs of up to 60 vertices, beyond brute force: a random cycle through all
    /// vertices (so a perfect matching exists when n is even) plus random chords, small costs
    /// (many ties), as the 2-factor's inflated graphs are.
    fn large_graph() -> impl Strategy<Value = (usize, Vec<(usize, usize, i64)>)> {
        (2usize..=30, any::<u64>()).prop_map(|(half, seed)| {
            let n = 2 * half;
            let mut s = seed | 1;
            let mut next = move || {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                s
            };
            let mut order: Vec<usize> = (0..n).collect();
            for i in (1..n).rev() {
                order.swap(i, (next() % (i as u64 + 1)) as usize);
            }
            let mut edges: Vec<(usize, usize, i64)> =
                (0..n).map(|i| (order[i], order[(i + 1) % n], (next() % 9) as i64 - 2)).collect();
            for _ in 0..2 * n {
                let (u, v) = ((next() % n as u64) as usize, (next() % n as u64) as usize);
                if u != v {
                    edges.push((u, v, (next() % 9) as i64 - 2));
                }
            }
            (n, edges)
        })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(500))]
        #[test]
        fn agrees_with_an_independent_blossom_on_larger_graphs((n, edges) in large_graph()) {
            let mate = min_weight_perfect_matching(n, &edges).map_err(|e| TestCaseError::fail(e.to_string()))?;
            prop_assert_eq!(Some(total(&mate, &edges)), independent(n, &edges));
        }
    }

    #[test]
    fn every_complete_graph_on_up_to_ten_vertices_with_tied_weights() {
        // Deterministic sweep: small weights force many ties and blossoms.
        let mut s = 12345u64;
        for n in (2..=10).step_by(2) {
            for _ in 0..200 {
                let mut edges = Vec::new();
                for u in 0..n {
                    for v in u + 1..n {
                        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                        edges.push((u, v, (s >> 61) as i64));
                    }
                }
                let mate = min_weight_perfect_matching(n, &edges).unwrap();
                assert_eq!(Some(total(&mate, &edges)), brute_force(n, &edges));
            }
        }
    }

    #[test]
    fn clear_errors() {
        // Odd count, a path of three, two components of odd size.
        assert!(matches!(
            min_weight_perfect_matching(3, &[(0, 1, 1), (1, 2, 1)]),
            Err(MatchingError::NoPerfectMatching { vertices: 3, matched: 2 })
        ));
        let e = min_weight_perfect_matching(6, &[(0, 1, 1), (1, 2, 1), (0, 2, 1), (3, 4, 1), (4, 5, 1), (3, 5, 1)])
            .unwrap_err();
        assert_eq!(e, MatchingError::NoPerfectMatching { vertices: 6, matched: 4 });
        assert!(e.to_string().contains("no perfect matching"));
        assert!(matches!(min_weight_perfect_matching(2, &[(0, 2, 1)]), Err(MatchingError::BadEdge { .. })));
        assert!(matches!(min_weight_perfect_matching(2, &[(1, 1, 1)]), Err(MatchingError::BadEdge { .. })));
        assert!(matches!(
            min_weight_perfect_matching(4, &[(0, 1, i64::MIN / 2), (2, 3, i64::MAX / 2)]),
            Err(MatchingError::CostsTooWide { .. })
        ));
        assert_eq!(min_weight_perfect_matching(0, &[]), Ok(vec![]));
    }

    #[test]
    fn prefers_two_cheap_edges_over_a_blossom_shortcut() {
        // A 5-cycle with a pendant: the blossom must be shrunk and expanded to find the optimum.
        let edges = [(0, 1, 5), (1, 2, 1), (2, 3, 5), (3, 4, 1), (4, 0, 1), (0, 5, 2), (2, 5, 9)];
        let mate = min_weight_perfect_matching(6, &edges).unwrap();
        assert_eq!(Some(total(&mate, &edges)), brute_force(6, &edges));
    }
}
