//! View-dependent refinement into one triangle strip: Lindstrom & Pascucci, *Visualization of Large
//! Terrains Made Easy* (IEEE Visualization 2001), §3–4, with geomorphing from the journal
//! follow-up (*Terrain Simplification Simplified*, IEEE TVCG 2002), and refinement on several
//! threads (ours).
//!
//! One recursive, top-down pass over the mapped records decides which vertices are active (nested
//! error and bounding sphere against the view, [`crate::refine::metric`]), culls bounding spheres against the
//! view frustum with an inherited plane mask, and appends the mesh to a single triangle strip in the
//! same pass. Because errors and radii are nested, a vertex is only ever active when its DAG parents
//! are, so the mesh is conforming by construction and no dependency lists are kept.
//!
//! The strip is generic over the record [`Layout`] and the record source, so the child computation
//! and record reads are monomorphised into the loop. Per-frame work is proportional to the output;
//! buffers are reused between frames (no allocation per vertex once warm).
//!
//! Strip convention: triangle k is `(v_k, v_k+1, v_k+2)` for even k and `(v_k+1, v_k, v_k+2)` for
//! odd k; every non-degenerate triangle is then clockwise seen from above (+z), i.e. its front face
//! is the underside in a right-handed, z-up world. Renderers set their front face accordingly.

pub mod check;
pub(crate) mod lanes;
pub mod minimal;
pub mod progressive;
pub mod records;
pub mod report;
mod walk;

// The error metrics live in `lod`, which every backend's test shares.
pub use crate::lod::metric;
pub use records::{MappedRecords, PagerRecords, RecordSlice, RecordSource};
use walk::{probe_vertex, Carry, Counted, MorphTri, NoMorph, Tally, Uncounted, Walk};

use glam::DVec3;
use serde::Serialize;

use crate::camera::Camera;
use crate::format::terrain::{Record, TerrainFile};
use crate::layout::hierarchy::Grid;
use crate::layout::{Layout, LayoutVisitor, Vertex};
use crate::lod::metric::{ErrorMetric, Isotropic, MetricKind, Projected};
use crate::lod::Lod;

/// A strip vertex: grid coordinates (`x` east, `y` north, in posts). The renderer turns them into
/// positions from its own copy of the heights.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, PartialOrd, Ord, bytemuck::Pod, bytemuck::Zeroable)]
pub struct StripVertex {
    pub x: u32,
    pub y: u32,
}

/// Geomorph state of a strip vertex: `blend` ∈ [0, 1] (0 at the edge midpoint's height, 1 at the
/// true height) and the height to draw, metres, which already includes the blends of the vertices
/// it is interpolated from.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Morph {
    pub blend: f32,
    pub z_m: f32,
}

/// One triangle strip for the whole terrain, with a geomorph entry per vertex when geomorphing is on.
#[derive(Clone, Debug, Default)]
pub struct Strip {
    pub vertices: Vec<StripVertex>,
    /// Same length as `vertices` when geomorphing is on, else empty.
    pub morph: Vec<Morph>,
    parity: u8,
}

impl Strip {
    pub fn new() -> Strip {
        Strip::default()
    }

    /// A strip of given vertices, without geomorph data (for checks and tests).
    pub fn from_vertices(vertices: Vec<StripVertex>) -> Strip {
        let parity = (vertices.len() % 2) as u8;
        Strip { vertices, morph: Vec::new(), parity }
    }

    /// Starts a strip at `v` (as the paper: `V = (v, v)`, parity 0).
    fn seed(&mut self, v: StripVertex, m: Morph, morph: bool) {
        self.vertices.clear();
        self.morph.clear();
        self.vertices.extend([v, v]);
        if morph {
            self.morph.extend([m, m]);
        }
        self.parity = 0;
    }

    /// The paper's `strip_append`: skips a vertex equal to one of the last two, and inserts one
    /// degenerate triangle (repeating the second-to-last vertex) when the vertex would land with the
    /// wrong winding. Invariant: `parity == len % 2`, so a vertex appended with parity p always lands
    /// at an index of parity `1 − p`.
    #[inline(always)]
    fn append(&mut self, v: StripVertex, parity: u8, m: Morph, morph: bool) {
        // A strip is seeded with two vertices, so the pattern always matches.
        let &[.., prev, last] = self.vertices.as_slice() else { return };
        if v == last || v == prev {
            return;
        }
        if parity != self.parity {
            self.parity = parity;
        } else {
            self.vertices.push(prev);
            if morph {
                if let &[.., pm, _] = self.morph.as_slice() {
                    self.morph.push(pm);
                }
            }
        }
        self.vertices.push(v);
        if morph {
            self.morph.push(m);
        }
    }

    /// Appends without any check (ends the strip; stitches chunks).
    #[inline(always)]
    fn push(&mut self, v: StripVertex, m: Morph, morph: bool) {
        self.vertices.push(v);
        if morph {
            self.morph.push(m);
        }
    }

    /// Number of strip vertices.
    pub fn len(&self) -> usize {
        self.vertices.len()
    }

    pub fn is_empty(&self) -> bool {
        self.vertices.is_empty()
    }

    /// Non-degenerate triangles, oriented as drawn (clockwise from above), in strip order.
    pub fn triangles(&self) -> impl Iterator<Item = [StripVertex; 3]> + '_ {
        self.vertices.windows(3).enumerate().filter_map(|(k, w)| {
            if w[0] == w[1] || w[1] == w[2] || w[0] == w[2] {
                None
            } else if k % 2 == 0 {
                Some([w[0], w[1], w[2]])
            } else {
                Some([w[1], w[0], w[2]])
            }
        })
    }

    /// `(non-degenerate, degenerate)` triangle counts.
    pub fn triangle_counts(&self) -> (u64, u64) {
        let total = self.vertices.len().saturating_sub(2) as u64;
        let good = self.vertices.windows(3).filter(|w| w[0] != w[1] && w[1] != w[2] && w[0] != w[2]).count() as u64;
        (good, total - good)
    }
}

