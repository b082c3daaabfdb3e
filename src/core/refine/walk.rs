//! The hot loop of refinement: Lindstrom & Pascucci's hoisted `submesh_refine` (*Visualization of
//! Large Terrains Made Easy*, IEEE Visualization 2001, §4, Figure 5) with the strip appended in
//! the same pass (`strip_append`, §4.3).
//!
//! What makes it fast (ARCHITECTURE.md, "Refinement"):
//! - A vertex is two words in registers: its grid position packed as `x | y << 32` (a strip
//!   vertex as it is written) and its record index. A node's two children come by lane integer
//!   arithmetic ([`lanes::children`]; the order from the level's parity, compile-time: odd and
//!   even levels are separate monomorphs, the even one inlined into the odd one, so one call
//!   refines two levels) and their indices by the layout's shortcut; for a Euclidean metric both
//!   are tested at once in f32 lanes ([`lanes::pair`], [`lanes::cull`]).
//! - Each child is tested by its parent, so only active vertices recurse.
//! - Culling is a compile-time mode: once a sphere is inside every frustum plane, its whole
//!   subtree runs the variant without plane tests.
//! - The strip is written through a raw cursor passed along in a register, as SOAR's `vip`
//!   ([`Out`]); the last two vertices are read back from behind it and the parity is the
//!   cursor's own (the strip keeps parity == length mod 2).

use crate::format::terrain::Record;
use crate::layout::hierarchy::{pack, split_children_packed, unpack};
use crate::layout::{Layout, Vertex};
use crate::lod::metric::ErrorMetric;
use crate::lod::Test;
use crate::refine::lanes::{self, record_of};
use crate::refine::records::RecordSource;
use crate::refine::{Morph, RefineCounters, Strip, StripVertex, View};

/// Morphed heights of a triangle's corners (left end of the hypotenuse, apex, right end) and the
/// apex's blend, carried down the recursion.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct MorphTri {
    pub z_left: f32,
    pub z_apex: f32,
    pub z_right: f32,
    pub blend_left: f32,
    pub blend_apex: f32,
}

impl MorphTri {
    #[inline(always)]
    pub fn apex(&self) -> Morph {
        Morph { blend: self.blend_apex, z_m: self.z_apex }
    }
    #[inline(always)]
    pub fn left(&self) -> Morph {
        Morph { blend: self.blend_left, z_m: self.z_left }
    }
}

/// What the recursion carries for geomorphing: [`MorphTri`] when on, nothing when off (so the
/// plain refinement passes no extra arguments).
pub(super) trait Carry: Copy + Default + Send + Sync + 'static {
    const ON: bool;
    /// What the active test of a split vertex adds for the halves: its morphed height and blend
    /// when on, nothing when off.
    type Point: Copy;
    fn new(t: &MorphTri) -> Self;
    fn apex(&self) -> Morph;
    /// The split vertex's morph state, given its height and geomorph blend (computed only when on).
    fn point(&self, z_m: f32, blend: f32) -> Self::Point;
    fn morph(p: Self::Point) -> Morph;
    /// The states of the left and right halves, given the split vertex's point.
    fn halves(&self, p: Self::Point) -> (Self, Self);
}

#[derive(Clone, Copy, Debug, Default)]
pub(super) struct NoMorph;

impl Carry for NoMorph {
    const ON: bool = false;
    type Point = ();
    #[inline(always)]
    fn new(_: &MorphTri) -> Self {
        NoMorph
    }
    #[inline(always)]
    fn apex(&self) -> Morph {
        Morph::default()
    }
    #[inline(always)]
    fn point(&self, _: f32, _: f32) {}
    #[inline(always)]
    fn morph(_: ()) -> Morph {
        Morph::default()
    }
    #[inline(always)]
    fn halves(&self, _: ()) -> (Self, Self) {
        (NoMorph, NoMorph)
    }
}

