//! The disk-page k-d tree (Sajadi et al. 2009, §4; J. L. Bentley, "Multidimensional binary
//! search trees used for associative searching", CACM 18(9), 1975) and the page culling of the
//! per-frame fetch (§5): a k-d tree whose primitives are the pages' bounding boxes and whose
//! leaves name page numbers.
//!
//! Each node splits at the median of its pages' box centres along the longest side of their
//! union; a page goes to every child whose side of the plane its box reaches, so a page can be
//! named by several leaves (the query de-duplicates). Every node also stores the union of its
//! pages' boxes: the frustum test of a node is then conservative for every page below it (a box
//! that contains a page's box passes whenever the page's box passes), which makes the query find
//! exactly the pages whose own box passes — what the brute force over all pages finds.
//!
//! The frustum is the camera's planes through the eye ([`crate::camera::Camera::frustum_normals`],
//! no far plane). A box is outside when all of it is behind one plane (its corner farthest along
//! the plane's normal is behind). A page is back-facing, and culled, when its normal cone
//! (axis, half-angle) and its box's bounding sphere put every triangle's normal more than 90°
//! from the direction towards the eye.

use glam::DVec3;

use crate::camera::PLANES;

pub use crate::format::pagefile::{KdNode, PageBounds, LEAF};

/// A node with at most this many pages is a leaf.
pub const LEAF_PAGES: usize = 4;
/// Depth limit (boxes that overlap a lot cannot be separated by any plane).
pub const MAX_DEPTH: u32 = 40;

/// Builds the tree over page boxes `(min, max)`: the nodes (root first) and the leaves' page
/// number list.
pub fn build_kdtree(boxes: &[([f32; 3], [f32; 3])]) -> (Vec<KdNode>, Vec<u32>) {
    let mut nodes = Vec::new();
    let mut refs = Vec::new();
    let all: Vec<u32> = (0..boxes.len() as u32).collect();
    if !boxes.is_empty() {
        build_node(boxes, all, 0, &mut nodes, &mut refs);
    }
    (nodes, refs)
}

fn build_node(
    boxes: &[([f32; 3], [f32; 3])],
    pages: Vec<u32>,
    depth: u32,
    nodes: &mut Vec<KdNode>,
    refs: &mut Vec<u32>,
) -> u32 {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for &p in &pages {
        let (a, b) = boxes[p as usize];
        for k in 0..3 {
            lo[k] = lo[k].min(a[k]);
            hi[k] = hi[k].max(b[k]);
        }
    }
    let at = nodes.len() as u32;
    nodes.push(KdNode { box_min: lo, box_max: hi, ..KdNode::default() });
    let leaf = |nodes: &mut Vec<KdNode>, refs: &mut Vec<u32>, pages: &[u32]| {
        let n = &mut nodes[at as usize];
        n.axis = LEAF;
        n.a = refs.len() as u32;
        n.b = pages.len() as u32;
        refs.extend_from_slice(pages);
        at
    };
    if pages.len() <= LEAF_PAGES || depth >= MAX_DEPTH {
        return leaf(nodes, refs, &pages);
    }
    let axis = (0..3).max_by(|&x, &y| (hi[x] - lo[x]).total_cmp(&(hi[y] - lo[y]))).unwrap_or(0);
    let mut centres: Vec<f32> =
        pages.iter().map(|&p| 0.5 * (boxes[p as usize].0[axis] + boxes[p as usize].1[axis])).collect();
    let mid = centres.len() / 2;
    let split = *centres.select_nth_unstable_by(mid, f32::total_cmp).1;
    let left: Vec<u32> = pages.iter().copied().filter(|&p| boxes[p as usize].0[axis] <= split).collect();
    let right: Vec<u32> = pages.iter().copied().filter(|&p| boxes[p as usize].1[axis] > split).collect();
    // A split that does not shrink both sides cannot separate these boxes.
    if left.len() == pages.len() || right.len() == pages.len() {
        return leaf(nodes, refs, &pages);
    }
    drop(pages);
    let l = build_node(boxes, left, depth + 1, nodes, refs);
    let r = build_node(boxes, right, depth + 1, nodes, refs);
    let n = &mut nodes[at as usize];
    n.axis = axis as u32;
    n.split = split;
    n.a = l;
    n.b = r;
    at
}

/// Whether the box is not entirely behind any of the frustum's planes through `eye_in_world`.
pub fn box_in_frustum(box_min: [f32; 3], box_max: [f32; 3], eye_in_world: DVec3, planes: &[DVec3; PLANES]) -> bool {
    planes.iter().all(|n| {
        // The corner farthest along n.
        let far = DVec3::new(
            if n.x >= 0.0 { box_max[0] } else { box_min[0] } as f64,
            if n.y >= 0.0 { box_max[1] } else { box_min[1] } as f64,
            if n.z >= 0.0 { box_max[2] } else { box_min[2] } as f64,
        );
        n.dot(far - eye_in_world) >= 0.0
    })
}