/// What to refine for: tolerance, metric, culling, geomorphing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefineOptions {
    /// Screen-space error tolerance τ, pixels.
    pub tolerance_px: f64,
    pub metric: MetricKind,
    /// Cull bounding spheres against the view frustum.
    pub cull: bool,
    /// Geomorphing: vertices blend in between the distances that project their error to τ and to
    /// `morph_ratio · τ` (> 1). `None`: off (no morph data is produced).
    pub morph_ratio: Option<f64>,
    /// Without geomorphing, still give every strip vertex its exact height (morph data with blend
    /// 1), for a renderer that does not hold every height (the GPU height cache).
    pub heights: bool,
    /// The scene's vertical exaggeration (≥ 1): the camera is in the exaggerated scene, where
    /// every height is this many times as high, and the mesh is refined to stay within τ there.
    pub z_exaggeration: f64,
}

impl Default for RefineOptions {
    fn default() -> Self {
        RefineOptions {
            tolerance_px: 1.0,
            metric: MetricKind::Isotropic,
            cull: true,
            morph_ratio: None,
            heights: false,
            z_exaggeration: 1.0,
        }
    }
}

/// Per-pass counts.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct RefineCounters {
    /// Active tests evaluated (one per visited vertex and triangle side).
    pub visited: u64,
    /// Vertices whose error asked for refinement but whose sphere lay outside the frustum.
    pub culled: u64,
}

impl std::ops::AddAssign for RefineCounters {
    fn add_assign(&mut self, o: RefineCounters) {
        self.visited += o.visited;
        self.culled += o.culled;
    }
}

/// Everything the active test needs for one frame, in world metres: the shared [`Lod`] test, the
/// grid's spacing, the rounding slack and the geomorph radius.
///
/// A Euclidean metric is evaluated in f32 ([`Fast`]), four lanes at a time in the walk; any other
/// metric in f64 through [`Lod::test`].
#[derive(Clone, Debug)]
pub struct View<M: ErrorMetric> {
    pub lod: Lod<M>,
    spacing_m: [f64; 2],
    kappa_inner: f64,
    /// Slack added to a vertex's radius (metres), per level, for the f64 test: `margin · level`,
    /// with the margin from [`crate::lod::margin_for_scale`], so that rounding in the f64 test
    /// can never make a child active while its parent is not. A table, as a grid has at most 63
    /// levels.
    slack_m: [f64; 64],
    pub(super) fast: Fast,
    cull: bool,
    morph: bool,
}

/// The constants of the f32 test (ARCHITECTURE.md, "Refinement: the f32 test"), laid out for
/// SSE lanes: coordinates come as `(x_left, x_right, y_left, y_right)`.
///
/// Positions are taken relative to an integer grid origin near the eye, so that `x − origin` is
/// exact and the eye-relative position carries a rounding error relative to its own size, not to
/// the terrain's. The reach is `(κ δ + r) · grow[l] + mu[l]` and the culling radius
/// `(r + eps[l] · reach) + mu[l]`, with `grow = 1 + l·2⁻¹⁷`, `eps = l·2⁻¹⁷` and `mu = l·μ`
/// (μ = 2⁻¹⁹ of the larger of the spacing and the height scale, for the absolute rounding of the
/// eye's offset). From child to parent these grow by 2⁻¹⁷ of the reach, far more than f32
/// rounding moves either side, so a child is never active, nor unculled, while its parent is not.
#[derive(Clone, Debug)]
#[repr(C, align(16))]
pub(super) struct Fast {
    pub origin: [i32; 4],
    pub spacing: [f32; 4],
    pub frac: [f32; 4],
    pub eye_z: [f32; 4],
    pub kappa: [f32; 4],
    /// The frustum planes' inward normals: per plane, per component (x, y, z), in every lane;
    /// zero past the last plane (eight, so that a mask bit indexes it without a check).
    pub planes: [[[f32; 4]; 3]; 8],
    pub grow: [[f32; 4]; 64],
    pub eps: [[f32; 4]; 64],
    pub mu: [[f32; 4]; 64],
}

/// The largest of the finite `values` (0 if none is): a scene's scale for a rounding margin.
fn largest_finite(values: impl IntoIterator<Item = f64>) -> f64 {
    values.into_iter().filter(|v| v.is_finite()).fold(0.0, f64::max)
}

/// The relative slack per level of the f32 test.
const FAST_EPS: f32 = 1.0 / 131072.0;

