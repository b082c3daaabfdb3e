//! Flight paths: sequences of camera frames (eye and look point) for flying over a terrain or
//! around a mesh, their JSON file format, and two generators each: a straight fly-over and an orbit
//! over a terrain (`flyover`, `orbit`) or about a mesh's bounding box (`flyover_box`, `orbit_box`).
//!
//! Coordinates are world metres, as everywhere in relief: origin at the grid's south-west corner,
//! x east (grid x × spacing x), y north (grid y × spacing y), z up (height in metres). A mesh's
//! coordinates are its file's, with a chosen up axis ([`UpAxis`]).
//!
//! The file is a JSON array with one object per frame, written one frame per line so that paths
//! diff well:
//!
//! ```text
//! [
//!   {"eye":[500.0,400.0,1200.0],"look":[1500.0,1400.0,900.0]},
//!   {"eye":[520.0,420.0,1210.0],"look":[1520.0,1420.0,910.0]}
//! ]
//! ```
//!
//! Unknown fields are rejected so that a typo (`"lok"`) is an error, not a silently ignored key.

use std::collections::VecDeque;
use std::io::Write;
use std::path::Path;

use glam::{DVec2, DVec3};
use serde::{Deserialize, Serialize};
use serde_json::value::RawValue;

use crate::camera::{Camera, UpAxis};
use crate::error::{Error, Result};
use crate::format::terrain::TerrainFile;
use crate::mesh::Bounds;

/// The most frames a generator makes: far more than any fly-through needs, and small enough that a
/// mistyped count fails with a message instead of exhausting memory.
pub const MAX_FRAMES: usize = 1_000_000;

/// Fly-over: the path starts and ends this fraction of the valid window's width/height inside
/// its south-west and north-east corners, so the first and last views are not of the edge.
pub const FLYOVER_INSET: f64 = 0.05;
/// Fly-over: default clearance above the terrain, as a fraction of the valid window's diagonal.
pub const FLYOVER_CLEARANCE_OF_DIAGONAL: f64 = 0.02;
/// Fly-over: the eye clears the highest terrain within this radius (fraction of the diagonal), so
/// that hills beside and just ahead of the eye are cleared too, not only the ground under it.
pub const FLYOVER_RADIUS_OF_DIAGONAL: f64 = 0.03;
/// Fly-over: the look point is this far ahead (horizontally, fraction of the diagonal) ...
pub const FLYOVER_LOOK_AHEAD_OF_DIAGONAL: f64 = 0.10;
/// ... and this many degrees below the horizon.
pub const FLYOVER_PITCH_DEG: f64 = 15.0;
/// Orbit: default radius as a fraction of half the valid window's diagonal.
pub const ORBIT_RADIUS_OF_HALF_DIAGONAL: f64 = 0.6;
/// Orbit: default altitude is `z_max` plus this fraction of half the diagonal.
pub const ORBIT_ALTITUDE_OF_HALF_DIAGONAL: f64 = 0.3;

/// Orbit around a mesh's bounding box: default horizontal radius, as a fraction of the box's
/// diagonal. Above half, every eye is outside the box; 1.2 also keeps a bounding sphere of the
/// object (radius half the diagonal) within about 24° of the view axis.
pub const ORBIT_BOX_RADIUS_OF_DIAGONAL: f64 = 1.2;
/// Orbit around a box: default eye height above the box's centre (along up), fraction of the
/// diagonal (looks down about 18°).
pub const ORBIT_BOX_ALTITUDE_OF_DIAGONAL: f64 = 0.4;

/// Samples per side of the square around the fly-over's clearance disk: bounds the cost per frame
/// (about 2,000 height reads in the disk) whatever the grid size, 16385² included.
const DISK_SAMPLES_PER_SIDE: f64 = 48.0;

/// One frame of a flight path: where the eye is and the point it looks at, world metres.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PathFrame {
    pub eye: [f64; 3],
    pub look: [f64; 3],
}

impl PathFrame {
    pub fn eye_in_world(&self) -> DVec3 {
        DVec3::from_array(self.eye)
    }

    pub fn look_at_world(&self) -> DVec3 {
        DVec3::from_array(self.look)
    }

    /// What makes this frame unusable as a camera, if anything.
    fn problem(&self) -> Option<String> {
        let finite = |v: &[f64; 3]| v.iter().all(|c| c.is_finite());
        if !finite(&self.eye) {
            return Some(format!("eye {:?} has a non-finite coordinate", self.eye));
        }
        if !finite(&self.look) {
            return Some(format!("look {:?} has a non-finite coordinate", self.look));
        }
        if self.eye == self.look {
            let [x, y, z] = self.eye;
            return Some(format!("look point equals the eye ({x}, {y}, {z})"));
        }
        None
    }
}