impl Carry for MorphTri {
    const ON: bool = true;
    type Point = Morph;
    #[inline(always)]
    fn new(t: &MorphTri) -> Self {
        *t
    }
    #[inline(always)]
    fn apex(&self) -> Morph {
        MorphTri::apex(self)
    }
    /// The split vertex morphs from the mean of the hypotenuse's (morphed) ends to its height.
    #[inline(always)]
    fn point(&self, z_m: f32, blend: f32) -> Morph {
        let mid = 0.5 * (self.z_left + self.z_right);
        Morph { blend, z_m: mid + blend * (z_m - mid) }
    }
    #[inline(always)]
    fn morph(p: Morph) -> Morph {
        p
    }
    #[inline(always)]
    fn halves(&self, p: Morph) -> (Self, Self) {
        let (m, z, blend) = (self, p.z_m, p.blend);
        (
            MorphTri { z_left: m.z_left, z_apex: z, z_right: m.z_apex, blend_left: m.blend_left, blend_apex: blend },
            MorphTri { z_left: m.z_apex, z_apex: z, z_right: m.z_right, blend_left: m.blend_apex, blend_apex: blend },
        )
    }
}

#[inline(always)]
fn unkey(k: u64) -> StripVertex {
    let (x, y) = unpack(k);
    StripVertex { x, y }
}

/// Where the walk writes its strip vertices: a raw cursor `at` into `vertices`' capacity, passed
/// along the recursion in a register and returned (SOAR's `vip`).
///
/// Invariant while the walk runs: `base + 2 ≤ at ≤ end`, `[base, at)` initialised, `end` the end
/// of `vertices`' allocation, and nothing else touches `vertices` (it is borrowed mutably for the
/// walk's lifetime). The cursor is used linearly (every call returns the one its caller goes on
/// with; no caller keeps an older one), so when the room runs out the vector grows and the cursor
/// is moved to the new allocation ([`Out::grow`]).
pub(super) struct Out<'a> {
    vertices: &'a mut Vec<StripVertex>,
    morph: &'a mut Vec<Morph>,
    base: *mut StripVertex,
    end: *mut StripVertex,
    /// Bit 3 of `base`'s address: the length's parity is bit 3 of the cursor XOR this.
    flip: usize,
}

/// A cursor into [`Out`].
pub(super) type At = *mut StripVertex;

impl<'a> Out<'a> {
    /// Writes after `strip`'s vertices (at least two, its seed, with parity == length mod 2),
    /// with room for `reserve` more.
    fn new(strip: &'a mut Strip, reserve: usize) -> (Out<'a>, At) {
        // The cursor reads the two vertices behind it: a seed must be there (checked always, as
        // the reads would otherwise leave the allocation).
        assert!(strip.vertices.len() >= 2, "a walk needs a seeded strip");
        debug_assert_eq!(strip.parity as usize, strip.vertices.len() % 2);
        let vertices = &mut strip.vertices;
        vertices.reserve(reserve.max(64));
        let len = vertices.len();
        let base = vertices.as_mut_ptr();
        // SAFETY: `len` and `capacity` are within (or one past the end of) the allocation.
        let (at, end) = unsafe { (base.add(len), base.add(vertices.capacity())) };
        let flip = base as usize & 8;
        (Out { vertices, morph: &mut strip.morph, base, end, flip }, at)
    }

    /// Doubles the room: the vertices written so far move with the vector; returns the cursor at
    /// the same length in the new allocation.
    #[cold]
    #[inline(never)]
    fn grow(&mut self, at: At) -> At {
        // SAFETY: `[base, at)` is initialised and `at` lies in the allocation (the invariant), so
        // the length is right; `reserve` keeps those elements and gives a fresh allocation, from
        // which the new pointers are taken.
        unsafe {
            let len = at.offset_from(self.base) as usize;
            self.vertices.set_len(len);
            self.vertices.reserve(len.max(64));
            self.base = self.vertices.as_mut_ptr();
            self.end = self.base.add(self.vertices.capacity());
            self.flip = self.base as usize & 8;
            self.base.add(len)
        }
    }

    /// Ends the walk at `at`: the strip's length becomes what was written.
    fn finish(self, at: At) -> usize {
        // SAFETY: `at` came from this walk's cursor, so `base ≤ at ≤ end` and every vertex in
        // `[base, at)` was written (the invariant); the length is within the capacity.
        unsafe {
            let len = at.offset_from(self.base) as usize;
            self.vertices.set_len(len);
            len
        }
    }