impl Fast {
    fn new<M: ErrorMetric>(lod: &Lod<M>, spacing_m: [f64; 2], max_coord: u32, z_range_m: [f64; 2]) -> Fast {
        // The origin stays one post inside the grid's range so that every `x − origin` fits an
        // i32 even on the largest grid (coordinates up to 2³¹).
        let hi = (max_coord as f64 - 1.0).max(1.0);
        let org = |e: f64, s: f64| -> i32 {
            let o = (e / s).round();
            if o.is_finite() {
                o.clamp(1.0, hi) as i64 as i32
            } else {
                1
            }
        };
        let (ox, oy) = (org(lod.eye.x, spacing_m[0]), org(lod.eye.y, spacing_m[1]));
        let fx = (lod.eye.x - (ox as u32) as f64 * spacing_m[0]) as f32;
        let fy = (lod.eye.y - (oy as u32) as f64 * spacing_m[1]) as f32;
        let (sx, sy) = (spacing_m[0] as f32, spacing_m[1] as f32);
        let scale =
            largest_finite([spacing_m[0], spacing_m[1], z_range_m[0].abs(), z_range_m[1].abs(), lod.eye.z.abs(), 1.0]);
        let mu = (scale / 524_288.0) as f32;
        Fast {
            origin: [ox, ox, oy, oy],
            spacing: [sx, sx, sy, sy],
            frac: [fx, fx, fy, fy],
            eye_z: [lod.eye.z as f32; 4],
            kappa: [lod.kappa as f32; 4],
            planes: std::array::from_fn(|k| {
                std::array::from_fn(|c| [lod.normals.get(k).map_or(0.0, |n| n.to_array()[c] as f32); 4])
            }),
            grow: std::array::from_fn(|l| [1.0 + l as f32 * FAST_EPS; 4]),
            eps: std::array::from_fn(|l| [l as f32 * FAST_EPS; 4]),
            mu: std::array::from_fn(|l| [l as f32 * mu; 4]),
        }
    }

    /// Position of post `(x, y)` with height `z` relative to the eye, f32.
    #[inline(always)]
    pub fn rel(&self, x: u32, y: u32, z: f32) -> [f32; 3] {
        let qx = x.wrapping_sub(self.origin[0] as u32) as i32 as f32;
        let qy = y.wrapping_sub(self.origin[2] as u32) as i32 as f32;
        [qx * self.spacing[0] - self.frac[0], qy * self.spacing[2] - self.frac[2], z - self.eye_z[0]]
    }

    /// The f32 test of one vertex: the reference the walk's lanes reproduce operation for
    /// operation.
    #[inline(always)]
    pub fn test<const CULL: bool>(&self, x: u32, y: u32, level: u32, rec: Record, mask: u8) -> Test {
        let [rx, ry, rz] = self.rel(x, y, rec.z);
        let l = level as usize & 63;
        let d2 = (rx * rx + ry * ry) + rz * rz;
        let own = self.kappa[0] * rec.error + rec.radius;
        let reach = own * self.grow[l][0] + self.mu[l][0];
        // Written so that a NaN anywhere (a corrupt or missing record) reads as inactive. A record
        // of error and radius 0 (a null vertex, see `layout::stored`, or a flat finest-level post)
        // is never active: the slack `mu` must not make it so.
        let active = reach * reach > d2 && own > 0.0;
        if !active {
            return Test::Inactive;
        }
        let mut mask = mask;
        if CULL && mask != 0 {
            let rc = (rec.radius + self.eps[l][0] * reach) + self.mu[l][0];
            for k in 0..crate::camera::PLANES {
                let bit = 1u8 << k;
                if mask & bit != 0 {
                    let [nx, ny, nz] = self.planes[k];
                    let s = (nx[0] * rx + ny[0] * ry) + nz[0] * rz;
                    if s < -rc {
                        return Test::Culled;
                    }
                    if s > rc {
                        mask &= !bit;
                    }
                }
            }
        }
        Test::Active { mask }
    }
}

pub use crate::lod::Test;

impl<M: ErrorMetric> View<M> {
    /// Builds the per-frame view. `extent_m` and `z_range_m` give the scene's scale for the rounding
    /// margin.
    pub fn new(
        camera: &Camera,
        options: &RefineOptions,
        metric: M,
        spacing_m: [f64; 2],
        extent_m: [f64; 2],
        z_range_m: [f64; 2],
    ) -> View<M> {
        // Exaggeration x: the scene is (x, y, x·z). Scaled by 1/x it is (x/x, y/x, z) with the
        // eye at eye/x, and a uniform scale changes no angle or screen-space error, so the
        // refinement runs there on the file's own heights, errors and radii: posts x times closer
        // (the radii, bounds of distances that only shrink, stay conservative for x ≥ 1).
        let x = options.z_exaggeration;
        let scaled;
        let (camera, spacing_m, extent_m) = if x != 1.0 && x.is_finite() && x >= 1.0 {
            scaled =
                Camera { eye_in_world: camera.eye_in_world / x, look_at_world: camera.look_at_world / x, ..*camera };
            (&scaled, [spacing_m[0] / x, spacing_m[1] / x], [extent_m[0] / x, extent_m[1] / x])
        } else {
            (camera, spacing_m, extent_m)
        };
        let lod = Lod::new(camera, options.tolerance_px, metric);
        let ratio = options.morph_ratio.unwrap_or(1.0);
        let scale = largest_finite([
            extent_m[0],
            extent_m[1],
            z_range_m[0].abs(),
            z_range_m[1].abs(),
            camera.eye_in_world.abs().max_element(),
            1.0,
        ]);
        let margin_m = crate::lod::margin_for_scale(scale);
        // The grid's largest coordinate, from its extent (the origin only needs to be near it).
        let max_coord = (extent_m[0] / spacing_m[0]).max(extent_m[1] / spacing_m[1]);
        let max_coord = if max_coord.is_finite() { max_coord.clamp(2.0, u32::MAX as f64) as u32 } else { 2 };
        View {
            fast: Fast::new(&lod, spacing_m, max_coord, z_range_m),
            kappa_inner: lod.kappa / ratio,
            lod,
            spacing_m,
            slack_m: std::array::from_fn(|level| margin_m * level as f64),
            cull: options.cull,
            morph: options.morph_ratio.is_some(),
        }
    }

    /// The plane mask a refinement starts with.
    pub fn full_mask(&self) -> u8 {
        if self.cull {
            crate::lod::ALL_PLANES
        } else {
            0
        }
    }

