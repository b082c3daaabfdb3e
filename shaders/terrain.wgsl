// Terrain: strip vertices are grid posts; positions come from the resident heights, shading from
// the full-resolution heights at each fragment, so a coarse mesh still shades sharply.
// Owner: src/render/terrain.rs (uniform layout `FrameUniform`, pipelines). CPU reference of the
// fragment maths: src/render/shade.rs — keep the two in step.

struct Frame {
    // Clip space from eye-relative world space (world − eye, metres): projection × rotation.
    clip_from_rel: mat4x4<f32>,
    // Eye-relative world direction from clip space, for the sky.
    rel_from_clip: mat4x4<f32>,
    eye_in_world: vec4<f32>,
    // (spacing x, spacing y) metres per post, then (posts per side − 1, 0).
    world_from_grid: vec4<f32>,
    // Land ramp from z_land_lo to z_max; water below 0 m down to z_min (metres); fog distance (m).
    z_min: f32,
    z_land_lo: f32,
    z_max: f32,
    fog_distance_m: f32,
    sun_dir: vec4<f32>,
    // Heights texture tiling: posts per tile side, tiles per row, posts per side, flags.
    tile_posts: u32,
    tiles_per_row: u32,
    posts: u32,
    flags: u32,
    wire_colour: vec4<f32>,
    // The DEM's own posts (x0, y0, x1, y1), inclusive; the rest of the grid is padding.
    valid_window: vec4<f32>,
};

@group(0) @binding(0) var<uniform> frame: Frame;
@group(0) @binding(1) var heights: texture_2d_array<f32>;

// Height of post (x, y), metres; posts are clamped to the grid.
fn post_height(x: i32, y: i32) -> f32 {
    let last = i32(frame.posts) - 1;
    let px = u32(clamp(x, 0, last));
    let py = u32(clamp(y, 0, last));
    let tx = px / frame.tile_posts;
    let ty = py / frame.tile_posts;
    let layer = ty * frame.tiles_per_row + tx;
    let texel = vec2<u32>(px - tx * frame.tile_posts, py - ty * frame.tile_posts);
    return textureLoad(heights, texel, layer, 0).r;
}

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    // Grid position in posts (exact in f32 up to 2^24 posts).
    @location(0) grid: vec2<f32>,
    // Eye-relative world position, metres.
    @location(1) rel: vec3<f32>,
};

fn vertex_at(grid: vec2<u32>, z_m: f32, towards_eye: f32) -> VertexOut {
    let world = vec3<f32>(f32(grid.x) * frame.world_from_grid.x, f32(grid.y) * frame.world_from_grid.y, z_m);
    // Subtract in f32 before projecting: keeps precision near the eye on large terrains.
    let rel = (world - frame.eye_in_world.xyz) * towards_eye;
    var out: VertexOut;
    out.clip = frame.clip_from_rel * vec4<f32>(rel, 1.0);
    out.grid = vec2<f32>(grid);
    out.rel = rel;
    return out;
}

@vertex
fn vs_terrain(@location(0) grid: vec2<u32>) -> VertexOut {
    return vertex_at(grid, post_height(i32(grid.x), i32(grid.y)), 1.0);
}

// Geomorphing: the refinement thread sends the blended height of each strip vertex.
@vertex
fn vs_terrain_morph(@location(0) grid: vec2<u32>, @location(1) morph: vec2<f32>) -> VertexOut {
    return vertex_at(grid, morph.y, 1.0);
}

// Wireframe: the same vertices pulled 0.2% towards the eye so lines win the depth test.
@vertex
fn vs_wire(@location(0) grid: vec2<u32>) -> VertexOut {
    return vertex_at(grid, post_height(i32(grid.x), i32(grid.y)), 0.998);
}

@vertex
fn vs_wire_morph(@location(0) grid: vec2<u32>, @location(1) morph: vec2<f32>) -> VertexOut {
    return vertex_at(grid, morph.y, 0.998);
}

// Unit normal at post (x, y) from central differences (one-sided at the border).
fn post_normal(x: i32, y: i32) -> vec3<f32> {
    let last = i32(frame.posts) - 1;
    let x0 = max(x - 1, 0);
    let x1 = min(x + 1, last);
    let y0 = max(y - 1, 0);
    let y1 = min(y + 1, last);
    let dz_dx = (post_height(x1, y) - post_height(x0, y)) / (f32(x1 - x0) * frame.world_from_grid.x);
    let dz_dy = (post_height(x, y1) - post_height(x, y0)) / (f32(y1 - y0) * frame.world_from_grid.y);
    return normalize(vec3<f32>(-dz_dx, -dz_dy, 1.0));
}

struct Surface {
    height_m: f32,
    normal: vec3<f32>,
};