    #[inline(always)]
    fn put(&mut self, at: At, v: StripVertex) -> At {
        let at = if at == self.end { self.grow(at) } else { at };
        // SAFETY: `base + 2 ≤ at < end`: inside the allocation, past the initialised part.
        unsafe {
            at.write(v);
            at.add(1)
        }
    }

    /// The paper's `strip_append` (see [`Strip::append`]): skips a vertex equal to one of the last
    /// two, and repeats the second-to-last vertex first when `v` would land with the wrong
    /// winding (when the length's parity equals `P`, the vertex's parity).
    #[inline(always)]
    fn append<S: Carry, const P: u8>(&mut self, at: At, v: u64, m: Morph) -> At {
        // SAFETY: `at ≥ base + 2` and `[base, at)` is initialised (the invariant).
        let (prev, last) = unsafe { (at.sub(2).read(), at.sub(1).read()) };
        let (prev, last) = (pack(prev.x, prev.y), pack(last.x, last.y));
        if v == last || v == prev {
            return at;
        }
        let mut at = at;
        if (at as usize ^ self.flip) & 8 == (P as usize) << 3 {
            if S::ON {
                if let &[.., pm, _] = self.morph.as_slice() {
                    self.morph.push(pm);
                }
            }
            at = self.put(at, unkey(prev));
        }
        if S::ON {
            self.morph.push(m);
        }
        self.put(at, unkey(v))
    }

    /// [`Self::append`] with the parity known only at run time.
    #[inline(always)]
    fn append_any<S: Carry>(&mut self, at: At, v: u64, parity: u8, m: Morph) -> At {
        if parity & 1 == 1 {
            self.append::<S, 1>(at, v, m)
        } else {
            self.append::<S, 0>(at, v, m)
        }
    }
}

/// Whether a walk counts its tests ([`Counted`]: `relief refine`'s report) or not
/// ([`Uncounted`]: every other refinement), at compile time, so that the loop without counts
/// carries no increments.
pub(super) trait Tally: Copy + Default + Send + Sync + 'static {
    const ON: bool;
}

#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Counted;

#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Uncounted;

impl Tally for Counted {
    const ON: bool = true;
}

impl Tally for Uncounted {
    const ON: bool = false;
}

impl RefineCounters {
    #[inline(always)]
    fn visit<C: Tally>(&mut self, n: u64) {
        if C::ON {
            self.visited += n;
        }
    }

    #[inline(always)]
    fn cull<C: Tally>(&mut self) {
        if C::ON {
            self.culled += 1;
        }
    }
}

/// One (sub)strip's refinement: the layout, the records and the view, the output, the counts
/// (when `C` counts).
pub(super) struct Walk<'a, L, R: ?Sized, M: ErrorMetric, S: Carry, C: Tally> {
    layout: &'a L,
    records: &'a R,
    view: &'a View<M>,
    out: Out<'a>,
    counters: RefineCounters,
    carry: std::marker::PhantomData<(S, C)>,
}

impl<'a, L: Layout, R: RecordSource + ?Sized, M: ErrorMetric, S: Carry, C: Tally> Walk<'a, L, R, M, S, C> {
    /// A walk appending to `strip` (seeded), with room reserved for `reserve` more vertices (it
    /// grows when that is not enough).
    pub fn new(layout: &'a L, records: &'a R, view: &'a View<M>, strip: &'a mut Strip, reserve: usize) -> (Self, At) {
        let (out, at) = Out::new(strip, reserve);
        (Walk { layout, records, view, out, counters: RefineCounters::default(), carry: Default::default() }, at)
    }

    /// Ends the walk at `at`, the strip's length set to what was written; the counts.
    pub fn finish(self, at: At) -> RefineCounters {
        let len = self.out.finish(at);
        debug_assert!(len >= 2);
        self.counters
    }

    /// Appends a vertex (outside the recursion: corners, the parallel split's own vertices).
    #[inline(always)]
    pub fn append(&mut self, at: At, v: StripVertex, parity: u8, m: Morph) -> At {
        self.out.append_any::<S>(at, pack(v.x, v.y), parity, m)
    }

    #[inline(always)]
    fn test<const MASKED: bool>(&mut self, c: u64, index: u64, lc: u32, mask: u8, m: &S) -> Option<(u8, S::Point)> {
        probe::<MASKED, R, M, S, C>(self.records, self.view, c, index, lc, mask, m, &mut self.counters)
    }