    /// World position of grid post `(x, y)` with height `z`.
    #[inline(always)]
    pub fn position(&self, x: u32, y: u32, z: f32) -> DVec3 {
        DVec3::new(x as f64 * self.spacing_m[0], y as f64 * self.spacing_m[1], z as f64)
    }

    /// The active test with frustum culling against the planes in `mask` (see [`Test`]): in f32
    /// for a Euclidean metric ([`Fast::test`]), else in f64.
    #[inline(always)]
    pub fn test<const CULL: bool>(&self, x: u32, y: u32, level: u32, rec: Record, mask: u8) -> Test {
        if M::EUCLIDEAN {
            return self.fast.test::<CULL>(x, y, level, rec, mask);
        }
        // A null record (error and radius 0) is never active, whatever the slack (as in f32).
        let own = self.lod.kappa * rec.error as f64 + rec.radius as f64;
        if own.is_nan() || own <= 0.0 {
            return Test::Inactive;
        }
        let rel = self.position(x, y, rec.z) - self.lod.eye;
        let r = rec.radius as f64 + self.slack(level);
        self.lod.test::<CULL>(rel, rec.error as f64, r, mask)
    }

    /// Whether a vertex is active, evaluated from scratch (all planes); equals what refinement
    /// decides along any path.
    pub fn is_active(&self, x: u32, y: u32, level: u32, rec: Record) -> bool {
        let t = if self.cull {
            self.test::<true>(x, y, level, rec, self.full_mask())
        } else {
            self.test::<false>(x, y, level, rec, 0)
        };
        matches!(t, Test::Active { .. })
    }

    /// The radius slack at `level`.
    #[inline(always)]
    fn slack(&self, level: u32) -> f64 {
        self.slack_m[level as usize & 63]
    }

    /// Geomorph blend of an active vertex: 0 where it just became active, 1 inside the inner radius.
    #[inline(always)]
    fn blend(&self, x: u32, y: u32, level: u32, rec: Record) -> f32 {
        let rel = self.position(x, y, rec.z) - self.lod.eye;
        let r = rec.radius as f64 + self.slack(level);
        let outer = self.lod.kappa * rec.error as f64 + r;
        let inner = self.kappa_inner * rec.error as f64 + r;
        let span = outer * outer - inner * inner;
        if span > 0.0 && span.is_finite() {
            ((outer * outer - self.lod.metric.distance_sq(rel)) / span).clamp(0.0, 1.0) as f32
        } else if rec.error > 0.0 {
            1.0 // infinite error (never refined away)
        } else {
            // Zero error: the vertex lies on its edge and follows its end points; it was activated
            // by its sphere alone and must not snap.
            0.0
        }
    }

    /// Whether a point (no radius) lies inside the frustum (always, with culling off).
    pub fn point_in_frustum(&self, p: DVec3) -> bool {
        !self.cull || self.lod.point_in_frustum(p)
    }

    /// Whether `κ δ > D`: an un-nested error at `p` projects over the tolerance.
    pub fn error_projects_over(&self, p: DVec3, error_m: f64) -> bool {
        self.lod.error_projects_over(p, error_m)
    }
}

/// Calls a generic function with a terrain's concrete layout and a [`View`] of the chosen metric
/// (for monomorphised loops over one frame).
pub trait ViewVisitor {
    type Output;
    fn visit<L: Layout, M: ErrorMetric>(self, layout: &L, view: &View<M>) -> Self::Output;
}

/// Builds the view of `terrain` for `camera` and `options` and hands it, with the terrain's layout,
/// to `visitor`.
pub fn with_view<V: ViewVisitor>(
    terrain: &TerrainFile,
    camera: &Camera,
    options: &RefineOptions,
    visitor: V,
) -> V::Output {
    struct Go<'a, V> {
        terrain: &'a TerrainFile,
        camera: &'a Camera,
        options: &'a RefineOptions,
        visitor: V,
    }
    impl<V: ViewVisitor> LayoutVisitor for Go<'_, V> {
        type Output = V::Output;
        fn visit<L: Layout>(self, layout: &L) -> V::Output {
            let h = self.terrain.header();
            let (spacing, extent, z_range) = (h.spacing_m, h.extent_m(), [h.z_min, h.z_max]);
            match self.options.metric {
                MetricKind::Isotropic => {
                    let view = View::new(self.camera, self.options, Isotropic, spacing, extent, z_range);
                    self.visitor.visit(layout, &view)
                }
                MetricKind::Projected => {
                    let metric = Projected { forward: self.camera.forward() };
                    let view = View::new(self.camera, self.options, metric, spacing, extent, z_range);
                    self.visitor.visit(layout, &view)
                }
            }
        }
    }
    terrain.layout().visit(Go { terrain, camera, options, visitor })
}

#[inline(always)]
fn sv(v: Vertex) -> StripVertex {
    StripVertex { x: v.x, y: v.y }
}

/// A pending triangle of the top levels, refined as one task on a worker thread.
#[derive(Clone, Copy, Debug)]
struct Task {
    apex: Vertex,
    split: Vertex,
    /// Left end of the hypotenuse: the strip arrives there before the task's vertices.
    left: StripVertex,
    level: u32,
    mask: u8,
    m: MorphTri,
}

#[derive(Clone, Copy, Debug)]
enum Item {
    Append(StripVertex, u8, Morph),
    Task(usize),
}

/// Default for [`Refiner::set_parallel_min_len`]: about 10⁴ triangles, below which two threads
/// measured no faster than one (BENCHMARKS.md).
pub const PARALLEL_MIN_LEN: usize = 16_384;