/// A flight path: one camera frame per rendered image.
#[derive(Clone, Debug, PartialEq)]
pub struct FlightPath {
    pub frames: Vec<PathFrame>,
}

/// What `relief path` reports about a path over a terrain.
#[derive(Serialize, Clone, Debug, PartialEq)]
pub struct PathSummary {
    pub frames: usize,
    /// Length of the polyline through the eyes, metres.
    pub length_m: f64,
    /// Least height of an eye above the terrain under it (the highest of the four posts around the
    /// eye), metres; `None` when no eye is over the grid. For a path around a mesh
    /// ([`FlightPath::summary_box`]): the least distance from an eye to its bounding box.
    pub min_clearance_m: Option<f64>,
}

impl FlightPath {
    /// Reads a flight-path file (see the module documentation for the format).
    ///
    /// Errors: [`Error::Io`] if the file cannot be read; [`Error::BadPath`] for malformed JSON
    /// (serde's message with line and column), an empty array (`flight path has no frames`), or a
    /// frame that cannot be parsed or used (`frame K: …`: missing or unknown field, a number out
    /// of range such as `1e999`, a non-finite coordinate, look point equal to the eye).
    pub fn load(path: &Path) -> Result<FlightPath> {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        let text = std::str::from_utf8(&bytes).map_err(|e| Error::bad_path(path, format!("not UTF-8 text: {e}")))?;
        // Two stages: the array first, then each frame from its own text. A frame's error can then
        // name the frame, and a number out of f64's range (1e999, which JSON allows) is reported
        // as that frame's problem: RawValue skips numbers without converting them.
        let raw: Vec<&RawValue> = serde_json::from_str(text).map_err(|e| Error::bad_path(path, e.to_string()))?;
        if raw.is_empty() {
            return Err(Error::bad_path(path, "flight path has no frames"));
        }
        let mut frames = Vec::with_capacity(raw.len());
        for (k, r) in raw.iter().enumerate() {
            let frame: PathFrame = serde_json::from_str(r.get())
                .map_err(|e| Error::bad_path(path, format!("frame {k}: {}", at_file_position(text, r.get(), &e))))?;
            if let Some(problem) = frame.problem() {
                return Err(Error::bad_path(path, format!("frame {k}: {problem}")));
            }
            frames.push(frame);
        }
        Ok(FlightPath { frames })
    }

    /// Writes the path in the format [`Self::load`] reads, one frame per line. The file is written
    /// beside `path` under a temporary name, synced and renamed over `path`, so a failure leaves
    /// the old file (or none), never a half-written one.
    ///
    /// A path that `load` would reject (no frames, a non-finite coordinate, look = eye) is refused
    /// with [`Error::BadPath`]: JSON has no NaN or infinity, so it could not be read back.
    pub fn save(&self, path: &Path) -> Result<()> {
        if self.frames.is_empty() {
            return Err(Error::bad_path(path, "flight path has no frames"));
        }
        let mut text = String::from("[\n");
        for (k, frame) in self.frames.iter().enumerate() {
            if let Some(problem) = frame.problem() {
                return Err(Error::bad_path(path, format!("frame {k}: {problem}")));
            }
            let line = serde_json::to_string(frame).map_err(|e| Error::bad_path(path, format!("frame {k}: {e}")))?;
            text.push_str("  ");
            text.push_str(&line);
            text.push_str(if k + 1 < self.frames.len() { ",\n" } else { "\n" });
        }
        text.push_str("]\n");

        crate::sys::atomic_file::write(path, |w| w.write_all(text.as_bytes()))
    }

    /// The camera of frame `k`: up is +z, or +y when the view is (nearly) vertical, where +z
    /// would be parallel to the view direction.
    pub fn camera(&self, k: usize, fov_x_deg: f64, width_px: u32, height_px: u32) -> Result<Camera> {
        self.camera_with_up(k, UpAxis::Z, fov_x_deg, width_px, height_px)
    }

    /// The camera of frame `k` with `up` as the world's up axis, or the frame's second horizontal
    /// axis ([`UpAxis::frame`]: +y for z up) when the view is (nearly) along `up`.
    pub fn camera_with_up(
        &self,
        k: usize,
        up: UpAxis,
        fov_x_deg: f64,
        width_px: u32,
        height_px: u32,
    ) -> Result<Camera> {
        let frame = self
            .frames
            .get(k)
            .ok_or_else(|| Error::out_of_range("frame", format!("below the path's {} frames", self.frames.len()), k))?;
        let (eye, look) = (frame.eye_in_world(), frame.look_at_world());
        let forward = (look - eye).normalize_or_zero();
        let (_, fallback, up) = up.frame();
        // Camera::new rejects |forward × up| < 1e-9; switch well before that, where the basis is
        // still well conditioned.
        let up = if forward.cross(up).length() < 1e-6 { fallback } else { up };
        Camera::new(eye, look, up, fov_x_deg, width_px, height_px)
    }