    /// The hoisted `submesh_refine` for a triangle of level `l` with active apex `i` and untested
    /// hypotenuse midpoint `j` (the root triangles and the parallel tasks, whose apex may be the
    /// grid centre, so the children here come from the layout's general rule): tests `j`; refines
    /// both halves if it is active, appending `i` between them, else appends `i` alone.
    pub fn sub(&mut self, at: At, i: Vertex, j: Vertex, l: u32, mask: u8, m: S) -> At {
        if mask != 0 {
            self.sub_mode::<true>(at, i, j, l, mask, m)
        } else {
            self.sub_mode::<false>(at, i, j, l, 0, m)
        }
    }

    fn sub_mode<const MASKED: bool>(&mut self, at: At, i: Vertex, j: Vertex, l: u32, mask: u8, m: S) -> At {
        let (ik, jk) = (pack(i.x, i.y), pack(j.x, j.y));
        if l >= 2 {
            self.counters.visit::<C>(1);
            if let Some((mask, p)) = self.test::<MASKED>(jk, j.index, l - 1, mask, &m) {
                if l == 2 {
                    return self.finest(at, ik, jk, p, &m);
                }
                let [cl, cr] = self.layout.split_children(i, j);
                let (left, right) = m.halves(p);
                self.counters.visit::<C>(2);
                let mut at = self.side_any::<MASKED>(at, jk, j.index, cl, l - 1, mask, left);
                at = self.out.append_any::<S>(at, ik, (l & 1) as u8, m.apex());
                return self.side_any::<MASKED>(at, jk, j.index, cr, l - 1, mask, right);
            }
        }
        self.out.append_any::<S>(at, ik, (l & 1) as u8, m.apex())
    }

    /// [`Self::side`] for a level known only at run time.
    #[inline(always)]
    #[allow(clippy::too_many_arguments, reason = "internal; each argument is a distinct input")]
    fn side_any<const MASKED: bool>(&mut self, at: At, a: u64, ai: u64, c: Vertex, l: u32, mask: u8, m: S) -> At {
        let ck = pack(c.x, c.y);
        if l & 1 == 1 {
            self.side::<true, MASKED>(at, a, ai, ck, c.index, l, mask, m)
        } else {
            self.side::<false, MASKED>(at, a, ai, ck, c.index, l, mask, m)
        }
    }

    /// The triangle of level `l` ≥ 2 (odd when `ODD`) with apex `a` (a split vertex itself, so
    /// below the root triangles) and split vertex `c`: tests `c` and refines the triangle if it
    /// is active, else appends `a`.
    #[inline(always)]
    #[allow(clippy::too_many_arguments, reason = "internal; each argument is a distinct input")]
    fn side<const ODD: bool, const MASKED: bool>(
        &mut self,
        at: At,
        a: u64,
        ai: u64,
        c: u64,
        ci: u64,
        l: u32,
        mask: u8,
        m: S,
    ) -> At {
        let t = self.test::<MASKED>(c, ci, l - 1, mask, &m);
        self.enter::<ODD, MASKED>(at, a, ai, c, ci, l, t, m)
    }

    /// Refines the triangle of level `l` (odd when `ODD`), apex `a`, split vertex `c`, given the
    /// test of `c`: into it when active, else appends `a`.
    #[inline(always)]
    #[allow(clippy::too_many_arguments, reason = "internal; each argument is a distinct input")]
    fn enter<const ODD: bool, const MASKED: bool>(
        &mut self,
        at: At,
        a: u64,
        ai: u64,
        c: u64,
        ci: u64,
        l: u32,
        t: Option<(u8, S::Point)>,
        m: S,
    ) -> At {
        match t {
            Some((mask_c, p)) => {
                let lm = l | (mask_c as u32) << 8;
                match (ODD, MASKED && mask_c != 0) {
                    (true, true) => self.node_odd::<true>(at, a, ai, c, ci, lm, p, m),
                    (true, false) => self.node_odd::<false>(at, a, ai, c, ci, lm, p, m),
                    (false, true) => self.node_even::<true>(at, a, ai, c, ci, lm, p, m),
                    (false, false) => self.node_even::<false>(at, a, ai, c, ci, lm, p, m),
                }
            }
            None if ODD => self.out.append::<S, 1>(at, a, m.apex()),
            None => self.out.append::<S, 0>(at, a, m.apex()),
        }
    }