/// Runs refinement, single-threaded or split across a thread pool, reusing its buffers between
/// frames.
pub struct Refiner {
    pool: Option<rayon::ThreadPool>,
    threads: usize,
    /// Strips shorter than this (judged by the previous frame's) are refined on the calling
    /// thread: splitting them costs more than it saves.
    parallel_min_len: usize,
    last_len: usize,
    items: Vec<Item>,
    next_items: Vec<Item>,
    tasks: Vec<Task>,
    next_tasks: Vec<Task>,
    backs: Vec<Back>,
    /// Per task, where a worker left it: (worker, start, end) in that worker's strip.
    placed: Vec<Option<(usize, usize, usize)>>,
}

impl Refiner {
    /// A refiner using `threads` threads (1: the calling thread only, no pool).
    pub fn new(threads: usize) -> crate::Result<Refiner> {
        let threads = threads.max(1);
        let pool = if threads > 1 {
            Some(
                // The calling thread refines too: the pool holds the other threads.
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads - 1)
                    .thread_name(|k| format!("relief-refine-{k}"))
                    .build()
                    .map_err(|e| crate::Error::Thread {
                        what: format!("{threads} refinement"),
                        source: std::io::Error::other(e),
                    })?,
            )
        } else {
            None
        };
        Ok(Refiner {
            pool,
            threads,
            parallel_min_len: PARALLEL_MIN_LEN,
            last_len: usize::MAX,
            items: Vec::new(),
            next_items: Vec::new(),
            tasks: Vec::new(),
            next_tasks: Vec::new(),
            backs: Vec::new(),
            placed: Vec::new(),
        })
    }

    pub fn threads(&self) -> usize {
        self.threads
    }

    /// Refine on the pool only when the previous strip had at least `len` vertices (default
    /// [`PARALLEL_MIN_LEN`]; 0: always).
    pub fn set_parallel_min_len(&mut self, len: usize) {
        self.parallel_min_len = len;
    }

    /// Refines a terrain file for `camera`, writing the strip into `strip`: in place when the
    /// file is mapped (through [`MappedRecords`] when its pager has an observer), else through
    /// its pager. Counts nothing; [`Self::refine_file_counted`] counts.
    pub fn refine_file(
        &mut self,
        terrain: &TerrainFile,
        camera: &Camera,
        options: &RefineOptions,
        strip: &mut Strip,
    ) -> crate::Result<()> {
        self.file_tally::<Uncounted>(terrain, camera, options, strip).map(drop)
    }

    /// [`Self::refine_file`], counting the vertices tested and culled.
    pub fn refine_file_counted(
        &mut self,
        terrain: &TerrainFile,
        camera: &Camera,
        options: &RefineOptions,
        strip: &mut Strip,
    ) -> crate::Result<RefineCounters> {
        self.file_tally::<Counted>(terrain, camera, options, strip)
    }

    fn file_tally<C: Tally>(
        &mut self,
        terrain: &TerrainFile,
        camera: &Camera,
        options: &RefineOptions,
        strip: &mut Strip,
    ) -> crate::Result<RefineCounters> {
        match (terrain.mapped_records(), terrain.pager().observer()) {
            (Some(records), None) => Ok(match RecordSlice::new(records) {
                Some(slice) => self.source_tally::<_, C>(terrain, &slice, camera, options, strip),
                None => self.source_tally::<_, C>(terrain, records, camera, options, strip),
            }),
            (Some(records), Some(observer)) => {
                let source = MappedRecords::new(records, terrain.header().payload_offset, observer);
                Ok(self.source_tally::<_, C>(terrain, &source, camera, options, strip))
            }
            (None, _) => {
                let source = PagerRecords::new(terrain);
                let counters = self.source_tally::<_, C>(terrain, &source, camera, options, strip);
                source.take_error()?;
                Ok(counters)
            }
        }
    }

    /// Like [`Self::refine_file`], reading records through `records` (same layout as `terrain`).
    pub fn refine_source<R: RecordSource + ?Sized>(
        &mut self,
        terrain: &TerrainFile,
        records: &R,
        camera: &Camera,
        options: &RefineOptions,
        strip: &mut Strip,
    ) {
        self.source_tally::<R, Uncounted>(terrain, records, camera, options, strip);
    }

    /// [`Self::refine_source`], counting the vertices tested and culled.
    pub fn refine_source_counted<R: RecordSource + ?Sized>(
        &mut self,
        terrain: &TerrainFile,
        records: &R,
        camera: &Camera,
        options: &RefineOptions,
        strip: &mut Strip,
    ) -> RefineCounters {
        self.source_tally::<R, Counted>(terrain, records, camera, options, strip)
    }

    fn source_tally<R: RecordSource + ?Sized, C: Tally>(
        &mut self,
        terrain: &TerrainFile,
        records: &R,
        camera: &Camera,
        options: &RefineOptions,
        strip: &mut Strip,
    ) -> RefineCounters {
        struct Go<'a, R: ?Sized, C> {
            refiner: &'a mut Refiner,
            records: &'a R,
            strip: &'a mut Strip,
            tally: std::marker::PhantomData<C>,
        }
        impl<R: RecordSource + ?Sized, C: Tally> ViewVisitor for Go<'_, R, C> {
            type Output = RefineCounters;
            fn visit<L: Layout, M: ErrorMetric>(self, layout: &L, view: &View<M>) -> RefineCounters {
                self.refiner.refine_tally::<L, R, M, C>(layout, self.records, view, self.strip)
            }
        }
        let go = Go { refiner: self, records, strip, tally: std::marker::PhantomData::<C> };
        with_view(terrain, camera, options, go)
    }

    /// The generic entry: layout, record source and metric are all monomorphised. Counts
    /// nothing, so that its loop has no increments; [`Self::refine_counted`] counts.
    pub fn refine<L: Layout, R: RecordSource + ?Sized, M: ErrorMetric>(
        &mut self,
        layout: &L,
        records: &R,
        view: &View<M>,
        strip: &mut Strip,
    ) {
        self.refine_tally::<L, R, M, Uncounted>(layout, records, view, strip);
    }

    /// [`Self::refine`], counting the vertices it tests and culls (a separate monomorph).
    pub fn refine_counted<L: Layout, R: RecordSource + ?Sized, M: ErrorMetric>(
        &mut self,
        layout: &L,
        records: &R,
        view: &View<M>,
        strip: &mut Strip,
    ) -> RefineCounters {
        self.refine_tally::<L, R, M, Counted>(layout, records, view, strip)
    }

    fn refine_tally<L: Layout, R: RecordSource + ?Sized, M: ErrorMetric, C: Tally>(
        &mut self,
        layout: &L,
        records: &R,
        view: &View<M>,
        strip: &mut Strip,
    ) -> RefineCounters {
        if view.morph {
            self.refine_mode::<L, R, M, MorphTri, C>(layout, records, view, strip)
        } else {
            self.refine_mode::<L, R, M, NoMorph, C>(layout, records, view, strip)
        }
    }

    fn refine_mode<L: Layout, R: RecordSource + ?Sized, M: ErrorMetric, S: Carry, C: Tally>(
        &mut self,
        layout: &L,
        records: &R,
        view: &View<M>,
        strip: &mut Strip,
    ) -> RefineCounters {
        let grid = layout.grid();
        let [sw, se, ne, nw] = grid.corners().map(|(x, y)| layout.vertex(x, y));
        let (cx, cy) = grid.centre();
        let c = layout.vertex(cx, cy);
        let corner_morph = |v: Vertex| {
            let z = records.record(v.index).z;
            Morph { blend: 1.0, z_m: z }
        };
        let corners = [sw, se, ne, nw].map(|v| (v, corner_morph(v)));
        let zc = records.record(c.index).z;
        let [w, s, e, n] = grid.edge_midpoints().map(|(x, y)| layout.vertex(x, y));
        // The four root triangles around the centre, in strip order: (c; sw, se) split at s, …
        let roots = [(s, 0usize), (e, 1), (n, 2), (w, 3)].map(|(split, k)| {
            let (left, ml) = corners[k];
            let (_, mr) = corners[(k + 1) % 4];
            Task {
                apex: c,
                split,
                left: sv(left),
                level: grid.levels(),
                mask: view.full_mask(),
                m: MorphTri { z_left: ml.z_m, z_apex: zc, z_right: mr.z_m, blend_left: 1.0, blend_apex: 1.0 },
            }
        });
        let parallel = self.pool.is_some() && grid.levels() >= 8 && self.last_len >= self.parallel_min_len;
        // Room for the previous frame's strip and half again, so the walk rarely grows it.
        let last = if self.last_len == usize::MAX { 0 } else { self.last_len };
        let reserve = last.saturating_add(last / 2).max(1024);
        strip.seed(sv(sw), corners[0].1, S::ON);
        let counters = if parallel {
            self.refine_parallel::<L, R, M, S, C>(layout, records, view, strip, &roots, &corners, reserve)
        } else {
            let (mut walk, mut at) = Walk::<L, R, M, S, C>::new(layout, records, view, strip, reserve);
            for (k, t) in roots.iter().enumerate() {
                at = walk.sub(at, t.apex, t.split, t.level, t.mask, S::new(&t.m));
                if k < 3 {
                    let (v, m) = corners[k + 1];
                    at = walk.append(at, sv(v), 1, m);
                }
            }
            walk.finish(at)
        };
        strip.parity = (strip.len() % 2) as u8;
        strip.push(sv(sw), corners[0].1, S::ON);
        self.last_len = strip.len();
        counters
    }

    /// Expands the top of the recursion breadth-first (keeping strip order) until there are enough
    /// tasks to balance the threads, refines the tasks in parallel (the calling thread's straight
    /// into the strip, the workers' into their own), then stitches the workers' in with degenerate
    /// triangles so that every vertex keeps its winding parity.
    #[allow(clippy::too_many_arguments, reason = "internal; each argument is a distinct input")]
    fn refine_parallel<L: Layout, R: RecordSource + ?Sized, M: ErrorMetric, S: Carry, C: Tally>(
        &mut self,
        layout: &L,
        records: &R,
        view: &View<M>,
        strip: &mut Strip,
        roots: &[Task; 4],
        corners: &[(Vertex, Morph); 4],
        reserve: usize,
    ) -> RefineCounters {
        let mut counters = RefineCounters::default();
        self.items.clear();
        self.tasks.clear();
        for (k, t) in roots.iter().enumerate() {
            self.items.push(Item::Task(self.tasks.len()));
            self.tasks.push(*t);
            if k < 3 {
                let (v, m) = corners[k + 1];
                self.items.push(Item::Append(sv(v), 1, m));
            }
        }
        // More tasks than threads, so that work stealing evens out the view-dependent cost; 16 a
        // thread measured faster than 64 at 10³–10⁵ triangles (fewer probes and seams, BENCHMARKS.md).
        let target = 16 * self.threads;
        while self.tasks.len() < target {
            let mut expanded = false;
            self.next_items.clear();
            self.next_tasks.clear();
            for item in self.items.iter() {
                let Item::Task(k) = *item else {
                    self.next_items.push(*item);
                    continue;
                };
                let t = self.tasks[k];
                if t.level < 3 {
                    self.next_items.push(Item::Task(self.next_tasks.len()));
                    self.next_tasks.push(t);
                    continue;
                }
                expanded = true;
                let split = probe_vertex::<R, M, S, C>(
                    records,
                    view,
                    t.split,
                    t.level - 1,
                    t.mask,
                    &S::new(&t.m),
                    &mut counters,
                );
                match split {
                    None => self.next_items.push(Item::Append(sv(t.apex), (t.level & 1) as u8, t.m.apex())),
                    Some((mask, p)) => {
                        let [cl, cr] = layout.split_children(t.apex, t.split);
                        let (left, right) = Carry::halves(&t.m, S::morph(p));
                        self.next_items.push(Item::Task(self.next_tasks.len()));
                        self.next_tasks.push(Task {
                            apex: t.split,
                            split: cl,
                            left: t.left,
                            level: t.level - 1,
                            mask,
                            m: left,
                        });
                        self.next_items.push(Item::Append(sv(t.apex), (t.level & 1) as u8, t.m.apex()));
                        self.next_items.push(Item::Task(self.next_tasks.len()));
                        self.next_tasks.push(Task {
                            apex: t.split,
                            split: cr,
                            left: sv(t.apex),
                            level: t.level - 1,
                            mask,
                            m: right,
                        });
                    }
                }
            }
            std::mem::swap(&mut self.items, &mut self.next_items);
            std::mem::swap(&mut self.tasks, &mut self.next_tasks);
            if !expanded {
                break;
            }
        }

        // The calling thread takes tasks from the front, in strip order, refining them straight
        // into `strip` (as the single-threaded walk would); the pool's workers take them from the
        // back into buffers of their own. Where the two meet depends on how fast each goes, so the
        // split balances itself; only the workers' share is copied into the strip afterwards.
        let n = self.tasks.len();
        let claims = Claims::new(n);
        let workers = self.threads - 1;
        if self.backs.len() < workers {
            self.backs.resize_with(workers, Back::default);
        }
        let tasks = &self.tasks;
        let items = &self.items;
        let backs = &mut self.backs[..workers];
        let pool = self.pool.as_ref().expect("parallel refinement has a pool");
        let mut resume = items.len();
        pool.in_place_scope(|scope| {
            for back in backs.iter_mut() {
                let claims = &claims;
                scope.spawn(move |_| back.run::<L, R, M, S, C>(layout, records, view, tasks, claims));
            }
            let (mut walk, mut at) = Walk::<L, R, M, S, C>::new(layout, records, view, &mut *strip, reserve);
            for (k, item) in items.iter().enumerate() {
                match *item {
                    Item::Append(v, p, m) => at = walk.append(at, v, p, m),
                    Item::Task(j) => {
                        if !claims.front() {
                            resume = k;
                            break;
                        }
                        let t = &tasks[j];
                        at = walk.sub(at, t.apex, t.split, t.level, t.mask, S::new(&t.m));
                    }
                }
            }
            counters += walk.finish(at);
        });
        strip.parity = (strip.len() % 2) as u8;

        if resume < items.len() {
            // The workers' tasks, in strip order.
            self.placed.clear();
            self.placed.resize(n, None);
            for (w, back) in self.backs[..workers].iter().enumerate() {
                counters += back.counters;
                for seg in &back.segments {
                    self.placed[seg.task] = Some((w, seg.start, seg.end));
                }
            }
            for item in &self.items[resume..] {
                match *item {
                    Item::Append(v, p, m) => strip.append(v, p, m, S::ON),
                    Item::Task(k) => {
                        let Some((w, start, end)) = self.placed[k] else {
                            unreachable!("every task is claimed by the front or a worker")
                        };
                        let chunk = &self.backs[w].strip;
                        stitch(strip, &chunk.vertices[start..end], if S::ON { &chunk.morph[start..end] } else { &[] });
                    }
                }
            }
        } else {
            for back in &self.backs[..workers] {
                counters += back.counters;
            }
        }
        counters
    }
}