    /// Length of the polyline through the eyes, metres.
    pub fn length_m(&self) -> f64 {
        self.frames.windows(2).map(|w| w[0].eye_in_world().distance(w[1].eye_in_world())).sum()
    }

    /// Frame count, length and least clearance above `terrain` (see [`PathSummary`]).
    pub fn summary(&self, terrain: &TerrainFile) -> Result<PathSummary> {
        let mut min_clearance_m: Option<f64> = None;
        for f in &self.frames {
            if let Some(g) = ground_max_m(terrain, f.eye[0], f.eye[1])? {
                let c = f.eye[2] - g;
                min_clearance_m = Some(min_clearance_m.map_or(c, |m| m.min(c)));
            }
        }
        Ok(PathSummary { frames: self.frames.len(), length_m: self.length_m(), min_clearance_m })
    }
}

/// serde's message for an error inside one frame's text, with the line and column moved from the
/// frame's text to the whole file, so the position points into the file the user edits.
fn at_file_position(file: &str, fragment: &str, e: &serde_json::Error) -> String {
    let msg = e.to_string();
    if e.line() == 0 {
        return msg;
    }
    let suffix = format!(" at line {} column {}", e.line(), e.column());
    let bare = msg.strip_suffix(&suffix).unwrap_or(&msg);
    // The fragment borrows from `file` (RawValue from a &str); guard anyway.
    let start = (fragment.as_ptr() as usize).wrapping_sub(file.as_ptr() as usize);
    let Some(before) = file.get(..start) else {
        return msg;
    };
    let fragment_line = 1 + before.matches('\n').count();
    let fragment_col0 = before.len() - before.rfind('\n').map_or(0, |i| i + 1);
    let (line, column) = if e.line() == 1 {
        (fragment_line, fragment_col0 + e.column())
    } else {
        (fragment_line + e.line() - 1, e.column())
    };
    format!("{bare} at line {line} column {column}")
}

fn check_frames(frames: usize) -> Result<()> {
    if frames == 0 || frames > MAX_FRAMES {
        return Err(Error::out_of_range("frames", format!("between 1 and {MAX_FRAMES}"), frames));
    }
    Ok(())
}

fn check_positive_m(what: &'static str, v: Option<f64>) -> Result<()> {
    match v {
        Some(v) if !(v.is_finite() && v > 0.0) => Err(Error::out_of_range(what, "a positive number of metres", v)),
        _ => Ok(()),
    }
}

/// The valid window (the DEM's own extent inside the padded grid) in world metres: the first and
/// last valid posts' positions, south-west `lo` and north-east `hi`.
#[derive(Clone, Copy, Debug)]
struct WindowM {
    lo: DVec2,
    hi: DVec2,
}

impl WindowM {
    fn of(terrain: &TerrainFile) -> WindowM {
        let h = terrain.header();
        let [x0, y0, x1, y1] = h.valid_window.map(f64::from);
        let [sx, sy] = h.spacing_m;
        // Half-open in posts: the last valid post is x1 − 1 (the header guarantees x0 < x1).
        WindowM { lo: DVec2::new(x0 * sx, y0 * sy), hi: DVec2::new((x1 - 1.0) * sx, (y1 - 1.0) * sy) }
    }

    fn diagonal_m(&self) -> f64 {
        (self.hi - self.lo).length()
    }

    fn centre(&self) -> DVec2 {
        (self.lo + self.hi) / 2.0
    }
}

/// The four posts around world point `(x_m, y_m)` (fewer distinct ones on post lines) with their
/// bilinear weights, or `None` outside the grid.
fn posts_around(terrain: &TerrainFile, x_m: f64, y_m: f64) -> Option<[(u32, u32, f64); 4]> {
    let [sx, sy] = terrain.header().spacing_m;
    let last = f64::from(terrain.grid().size() - 1);
    let (gx, gy) = (x_m / sx, y_m / sy);
    if !(0.0..=last).contains(&gx) || !(0.0..=last).contains(&gy) {
        return None;
    }
    let (fx, fy) = (gx.floor(), gy.floor());
    let (x0, y0) = (fx as u32, fy as u32);
    let (x1, y1) = ((gx.ceil() as u32).min(last as u32), (gy.ceil() as u32).min(last as u32));
    let (tx, ty) = (gx - fx, gy - fy);
    Some([(x0, y0, (1.0 - tx) * (1.0 - ty)), (x1, y0, tx * (1.0 - ty)), (x0, y1, (1.0 - tx) * ty), (x1, y1, tx * ty)])
}