    /// A triangle of odd level (the level in `lm`'s low byte, the plane mask its children start
    /// from in the next) whose split vertex `s` tested active, apex `a` a split vertex.
    /// Recursive; the even level below is inlined into it, so one call refines two levels.
    #[inline(never)]
    #[allow(clippy::too_many_arguments, reason = "internal; each argument is a distinct input")]
    fn node_odd<const MASKED: bool>(
        &mut self,
        at: At,
        a: u64,
        ai: u64,
        s: u64,
        si: u64,
        lm: u32,
        p: S::Point,
        m: S,
    ) -> At {
        self.node::<true, MASKED>(at, a, ai, s, si, lm, p, m)
    }

    /// [`Self::node_odd`] for even levels (≥ 2): a level-2 triangle's split vertex has no children.
    #[inline(always)]
    #[allow(clippy::too_many_arguments, reason = "internal; each argument is a distinct input")]
    fn node_even<const MASKED: bool>(
        &mut self,
        at: At,
        a: u64,
        ai: u64,
        s: u64,
        si: u64,
        lm: u32,
        p: S::Point,
        m: S,
    ) -> At {
        if lm & 0xff == 2 {
            return self.finest(at, a, s, p, &m);
        }
        self.node::<false, MASKED>(at, a, ai, s, si, lm, p, m)
    }

    /// The children of `s` by the level's parity and the layout's index shortcut, each tested
    /// before it is entered; `a` appended between them. For a Euclidean metric both children are
    /// tested at once in f32 lanes ([`lanes`]), culling included, before either is entered (so
    /// their records are read one after the other); for any other metric one after the other.
    #[inline(always)]
    #[allow(clippy::too_many_arguments, reason = "internal; each argument is a distinct input")]
    fn node<const ODD: bool, const MASKED: bool>(
        &mut self,
        at: At,
        a: u64,
        ai: u64,
        s: u64,
        si: u64,
        lm: u32,
        p: S::Point,
        m: S,
    ) -> At {
        let (l, mask) = (lm & 0xff, (lm >> 8) as u8);
        // The split vertex has level l − 1: odd when the triangle's level is even.
        let kids = if ODD { lanes::children::<false>(a, s) } else { lanes::children::<true>(a, s) };
        let (cl, cr) = (kids.left, kids.right);
        let [il, ir] = self.layout.inner_child_indices(ai, si, unpack(cl), unpack(cr));
        if L::PREFETCH_GRANDCHILDREN && l >= 4 {
            // The grandchildren are read right after the children: start their loads now, so
            // that their latency overlaps the children's.
            match self.layout.quadtree_children(si) {
                Some(first) => {
                    self.records.prefetch(first);
                    self.records.prefetch(first + 3);
                }
                None => {
                    for c in [cl, cr] {
                        let g = if ODD {
                            split_children_packed::<true>(s, c)
                        } else {
                            split_children_packed::<false>(s, c)
                        };
                        for g in g {
                            let (x, y) = unpack(g);
                            self.records.prefetch(self.layout.index(x, y));
                        }
                    }
                }
            }
        }
        let (left, right) = m.halves(p);
        self.counters.visit::<C>(2);
        // The children's triangles have level l − 1, of the other parity.
        if !M::EUCLIDEAN {
            return if ODD {
                let at = self.side::<false, MASKED>(at, s, si, cl, il, l - 1, mask, left);
                let at = self.out.append::<S, 1>(at, a, m.apex());
                self.side::<false, MASKED>(at, s, si, cr, ir, l - 1, mask, right)
            } else {
                let at = self.side::<true, MASKED>(at, s, si, cl, il, l - 1, mask, left);
                let at = self.out.append::<S, 0>(at, a, m.apex());
                self.side::<true, MASKED>(at, s, si, cr, ir, l - 1, mask, right)
            };
        }
        let (rl, rr) = (self.records.record4(il), self.records.record4(ir));
        let pair = lanes::pair(&self.view.fast, &kids, rl, rr, l - 2);
        let (mut on_l, mut on_r) = (pair.bits & 1 != 0, pair.bits & 2 != 0);
        let (mut mask_l, mut mask_r) = (0, 0);
        if MASKED && pair.bits != 0 {
            let [(out_l, keep_l), (out_r, keep_r)] = lanes::cull(&self.view.fast, &pair, l - 2, mask);
            if on_l && out_l {
                on_l = false;
                self.counters.cull::<C>();
            }
            if on_r && out_r {
                on_r = false;
                self.counters.cull::<C>();
            }
            (mask_l, mask_r) = (keep_l, keep_r);
        }
        let tl = on_l.then(|| (mask_l, self.point(&left, cl, record_of(rl), l - 2)));
        let tr = on_r.then(|| (mask_r, self.point(&right, cr, record_of(rr), l - 2)));
        if ODD {
            let at = self.enter::<false, MASKED>(at, s, si, cl, il, l - 1, tl, left);
            let at = self.out.append::<S, 1>(at, a, m.apex());
            self.enter::<false, MASKED>(at, s, si, cr, ir, l - 1, tr, right)
        } else {
            let at = self.enter::<true, MASKED>(at, s, si, cl, il, l - 1, tl, left);
            let at = self.out.append::<S, 0>(at, a, m.apex());
            self.enter::<true, MASKED>(at, s, si, cr, ir, l - 1, tr, right)
        }
    }