/// Appends a chunk refined on its own from `(a, a)` with parity 0 (the same invariant as the
/// whole strip, parity == len % 2): its vertex at local index 2 must land on an even index, after
/// a repeated `a` so that the seam triangles are degenerate. `morph` is empty when geomorphing
/// is off.
fn stitch(strip: &mut Strip, chunk: &[StripVertex], morph: &[Morph]) {
    let on = !morph.is_empty();
    let (a, ma) = (chunk[0], morph.first().copied().unwrap_or_default());
    if strip.vertices.last() != Some(&a) {
        strip.push(a, ma, on);
    }
    strip.push(a, ma, on);
    if strip.len() % 2 == 1 {
        strip.push(a, ma, on);
    }
    strip.vertices.extend_from_slice(&chunk[2..]);
    if on {
        strip.morph.extend_from_slice(&morph[2..]);
    }
    strip.parity = (strip.len() % 2) as u8;
}

/// Which tasks are taken: the calling thread claims from the front, in order, the workers from
/// the back; `(front << 32) | back` in one word, so that a task is claimed exactly once.
struct Claims(std::sync::atomic::AtomicU64);

impl Claims {
    fn new(n: usize) -> Claims {
        Claims(std::sync::atomic::AtomicU64::new(n as u64))
    }

    /// Claims the next front task (the calling thread's, in strip order); false once the workers
    /// have taken the rest.
    fn front(&self) -> bool {
        use std::sync::atomic::Ordering::Relaxed;
        self.0.fetch_update(Relaxed, Relaxed, |w| ((w >> 32) < (w & 0xffff_ffff)).then(|| w + (1 << 32))).is_ok()
    }

