// General triangle meshes: a non-indexed triangle list, three positions per triangle relative to
// the upload's origin. Flat shading from the face normal, which the fragment shader takes from
// screen-space derivatives of the eye-relative position (no normals uploaded: 12 bytes a vertex).
// Owner: src/render/mesh.rs (uniform layout `MeshFrameUniform`, pipelines). CPU reference of the
// fragment maths: src/render/mesh_shade.rs — keep the two in step.

struct Frame {
    // Clip space from eye-relative world space (world − eye): projection × rotation.
    clip_from_rel: mat4x4<f32>,
    // Eye-relative world direction from clip space, for the sky.
    rel_from_clip: mat4x4<f32>,
    // Eye − the upload's origin (computed in f64, then rounded): vertices are origin-relative.
    eye_from_origin: vec4<f32>,
    // Unit vector up (the sky's zenith) and unit vector towards the sun.
    zenith: vec4<f32>,
    sun_dir: vec4<f32>,
    // Linear RGB of front (counter-clockwise) and back faces; back faces show through holes.
    front_albedo: vec4<f32>,
    back_albedo: vec4<f32>,
    wire_colour: vec4<f32>,
    // Weights of the ambient, headlight and sun terms.
    light: vec4<f32>,
    // Distance at which fog reaches 1 − 1/e, world units.
    fog_distance_m: f32,
    // Bit 0: wireframe.
    flags: u32,
    pad0: u32,
    pad1: u32,
};

@group(0) @binding(0) var<uniform> frame: Frame;

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    // Eye-relative world position.
    @location(0) rel: vec3<f32>,
    // Barycentric coordinates (the corner's unit vector), for the wireframe.
    @location(1) bary: vec3<f32>,
};

@vertex
fn vs_mesh(@builtin(vertex_index) i: u32, @location(0) local: vec3<f32>) -> VertexOut {
    // Both operands are small near the eye (origin-relative), so the difference keeps precision
    // on meshes whose world coordinates are large.
    let rel = local - frame.eye_from_origin.xyz;
    let corner = i % 3u;
    var out: VertexOut;
    out.clip = frame.clip_from_rel * vec4<f32>(rel, 1.0);
    out.rel = rel;
    out.bary = vec3<f32>(f32(corner == 0u), f32(corner == 1u), f32(corner == 2u));
    return out;
}

// Sky colour along an eye-relative direction: horizon haze to zenith blue (as the terrain's, about
// `frame.zenith`).
fn sky(dir: vec3<f32>) -> vec3<f32> {
    let up = clamp(dot(normalize(dir), frame.zenith.xyz), -1.0, 1.0);
    let horizon = vec3<f32>(0.72, 0.80, 0.88);
    if (up < 0.0) {
        return mix(horizon, vec3<f32>(0.45, 0.50, 0.55), min(-up * 4.0, 1.0));
    }
    return mix(horizon, vec3<f32>(0.16, 0.34, 0.68), pow(up, 0.6));
}

// The face's unit normal turned towards the eye (two-sided lighting). The derivatives of the
// interpolated position lie in the triangle's plane for every pixel of the 2×2 quad, helpers
// included, so this is the face normal whatever the triangle's size on screen.
fn face_normal(rel: vec3<f32>) -> vec3<f32> {
    let n = normalize(cross(dpdx(rel), dpdy(rel)));
    return select(n, -n, dot(n, rel) > 0.0);
}

// Lit, fogged colour of a face with normal `n` (towards the eye) seen along `rel` (linear RGB).
fn shade(n: vec3<f32>, rel: vec3<f32>, front: bool) -> vec3<f32> {
    let albedo = select(frame.back_albedo.rgb, frame.front_albedo.rgb, front);
    let headlight = max(dot(n, -normalize(rel)), 0.0);
    let sun = max(dot(n, frame.sun_dir.xyz), 0.0);
    let lit = albedo * (frame.light.x + frame.light.y * headlight + frame.light.z * sun);
    let d = length(rel) / frame.fog_distance_m;
    let fog = 1.0 - exp(-d * d);
    return mix(lit, sky(rel), fog);
}

@fragment
fn fs_mesh(in: VertexOut, @builtin(front_facing) front: bool) -> @location(0) vec4<f32> {
    // Derivatives first, in uniform control flow.
    let n = face_normal(in.rel);
    let width = fwidth(in.bary);
    var c = shade(n, in.rel, front);
    if ((frame.flags & 1u) != 0u) {
        // Edges about one pixel wide: the distance to the nearest edge in pixels.
        let w = max(width, vec3<f32>(1e-6));
        let px = in.bary / w;
        let line = 1.0 - clamp(min(px.x, min(px.y, px.z)) - 0.5, 0.0, 1.0);
        // Triangles a few pixels across would be all edge: fade their lines (down to a tint that
        // still shows the density) by the triangle's smallest height in pixels, 1 / max(width).
        let height_px = 1.0 / max(w.x, max(w.y, w.z));
        let strength = clamp((height_px - 1.0) / 5.0, 0.15, 1.0);
        c = mix(c, frame.wire_colour.rgb, line * strength);
    }
    return vec4<f32>(c, 1.0);
}

// Sky: one triangle covering the screen at the far plane (depth 0 with reversed z).
struct SkyOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) ndc: vec2<f32>,
};

@vertex
fn vs_sky(@builtin(vertex_index) i: u32) -> SkyOut {
    let ndc = vec2<f32>(f32((i << 1u) & 2u) * 2.0 - 1.0, f32(i & 2u) * 2.0 - 1.0);
    var out: SkyOut;
    out.clip = vec4<f32>(ndc, 0.0, 1.0);
    out.ndc = ndc;
    return out;
}

@fragment
fn fs_sky(in: SkyOut) -> @location(0) vec4<f32> {
    let p = frame.rel_from_clip * vec4<f32>(in.ndc, 0.5, 1.0);
    return vec4<f32>(sky(p.xyz / p.w), 1.0);
}