// Bilinear height and normal at a grid position: the full-resolution surface under the fragment.
fn surface_at(grid: vec2<f32>) -> Surface {
    let last = f32(frame.posts - 1u);
    let g = clamp(grid, vec2<f32>(0.0), vec2<f32>(last));
    let base = min(floor(g), vec2<f32>(last - 1.0));
    let f = g - base;
    let x = i32(base.x);
    let y = i32(base.y);
    let h = mix(
        mix(post_height(x, y), post_height(x + 1, y), f.x),
        mix(post_height(x, y + 1), post_height(x + 1, y + 1), f.x),
        f.y,
    );
    let n = mix(
        mix(post_normal(x, y), post_normal(x + 1, y), f.x),
        mix(post_normal(x, y + 1), post_normal(x + 1, y + 1), f.x),
        f.y,
    );
    var s: Surface;
    s.height_m = h;
    s.normal = normalize(n);
    return s;
}

// Hypsometric tints for land (low to high) and water (shallow to deep), linear RGB.
fn ramp(z_m: f32) -> vec3<f32> {
    if (z_m < 0.0) {
        let t = clamp(z_m / min(frame.z_min, -1.0), 0.0, 1.0);
        return mix(vec3<f32>(0.30, 0.55, 0.75), vec3<f32>(0.02, 0.07, 0.25), t);
    }
    let t = clamp((z_m - frame.z_land_lo) / max(frame.z_max - frame.z_land_lo, 1.0), 0.0, 1.0);
    if (t < 0.3) {
        return mix(vec3<f32>(0.13, 0.32, 0.10), vec3<f32>(0.45, 0.50, 0.22), t / 0.3);
    }
    if (t < 0.6) {
        return mix(vec3<f32>(0.45, 0.50, 0.22), vec3<f32>(0.42, 0.30, 0.17), (t - 0.3) / 0.3);
    }
    if (t < 0.85) {
        return mix(vec3<f32>(0.42, 0.30, 0.17), vec3<f32>(0.55, 0.53, 0.52), (t - 0.6) / 0.25);
    }
    return mix(vec3<f32>(0.55, 0.53, 0.52), vec3<f32>(0.95, 0.95, 0.97), (t - 0.85) / 0.15);
}

// Sky colour along an eye-relative direction: horizon haze to zenith blue.
fn sky(dir: vec3<f32>) -> vec3<f32> {
    let up = clamp(normalize(dir).z, -1.0, 1.0);
    let horizon = vec3<f32>(0.72, 0.80, 0.88);
    if (up < 0.0) {
        return mix(horizon, vec3<f32>(0.45, 0.50, 0.55), min(-up * 4.0, 1.0));
    }
    return mix(horizon, vec3<f32>(0.16, 0.34, 0.68), pow(up, 0.6));
}

// Lit, tinted, fogged colour of the surface seen along `rel` (linear RGB).
fn shade(s: Surface, rel: vec3<f32>) -> vec3<f32> {
    let lambert = max(dot(s.normal, frame.sun_dir.xyz), 0.0);
    let lit = ramp(s.height_m) * (0.30 + 0.70 * lambert);
    let d = length(rel) / frame.fog_distance_m;
    let fog = 1.0 - exp(-d * d);
    return mix(lit, sky(rel), fog);
}

// Padding replicates the DEM's edges out to the 2^n + 1 grid: not terrain, so not drawn.
fn outside_dem(grid: vec2<f32>) -> bool {
    return any(grid < frame.valid_window.xy) || any(grid > frame.valid_window.zw);
}

@fragment
fn fs_terrain(in: VertexOut) -> @location(0) vec4<f32> {
    if (outside_dem(in.grid)) {
        discard;
    }
    return vec4<f32>(shade(surface_at(in.grid), in.rel), 1.0);
}

@fragment
fn fs_wire(in: VertexOut) -> @location(0) vec4<f32> {
    if (outside_dem(in.grid)) {
        discard;
    }
    return frame.wire_colour;
}

// What fs_terrain computes, written out for the CPU reference test (src/render/shade.rs): the
// position always, then the normal (flags = 1) or the colour (flags = 2); two targets keep within
// the 32 bytes per sample every adapter allows.
struct Probe {
    @location(0) position: vec4<f32>,
    @location(1) value: vec4<f32>,
};

@fragment
fn fs_probe(in: VertexOut) -> Probe {
    if (outside_dem(in.grid)) {
        discard;
    }
    let s = surface_at(in.grid);
    var out: Probe;
    out.position = vec4<f32>(in.grid, s.height_m, in.rel.z + frame.eye_in_world.z);
    if (frame.flags == 1u) {
        out.value = vec4<f32>(s.normal, 1.0);
    } else {
        out.value = vec4<f32>(shade(s, in.rel), 1.0);
    }
    return out;
}

// Overlay lines in world space (the frozen view's frustum), drawn over everything.
@vertex
fn vs_overlay(@location(0) world: vec3<f32>) -> @builtin(position) vec4<f32> {
    return frame.clip_from_rel * vec4<f32>(world - frame.eye_in_world.xyz, 1.0);
}

@fragment
fn fs_overlay() -> @location(0) vec4<f32> {
    return vec4<f32>(0.95, 0.15, 0.1, 1.0);
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