/// The highest of the (up to four) posts around world point `(x_m, y_m)`, metres, or `None`
/// outside the grid. Every triangulation of the grid cell lies at or below it, whatever the
/// refinement, so an eye above it is above the terrain drawn there.
pub fn ground_max_m(terrain: &TerrainFile, x_m: f64, y_m: f64) -> Result<Option<f64>> {
    let Some(posts) = posts_around(terrain, x_m, y_m) else { return Ok(None) };
    let mut best = f64::NEG_INFINITY;
    for (x, y, _) in posts {
        best = best.max(f64::from(terrain.height_at(x, y)?));
    }
    Ok(Some(best))
}

/// Bilinear height of the posts around world point `(x_m, y_m)`, metres, or `None` outside the
/// grid.
pub fn ground_bilinear_m(terrain: &TerrainFile, x_m: f64, y_m: f64) -> Result<Option<f64>> {
    let Some(posts) = posts_around(terrain, x_m, y_m) else { return Ok(None) };
    let mut sum = 0.0;
    for (x, y, w) in posts {
        sum += w * f64::from(terrain.height_at(x, y)?);
    }
    Ok(Some(sum))
}

/// The highest terrain within `radius_m` of a point, from a lattice of at most
/// [`DISK_SAMPLES_PER_SIDE`]² posts of the valid window, plus the posts around the point itself.
/// The lattice is fixed in the grid (multiples of the stride), not centred on the point, so
/// neighbouring frames see the same samples and the profile does not jitter.
struct DiskMax<'a> {
    terrain: &'a TerrainFile,
    radius_m: f64,
    stride: [i64; 2],
}

impl<'a> DiskMax<'a> {
    fn new(terrain: &'a TerrainFile, radius_m: f64) -> DiskMax<'a> {
        let [sx, sy] = terrain.header().spacing_m;
        let stride = |s: f64| ((2.0 * radius_m / s / DISK_SAMPLES_PER_SIDE).ceil() as i64).max(1);
        DiskMax { terrain, radius_m, stride: [stride(sx), stride(sy)] }
    }

    fn max_m(&self, p: DVec2) -> Result<f64> {
        let h = self.terrain.header();
        let [sx, sy] = h.spacing_m;
        let [x0, y0, x1, y1] = h.valid_window.map(i64::from);
        let [kx, ky] = self.stride;
        let r = self.radius_m;
        // Lattice indices whose posts can fall in the disk, limited to the valid window.
        let range = |c: f64, s: f64, k: i64, lo: i64, hi: i64| {
            // Window bounds are non-negative: the first lattice index at or after `lo` is ⌈lo/k⌉.
            let first = (((c - r) / s / k as f64).ceil() as i64).max((lo + k - 1) / k);
            let last = (((c + r) / s / k as f64).floor() as i64).min((hi - 1) / k);
            (first, last)
        };
        let (ix0, ix1) = range(p.x, sx, kx, x0, x1);
        let (iy0, iy1) = range(p.y, sy, ky, y0, y1);
        let mut best = ground_max_m(self.terrain, p.x, p.y)?.unwrap_or(f64::NEG_INFINITY);
        for iy in iy0..=iy1 {
            let y = iy * ky;
            let dy = y as f64 * sy - p.y;
            for ix in ix0..=ix1 {
                let x = ix * kx;
                let dx = x as f64 * sx - p.x;
                if dx * dx + dy * dy <= r * r {
                    best = best.max(f64::from(self.terrain.height_at(x as u32, y as u32)?));
                }
            }
        }
        Ok(best)
    }
}

/// `out[i]` = max of `v[i − w ..= i + w]` (clipped to the slice), in O(n) with a monotone deque.
fn running_max(v: &[f64], w: usize) -> Vec<f64> {
    let mut out = Vec::with_capacity(v.len());
    let mut window: VecDeque<usize> = VecDeque::new();
    let mut next = 0;
    for i in 0..v.len() {
        let hi = (i + w).min(v.len() - 1);
        while next <= hi {
            while window.back().is_some_and(|&b| v[b] <= v[next]) {
                window.pop_back();
            }
            window.push_back(next);
            next += 1;
        }
        while window.front().is_some_and(|&f| f + w < i) {
            window.pop_front();
        }
        // `i` itself has been pushed and is within the window, so the deque is not empty.
        out.push(window.front().map_or(v[i], |&f| v[f]));
    }
    out
}

/// `out[i]` = mean of `v[i − w ..= i + w]` (clipped to the slice).
fn moving_average(v: &[f64], w: usize) -> Vec<f64> {
    let mut prefix = Vec::with_capacity(v.len() + 1);
    prefix.push(0.0);
    for x in v {
        prefix.push(prefix[prefix.len() - 1] + x);
    }
    (0..v.len())
        .map(|i| {
            let (lo, hi) = (i.saturating_sub(w), (i + w).min(v.len() - 1));
            (prefix[hi + 1] - prefix[lo]) / (hi + 1 - lo) as f64
        })
        .collect()
}

/// Options of [`flyover`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlyoverOptions {
    /// Number of frames (at least 1).
    pub frames: usize,
    /// Least height of the eye above the highest terrain around it, metres; default
    /// [`FLYOVER_CLEARANCE_OF_DIAGONAL`] (2%) of the valid window's diagonal.
    pub clearance_m: Option<f64>,
}