    /// Claims the last unclaimed task, for a worker.
    fn back(&self) -> Option<usize> {
        use std::sync::atomic::Ordering::Relaxed;
        self.0
            .fetch_update(Relaxed, Relaxed, |w| ((w >> 32) < (w & 0xffff_ffff)).then(|| w - 1))
            .ok()
            .map(|w| (w & 0xffff_ffff) as usize - 1)
    }
}

/// A worker's output: its tasks' strips one after another, each seeded with its left vertex at
/// an even offset (so that each keeps parity == length mod 2, as the walk needs).
#[derive(Default)]
struct Back {
    strip: Strip,
    segments: Vec<Segment>,
    counters: RefineCounters,
}

impl Back {
    /// Refines tasks claimed from the back until none is left.
    fn run<L: Layout, R: RecordSource + ?Sized, M: ErrorMetric, S: Carry, C: Tally>(
        &mut self,
        layout: &L,
        records: &R,
        view: &View<M>,
        tasks: &[Task],
        claims: &Claims,
    ) {
        self.strip.vertices.clear();
        self.strip.morph.clear();
        self.segments.clear();
        self.counters = RefineCounters::default();
        while let Some(k) = claims.back() {
            let t = &tasks[k];
            if self.strip.len() % 2 == 1 {
                // Keep every task's seed at an even offset.
                let pad = self.strip.vertices.last().copied().unwrap_or_default();
                self.strip.push(pad, Morph::default(), S::ON);
            }
            let start = self.strip.len();
            self.strip.push(t.left, t.m.left(), S::ON);
            self.strip.push(t.left, t.m.left(), S::ON);
            self.strip.parity = 0;
            let (mut walk, at) = Walk::<L, R, M, S, C>::new(layout, records, view, &mut self.strip, 0);
            let at = walk.sub(at, t.apex, t.split, t.level, t.mask, S::new(&t.m));
            self.counters += walk.finish(at);
            self.segments.push(Segment { task: k, start, end: self.strip.len() });
        }
    }
}