    /// The morph point of an active vertex `c` (record `rec`, level `lc`) under carry `m`.
    #[inline(always)]
    fn point(&self, m: &S, c: u64, rec: Record, lc: u32) -> S::Point {
        if S::ON {
            let (x, y) = unpack(c);
            m.point(rec.z, self.view.blend(x, y, lc, rec))
        } else {
            m.point(0.0, 1.0)
        }
    }

    /// A level-2 triangle whose split vertex `j` (level 1, no children) is active.
    #[inline(always)]
    fn finest(&mut self, at: At, i: u64, j: u64, p: S::Point, m: &S) -> At {
        let mj = S::morph(p);
        let at = self.out.append::<S, 1>(at, j, mj);
        let at = self.out.append::<S, 0>(at, i, m.apex());
        self.out.append::<S, 1>(at, j, mj)
    }
}

/// The active test of vertex `c` (packed, record `index`) at level `lc`, culling against `mask`
/// when `MASKED`: the plane mask its children start from and its morph point, if it is active.
#[inline(always)]
#[allow(clippy::too_many_arguments, reason = "internal; each argument is a distinct input")]
pub(super) fn probe<const MASKED: bool, R: RecordSource + ?Sized, M: ErrorMetric, S: Carry, C: Tally>(
    records: &R,
    view: &View<M>,
    c: u64,
    index: u64,
    lc: u32,
    mask: u8,
    m: &S,
    counters: &mut RefineCounters,
) -> Option<(u8, S::Point)> {
    let rec: Record = records.record(index);
    let (x, y) = unpack(c);
    match view.test::<MASKED>(x, y, lc, rec, mask) {
        Test::Inactive => None,
        Test::Culled => {
            counters.cull::<C>();
            None
        }
        Test::Active { mask } => {
            let point = if S::ON { m.point(rec.z, view.blend(x, y, lc, rec)) } else { m.point(0.0, 1.0) };
            Some((if MASKED { mask } else { 0 }, point))
        }
    }
}

/// [`probe`] of a [`Vertex`], culling when `mask` has planes left (counted as visited).
pub(super) fn probe_vertex<R: RecordSource + ?Sized, M: ErrorMetric, S: Carry, C: Tally>(
    records: &R,
    view: &View<M>,
    v: Vertex,
    lv: u32,
    mask: u8,
    m: &S,
    counters: &mut RefineCounters,
) -> Option<(u8, S::Point)> {
    counters.visit::<C>(1);
    let k = pack(v.x, v.y);
    if mask != 0 {
        probe::<true, R, M, S, C>(records, view, k, v.index, lv, mask, m, counters)
    } else {
        probe::<false, R, M, S, C>(records, view, k, v.index, lv, 0, m, counters)
    }
}