impl FlyoverOptions {
    pub fn new(frames: usize) -> FlyoverOptions {
        FlyoverOptions { frames, clearance_m: None }
    }
}

/// A low-altitude straight fly-over of the valid window, south-west to north-east along its
/// diagonal, [`FLYOVER_INSET`] inside the corners; eyes are equally spaced in x/y.
///
/// Each eye's raw altitude is the highest terrain within [`FLYOVER_RADIUS_OF_DIAGONAL`] of the
/// diagonal (sampled, see `DiskMax`; always including the posts under the eye) plus the
/// clearance. The profile is then smoothed by a running max followed by a moving average over the
/// frames within the same radius. Every frame's window in the average holds only maxima over
/// windows that contain that frame, so the smoothed altitude is never below the frame's raw
/// altitude: the eye stays at least the clearance above the posts around it. The look point is
/// [`FLYOVER_LOOK_AHEAD_OF_DIAGONAL`] of the diagonal ahead, [`FLYOVER_PITCH_DEG`] below the
/// horizon.
pub fn flyover(terrain: &TerrainFile, opts: &FlyoverOptions) -> Result<FlightPath> {
    check_frames(opts.frames)?;
    check_positive_m("clearance", opts.clearance_m)?;
    let window = WindowM::of(terrain);
    let diagonal_m = window.diagonal_m();
    if diagonal_m <= 0.0 {
        return Err(Error::InvalidArgument(format!(
            "{}: the valid window is a single post; there is nothing to fly over",
            terrain.path().display()
        )));
    }
    let clearance_m = opts.clearance_m.unwrap_or(FLYOVER_CLEARANCE_OF_DIAGONAL * diagonal_m);
    let size = window.hi - window.lo;
    let start = window.lo + FLYOVER_INSET * size;
    let end = window.hi - FLYOVER_INSET * size;
    let n = opts.frames;
    let xy: Vec<DVec2> =
        (0..n).map(|k| if n == 1 { start } else { start + (end - start) * (k as f64 / (n - 1) as f64) }).collect();

    let radius_m = FLYOVER_RADIUS_OF_DIAGONAL * diagonal_m;
    let disk = DiskMax::new(terrain, radius_m);
    let raw = xy.iter().map(|&p| Ok(disk.max_m(p)? + clearance_m)).collect::<Result<Vec<f64>>>()?;
    let step_m = if n > 1 { (end - start).length() / (n - 1) as f64 } else { 0.0 };
    let half_window = if step_m > 0.0 { ((radius_m / step_m).ceil() as usize).min(n) } else { 0 };
    let smooth = moving_average(&running_max(&raw, half_window), half_window);

    let ahead = (end - start).normalize();
    let look_ahead_m = FLYOVER_LOOK_AHEAD_OF_DIAGONAL * diagonal_m;
    let drop_m = look_ahead_m * FLYOVER_PITCH_DEG.to_radians().tan();
    let frames = xy
        .iter()
        .zip(smooth.iter().zip(&raw))
        .map(|(&p, (&z_smooth, &z_raw))| {
            // The bound above holds exactly; the max only absorbs the prefix sums' rounding.
            let z = z_smooth.max(z_raw);
            let look = p + ahead * look_ahead_m;
            PathFrame { eye: [p.x, p.y, z], look: [look.x, look.y, z - drop_m] }
        })
        .collect();
    Ok(FlightPath { frames })
}

/// Options of [`orbit`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrbitOptions {
    /// Number of frames (at least 1), evenly spaced over one full turn.
    pub frames: usize,
    /// Horizontal distance from the valid window's centre, metres; default
    /// [`ORBIT_RADIUS_OF_HALF_DIAGONAL`] × half the diagonal.
    pub radius_m: Option<f64>,
    /// Eye height, metres; default `z_max` + [`ORBIT_ALTITUDE_OF_HALF_DIAGONAL`] × half the
    /// diagonal.
    pub altitude_m: Option<f64>,
}

impl OrbitOptions {
    pub fn new(frames: usize) -> OrbitOptions {
        OrbitOptions { frames, radius_m: None, altitude_m: None }
    }
}