#[derive(Clone, Copy, Debug)]
struct Segment {
    task: usize,
    start: usize,
    end: usize,
}

/// Triangle count of the conforming bisection mesh whose inserted vertices are `vertices` (corners
/// excluded, centre included): every interior vertex splits two triangles, a border vertex one.
pub fn mesh_triangles(grid: Grid, vertices: impl IntoIterator<Item = (u32, u32)>) -> u64 {
    let m = grid.max_coord();
    let mut t = 2u64;
    for (x, y) in vertices {
        let border = x == 0 || y == 0 || x == m || y == m;
        t += if border { 1 } else { 2 };
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::RowMajor;

    /// A 3 × 3 grid (n = 1) of flat records; the centre has infinite error, the edge midpoints
    /// `edge_error`.
    fn tiny(edge_error: f32) -> (RowMajor, Vec<Record>) {
        let layout = RowMajor::new(Grid::new(1).unwrap());
        let mut records = vec![Record { z: 0.0, error: edge_error, radius: 0.0 }; 9];
        records[layout.index(1, 1) as usize].error = f32::INFINITY;
        (layout, records)
    }

    fn strip_of(layout: &RowMajor, records: &[Record], tolerance_px: f64) -> Vec<(u32, u32)> {
        let camera =
            Camera::new(DVec3::new(1.0, 1.0, 100.0), DVec3::new(1.0, 1.0, 0.0), DVec3::Y, 60.0, 640, 480).unwrap();
        let options = RefineOptions { tolerance_px, ..RefineOptions::default() };
        let view = View::new(&camera, &options, Isotropic, [1.0, 1.0], [2.0, 2.0], [0.0, 0.0]);
        let mut strip = Strip::new();
        Refiner::new(1).unwrap().refine(layout, records, &view, &mut strip);
        strip.vertices.iter().map(|v| (v.x, v.y)).collect()
    }

    /// Worked by hand from the paper's `strip_append` rules: only the centre active gives the four
    /// triangles around it, each corner turn costing one degenerate triangle.
    #[test]
    fn centre_only_strip_is_the_four_root_triangles() {
        let (layout, records) = tiny(0.0);
        let s = strip_of(&layout, &records, 1.0);
        let (sw, se, ne, nw, c) = ((0, 0), (2, 0), (2, 2), (0, 2), (1, 1));
        assert_eq!(s, vec![sw, sw, sw, c, se, c, ne, c, nw, sw]);
    }

    /// All eight triangles of the 3 × 3 grid, again worked by hand: the edge midpoints are appended
    /// with parity 1, so each costs one repeated centre.
    #[test]
    fn fully_refined_tiny_grid_strip() {
        let (layout, records) = tiny(10.0);
        let s = strip_of(&layout, &records, 1.0);
        let (sw, se, ne, nw, c) = ((0, 0), (2, 0), (2, 2), (0, 2), (1, 1));
        let (w, south, e, n) = ((0, 1), (1, 0), (2, 1), (1, 2));
        assert_eq!(s, vec![sw, sw, south, c, se, c, e, c, ne, c, n, c, nw, c, w, sw]);
        let strip = Strip::from_vertices(s.iter().map(|&(x, y)| StripVertex { x, y }).collect());
        assert_eq!(strip.triangle_counts(), (8, 6));
        // Every triangle clockwise seen from above.
        for [a, b, c] in strip.triangles() {
            let cross = (b.x as i64 - a.x as i64) * (c.y as i64 - a.y as i64)
                - (b.y as i64 - a.y as i64) * (c.x as i64 - a.x as i64);
            assert!(cross < 0);
        }
    }

    #[test]
    fn append_keeps_parity_equal_to_length_parity() {
        let mut s = Strip::new();
        s.seed(StripVertex { x: 0, y: 0 }, Morph::default(), false);
        for (k, p) in (1..).zip([1u8, 1, 0, 0, 1, 0, 1, 1]) {
            s.append(StripVertex { x: k, y: 0 }, p, Morph::default(), false);
            assert_eq!(s.parity as usize, s.len() % 2);
        }
    }
}