/// Whether every triangle of the page faces away from `eye_in_world` (conservatively): the
/// angle between the cone's axis and the direction from the box's centre to the eye, less the
/// cone's half-angle and the angle the box's bounding sphere subtends, still exceeds 90°.
pub fn back_facing(page: &PageBounds, eye_in_world: DVec3) -> bool {
    // A cone of 90° or more (or NaN) holds normals facing every way the eye could be.
    if page.cone_half_angle_rad.is_nan() || page.cone_half_angle_rad >= std::f32::consts::FRAC_PI_2 {
        return false;
    }
    let lo = DVec3::from(page.box_min.map(f64::from));
    let hi = DVec3::from(page.box_max.map(f64::from));
    let centre = (lo + hi) / 2.0;
    let radius = (hi - lo).length() / 2.0;
    let to_eye = eye_in_world - centre;
    let d = to_eye.length();
    if d <= radius {
        return false;
    }
    let axis = DVec3::from(page.cone_axis.map(f64::from));
    let cos = (axis.dot(to_eye) / (axis.length() * d)).clamp(-1.0, 1.0);
    let spread = page.cone_half_angle_rad as f64 + (radius / d).asin();
    cos.acos() - spread > std::f64::consts::FRAC_PI_2
}

/// The page numbers in the leaves whose node boxes pass the frustum test, each once, ascending,
/// into `out` (cleared first). `stack` is scratch kept by the caller (no allocation per frame).
pub fn query_frustum(
    nodes: &[KdNode],
    refs: &[u32],
    eye_in_world: DVec3,
    planes: &[DVec3; PLANES],
    out: &mut Vec<u32>,
    stack: &mut Vec<u32>,
) {
    out.clear();
    stack.clear();
    if nodes.is_empty() {
        return;
    }
    stack.push(0);
    while let Some(i) = stack.pop() {
        let n = &nodes[i as usize];
        if !box_in_frustum(n.box_min, n.box_max, eye_in_world, planes) {
            continue;
        }
        if n.axis == LEAF {
            out.extend_from_slice(&refs[n.a as usize..(n.a + n.b) as usize]);
        } else {
            stack.push(n.b);
            stack.push(n.a);
        }
    }
    out.sort_unstable();
    out.dedup();
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;

    fn lcg(s: &mut u64) -> f32 {
        *s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (*s >> 40) as f32 / (1u64 << 24) as f32
    }

    #[test]
    fn query_equals_brute_force_on_random_boxes_and_views() {
        let mut s = 7u64;
        let boxes: Vec<([f32; 3], [f32; 3])> = (0..700)
            .map(|_| {
                let c = [lcg(&mut s) * 10.0, lcg(&mut s) * 10.0, lcg(&mut s) * 3.0];
                let h = [lcg(&mut s), lcg(&mut s), lcg(&mut s) * 0.2];
                ([c[0] - h[0], c[1] - h[1], c[2] - h[2]], [c[0] + h[0], c[1] + h[1], c[2] + h[2]])
            })
            .collect();
        let (nodes, refs) = build_kdtree(&boxes);
        assert!(nodes.len() > 100, "a real tree: {} nodes", nodes.len());
        let (mut out, mut stack) = (Vec::new(), Vec::new());
        let mut seen_some = 0;
        for _ in 0..300 {
            let eye =
                DVec3::new(lcg(&mut s) as f64 * 16.0 - 3.0, lcg(&mut s) as f64 * 16.0 - 3.0, lcg(&mut s) as f64 * 8.0);
            let look = DVec3::new(lcg(&mut s) as f64 * 10.0, lcg(&mut s) as f64 * 10.0, lcg(&mut s) as f64);
            let Ok(cam) = Camera::new(eye, look, DVec3::Z, 20.0 + 100.0 * lcg(&mut s) as f64, 640, 360) else {
                continue;
            };
            let planes = cam.frustum_normals();
            query_frustum(&nodes, &refs, eye, &planes, &mut out, &mut stack);
            let kd: Vec<u32> = out
                .iter()
                .copied()
                .filter(|&p| box_in_frustum(boxes[p as usize].0, boxes[p as usize].1, eye, &planes))
                .collect();
            let brute: Vec<u32> = (0..boxes.len() as u32)
                .filter(|&p| box_in_frustum(boxes[p as usize].0, boxes[p as usize].1, eye, &planes))
                .collect();
            assert_eq!(kd, brute);
            seen_some += usize::from(!brute.is_empty() && brute.len() < boxes.len());
        }
        assert!(seen_some > 50, "views cut the set: {seen_some}");
    }

    #[test]
    fn normal_cones_cull_only_pages_facing_away() {
        let page = PageBounds {
            box_min: [-1.0, -1.0, -0.1],
            box_max: [1.0, 1.0, 0.1],
            cone_axis: [0.0, 0.0, 1.0],
            cone_half_angle_rad: 0.3,
        };
        assert!(!back_facing(&page, DVec3::new(0.0, 0.0, 10.0)), "seen from above");
        assert!(back_facing(&page, DVec3::new(0.0, 0.0, -10.0)), "seen from below");
        assert!(!back_facing(&page, DVec3::new(10.0, 0.0, -1.0)), "grazing: some triangle may face the eye");
        assert!(!back_facing(&page, DVec3::new(0.0, 0.0, -0.5)), "eye inside the bounding sphere");
        let wide = PageBounds { cone_half_angle_rad: std::f32::consts::PI, ..page };
        assert!(!back_facing(&wide, DVec3::new(0.0, 0.0, -10.0)));
    }
}