/// A circle around the valid window's centre at constant altitude, counter-clockwise seen from
/// above, starting due east (angle 0) and ending at 2π(n − 1)/n, every frame looking at the
/// centre at the terrain's (bilinear) height there. An altitude that puts an eye at or below the
/// terrain under it is an [`Error::InvalidArgument`].
pub fn orbit(terrain: &TerrainFile, opts: &OrbitOptions) -> Result<FlightPath> {
    check_frames(opts.frames)?;
    check_positive_m("radius", opts.radius_m)?;
    if let Some(a) = opts.altitude_m {
        if !a.is_finite() {
            return Err(Error::out_of_range("altitude", "a finite number of metres", a));
        }
    }
    let window = WindowM::of(terrain);
    let half_diagonal_m = window.diagonal_m() / 2.0;
    let radius_m = opts.radius_m.unwrap_or(ORBIT_RADIUS_OF_HALF_DIAGONAL * half_diagonal_m);
    if radius_m <= 0.0 {
        return Err(Error::InvalidArgument(format!(
            "{}: the valid window is a single post; give the orbit a radius",
            terrain.path().display()
        )));
    }
    let altitude_m =
        opts.altitude_m.unwrap_or(terrain.header().z_max + ORBIT_ALTITUDE_OF_HALF_DIAGONAL * half_diagonal_m);
    let centre = window.centre();
    // The centre lies inside the grid, so there is always a height there; z_min is a fallback
    // that cannot be reached.
    let look_z = ground_bilinear_m(terrain, centre.x, centre.y)?.unwrap_or(terrain.header().z_min);
    let n = opts.frames;
    let mut frames = Vec::with_capacity(n);
    for k in 0..n {
        let angle = std::f64::consts::TAU * k as f64 / n as f64;
        let p = centre + radius_m * DVec2::new(angle.cos(), angle.sin());
        if let Some(ground) = ground_max_m(terrain, p.x, p.y)? {
            if altitude_m <= ground {
                return Err(Error::InvalidArgument(format!(
                    "orbit altitude {altitude_m} m is not above the terrain ({ground} m) under frame {k}"
                )));
            }
        }
        frames.push(PathFrame { eye: [p.x, p.y, altitude_m], look: [centre.x, centre.y, look_z] });
    }
    Ok(FlightPath { frames })
}

/// A bounding box seen with `up` as the up axis: horizontal coordinates along `e1`, `e2`.
struct BoxFrame {
    e1: DVec3,
    e2: DVec3,
    up: DVec3,
    centre: DVec3,
    diagonal_m: f64,
    /// Horizontal corners (e1, e2 coordinates).
    lo: DVec2,
    hi: DVec2,
    /// Highest coordinate along `up`.
    top: f64,
}

impl BoxFrame {
    fn new(bounds: &Bounds, up: UpAxis) -> Result<BoxFrame> {
        let (e1, e2, upv) = up.frame();
        let (min, max) = (DVec3::from(bounds.min), DVec3::from(bounds.max));
        if !(min.is_finite() && max.is_finite() && min.cmple(max).all()) {
            return Err(Error::InvalidArgument(format!("unusable bounding box {bounds:?}")));
        }
        let h = |p: DVec3| DVec2::new(p.dot(e1), p.dot(e2));
        Ok(BoxFrame {
            e1,
            e2,
            up: upv,
            centre: bounds.centre(),
            diagonal_m: bounds.diagonal(),
            lo: h(min),
            hi: h(max),
            top: max.dot(upv),
        })
    }

    /// The world point at horizontal position `p` and height `z` along up.
    fn point(&self, p: DVec2, z: f64) -> DVec3 {
        self.e1 * p.x + self.e2 * p.y + self.up * z
    }
}

/// [`orbit`] around a mesh's bounding box: a circle about the `up` axis through the box's centre,
/// counter-clockwise seen from above, starting along the frame's first horizontal axis
/// ([`UpAxis::frame`]; +x for z up), every frame looking at the centre. Radius (horizontal, from
/// the axis) defaults to [`ORBIT_BOX_RADIUS_OF_DIAGONAL`] of the box's diagonal and the eye height
/// (coordinate along `up`) to the centre's plus [`ORBIT_BOX_ALTITUDE_OF_DIAGONAL`] of the diagonal,
/// so by default every eye is outside the box.
pub fn orbit_box(bounds: &Bounds, up: UpAxis, opts: &OrbitOptions) -> Result<FlightPath> {
    check_frames(opts.frames)?;
    check_positive_m("radius", opts.radius_m)?;
    if let Some(a) = opts.altitude_m {
        if !a.is_finite() {
            return Err(Error::out_of_range("altitude", "a finite number", a));
        }
    }
    let b = BoxFrame::new(bounds, up)?;
    let radius_m = opts.radius_m.unwrap_or(ORBIT_BOX_RADIUS_OF_DIAGONAL * b.diagonal_m);
    if radius_m <= 0.0 {
        return Err(Error::InvalidArgument("the bounding box is a single point; give the orbit a radius".into()));
    }
    let altitude = opts.altitude_m.unwrap_or(b.centre.dot(b.up) + ORBIT_BOX_ALTITUDE_OF_DIAGONAL * b.diagonal_m);
    let centre_h = DVec2::new(b.centre.dot(b.e1), b.centre.dot(b.e2));
    let look = b.centre.to_array();
    let frames = (0..opts.frames)
        .map(|k| {
            let angle = std::f64::consts::TAU * k as f64 / opts.frames as f64;
            let p = centre_h + radius_m * DVec2::new(angle.cos(), angle.sin());
            PathFrame { eye: b.point(p, altitude).to_array(), look }
        })
        .collect();
    Ok(FlightPath { frames })
}

/// [`flyover`] over a mesh's bounding box: straight along the horizontal diagonal (about `up`),
/// [`FLYOVER_INSET`] inside its corners, at a constant height: the box's top plus the clearance
/// (default [`FLYOVER_CLEARANCE_OF_DIAGONAL`] of the box's diagonal), so every eye is above the
/// box. Looks [`FLYOVER_LOOK_AHEAD_OF_DIAGONAL`] of the diagonal ahead, [`FLYOVER_PITCH_DEG`]
/// below the horizon, as over a terrain.
pub fn flyover_box(bounds: &Bounds, up: UpAxis, opts: &FlyoverOptions) -> Result<FlightPath> {
    check_frames(opts.frames)?;
    check_positive_m("clearance", opts.clearance_m)?;
    let b = BoxFrame::new(bounds, up)?;
    let size = b.hi - b.lo;
    if size.length() <= 0.0 {
        return Err(Error::InvalidArgument(
            "the bounding box has no horizontal extent; there is nothing to fly across".into(),
        ));
    }
    let z = b.top + opts.clearance_m.unwrap_or(FLYOVER_CLEARANCE_OF_DIAGONAL * b.diagonal_m);
    let (start, end) = (b.lo + FLYOVER_INSET * size, b.hi - FLYOVER_INSET * size);
    let ahead = (end - start).normalize();
    let look_ahead = FLYOVER_LOOK_AHEAD_OF_DIAGONAL * b.diagonal_m;
    let drop = look_ahead * FLYOVER_PITCH_DEG.to_radians().tan();
    let n = opts.frames;
    let frames = (0..n)
        .map(|k| {
            let p = if n == 1 { start } else { start + (end - start) * (k as f64 / (n - 1) as f64) };
            PathFrame { eye: b.point(p, z).to_array(), look: b.point(p + ahead * look_ahead, z - drop).to_array() }
        })
        .collect();
    Ok(FlightPath { frames })
}

impl FlightPath {
    /// Frame count, length, and as `min_clearance_m` the least distance from an eye to `bounds`
    /// (0 for an eye inside): the [`PathSummary`] of a path around a mesh.
    pub fn summary_box(&self, bounds: &Bounds) -> PathSummary {
        let min_clearance_m = self.frames.iter().map(|f| bounds.distance_to(f.eye_in_world())).reduce(f64::min);
        PathSummary { frames: self.frames.len(), length_m: self.length_m(), min_clearance_m }
    }
}

/// What a path is made over or around: a terrain file, or a mesh's bounding box with its up axis
/// (a mesh file, a meta-node file or a page file).
pub enum PathSubject {
    Terrain(Box<TerrainFile>),
    Box(Bounds, UpAxis),
}

impl PathSubject {
    /// Opens `path`: a relief terrain file by its magic; a meta-node or page file by theirs (their
    /// boxes); anything else is read as a mesh. `up` is a mesh's up axis (default: guessed from
    /// its box, [`UpAxis::guess`]); a terrain's is z.
    pub fn open(path: &Path, up: Option<UpAxis>) -> Result<PathSubject> {
        use crate::format::{sniff, FileKind};
        let guess = |b: &Bounds| up.unwrap_or_else(|| UpAxis::guess(b.extent()));
        Ok(match sniff(path)? {
            Some(FileKind::Terrain) => {
                if up.is_some_and(|u| u != UpAxis::Z) {
                    return Err(Error::InvalidArgument(format!("{}: a terrain's up axis is z", path.display())));
                }
                PathSubject::Terrain(Box::new(TerrainFile::open(path)?))
            }
            Some(FileKind::Pages) => {
                let b = crate::format::pagefile::PageFile::open(path)?.header().bounds;
                PathSubject::Box(b, guess(&b))
            }
            Some(FileKind::MetaNode) => {
                let b = crate::format::metanode::MetaNodeFile::open(path)?.header().bounds;
                PathSubject::Box(b, guess(&b))
            }
            Some(FileKind::Imagery) => {
                return Err(Error::InvalidArgument(format!(
                    "{}: an imagery tile file has no terrain or mesh to fly over (drape it with --imagery)",
                    path.display()
                )))
            }
            Some(FileKind::Shard) => {
                return Err(Error::InvalidArgument(format!(
                    "{}: a conversion shard is not a terrain yet (merge the shards: relief convert --merge)",
                    path.display()
                )))
            }
            Some(FileKind::Vdt) | None => {
                let mesh = crate::mesh::read_mesh(path)?;
                let b = mesh.bounds().ok_or_else(|| Error::bad_mesh(path, "no vertices"))?;
                PathSubject::Box(b, guess(&b))
            }
        })
    }

    /// The up axis paths use.
    pub fn up(&self) -> UpAxis {
        match self {
            PathSubject::Terrain(_) => UpAxis::Z,
            PathSubject::Box(_, up) => *up,
        }
    }

    /// A low straight fly-over ([`flyover`], [`flyover_box`]).
    pub fn flyover(&self, opts: &FlyoverOptions) -> Result<FlightPath> {
        match self {
            PathSubject::Terrain(t) => flyover(t, opts),
            PathSubject::Box(b, up) => flyover_box(b, *up, opts),
        }
    }

    /// A circle around the centre ([`orbit`], [`orbit_box`]).
    pub fn orbit(&self, opts: &OrbitOptions) -> Result<FlightPath> {
        match self {
            PathSubject::Terrain(t) => orbit(t, opts),
            PathSubject::Box(b, up) => orbit_box(b, *up, opts),
        }
    }

    /// The path's summary: clearance above the terrain, or distance to the box.
    pub fn summary(&self, path: &FlightPath) -> Result<PathSummary> {
        match self {
            PathSubject::Terrain(t) => path.summary(t),
            PathSubject::Box(b, _) => Ok(path.summary_box(b)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn running_max_and_average_match_the_naive_ones() {
        let v: Vec<f64> = (0..57).map(|i| ((i * 37 % 23) as f64).sin() * 10.0 + i as f64 * 0.1).collect();
        for w in [0, 1, 2, 5, 56, 100] {
            let m = running_max(&v, w);
            let a = moving_average(&v, w);
            for i in 0..v.len() {
                let (lo, hi) = (i.saturating_sub(w), (i + w).min(v.len() - 1));
                let naive_max = v[lo..=hi].iter().copied().fold(f64::NEG_INFINITY, f64::max);
                let naive_mean = v[lo..=hi].iter().sum::<f64>() / (hi + 1 - lo) as f64;
                assert_eq!(m[i], naive_max, "w {w} i {i}");
                assert!((a[i] - naive_mean).abs() < 1e-9, "w {w} i {i}");
            }
        }
    }

    #[test]
    fn smoothing_never_lowers_a_frame() {
        let v: Vec<f64> = (0..200).map(|i| if i % 17 == 0 { 100.0 } else { (i % 5) as f64 }).collect();
        for w in [1, 3, 8] {
            let s = moving_average(&running_max(&v, w), w);
            assert!(s.iter().zip(&v).all(|(s, v)| s >= v), "w {w}");
        }
    }

    #[test]
    fn frame_errors_point_where_parsing_the_whole_file_does() {
        for text in [
            "[{\"eye\":[1,2,3]}]",
            "[\n  {\"eye\":[1,2,3],\"look\":[4,5,6]},\n  {\"eye\":[1,2,3],\n   \"look\":[4,5]}\n]",
            "[ {\"eye\":[1,2,3],\"look\":[4,5,6]}, {\"eye\":[1,2,1e999],\"look\":[4,5,6]} ]",
            "[{\"eye\":[1,2,3],\"lok\":[4,5,6]}]",
        ] {
            let whole = serde_json::from_str::<Vec<PathFrame>>(text).unwrap_err();
            let raw: Vec<&RawValue> = serde_json::from_str(text).unwrap();
            let e = raw.iter().find_map(|r| serde_json::from_str::<PathFrame>(r.get()).err().map(|e| (r, e))).unwrap();
            assert_eq!(at_file_position(text, e.0.get(), &e.1), whole.to_string(), "{text}");
        }
    }

    #[test]
    fn camera_falls_back_to_y_up_for_vertical_views() {
        let path = FlightPath {
            frames: vec![
                PathFrame { eye: [0.0, 0.0, 100.0], look: [0.0, 0.0, 0.0] },
                PathFrame { eye: [0.0, 0.0, 100.0], look: [50.0, 0.0, 90.0] },
            ],
        };
        assert_eq!(path.camera(0, 60.0, 64, 48).unwrap().up_in_world, DVec3::Y);
        assert_eq!(path.camera(1, 60.0, 64, 48).unwrap().up_in_world, DVec3::Z);
        assert!(path.camera(2, 60.0, 64, 48).is_err());
    }
}
