// Terrain: strip vertices are grid posts; positions come from the resident heights (or from the
// strip itself, which then carries them), shading from the full-resolution heights at each
// fragment (or the finest the height cache holds there), so a coarse mesh still shades sharply.
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
    // The height cache: (1 when heights come from it, else 0; tile cells per side T; levels; 0).
    cache: vec4<u32>,
    // Nodata: (style: 0 drawn as the filled heights, 1 not drawn, 2 shaded as water; 1 when the
    // void mask below is the file's; 0; 0).
    nodata: vec4<u32>,
    // The look (src/render/shade.rs, `Look`): (vertical exaggeration, ramp: 0 hypsometric,
    // 1 viridis, 2 grey; 0; 0).
    looks: vec4<f32>,
    // Imagery (src/render/imagery.rs): texture coordinates of grid posts, u = x + y·gx and
    // v = z + w·gy; then (1 when an image is draped, how much the hillshade lights it, 1 when u
    // wraps around the world, 1 when it is paged through the imagery cache); then, paged, the
    // image's level-0 width and height (texels), tile texels T and levels.
    imagery_uv: vec4<f32>,
    imagery: vec4<f32>,
    imagery_pages: vec4<f32>,
};

@group(0) @binding(0) var<uniform> frame: Frame;
// The whole grid in tiles (resident), or the cache's pool of slots, one per layer.
@group(0) @binding(1) var heights: texture_2d_array<f32>;
// The cache's table (src/core/heightcache.rs): per level its first entry (0..16) and tiles per
// side (16..32), then one entry per tile: 0 when absent, else slot + 1 | fade << 24.
@group(0) @binding(2) var<storage, read> cache_table: array<u32>;
// The terrain file's void mask: a bit per post of the valid window, rows from the south, least
// significant bit first (src/core/format/terrain.rs, `VoidMask`).
@group(0) @binding(3) var<storage, read> void_mask: array<u32>;
// The draped image (sRGB): whole, as layer 0 with its mip levels (one texel when there is none),
// or paged, the imagery cache's pool of slots (one tile and its one-texel border per layer).
@group(0) @binding(4) var imagery_texture: texture_2d_array<f32>;
@group(0) @binding(5) var imagery_sampler: sampler;
// The imagery cache's table, laid out as `cache_table` over the image's levels (tiles per row at
// 16..32); a small unused buffer when the image is whole.
@group(0) @binding(6) var<storage, read> imagery_table: array<u32>;

// Paged imagery: the level-k tile under level-0 texel coordinate p0 (its table entry) and p0's
// position in that tile's slot (0..1 over the slot's T + 2 texels).
struct ImageTile {
    entry: u32,
    st: vec2<f32>,
};

fn image_tile(p0: vec2<f32>, k: u32) -> ImageTile {
    let size = vec2<u32>(frame.imagery_pages.xy);
    let level_size = (size + vec2<u32>((1u << k) - 1u)) >> vec2<u32>(k);
    let t = u32(frame.imagery_pages.z);
    let pk = clamp(p0 / f32(1u << k), vec2<f32>(0.0), vec2<f32>(level_size));
    let cell = min(vec2<u32>(floor(pk)), level_size - vec2<u32>(1u));
    let tile = cell / t;
    var r: ImageTile;
    r.entry = imagery_table[32u + imagery_table[k] + tile.y * imagery_table[16u + k] + tile.x];
    r.st = (pk - vec2<f32>(tile * t) + vec2<f32>(1.0)) / f32(t + 2u);
    return r;
}

// The finest resident tile at or above level k (the coarsest is always resident), sampled.
struct ImageSample {
    level: u32,
    fade: f32,
    rgb: vec3<f32>,
};

fn image_sample(p0: vec2<f32>, k0: u32) -> ImageSample {
    let levels = u32(frame.imagery_pages.w);
    var k = k0;
    var t = image_tile(p0, k);
    loop {
        if (t.entry != 0u || k + 1u >= levels) {
            break;
        }
        k = k + 1u;
        t = image_tile(p0, k);
    }
    var r: ImageSample;
    r.level = k;
    r.fade = f32(t.entry >> 24u) / 255.0;
    let slot = max(i32(t.entry & 0xffffffu) - 1, 0);
    r.rgb = textureSampleLevel(imagery_texture, imagery_sampler, t.st, slot, 0.0).rgb;
    return r;
}

// Paged imagery at level-0 texel p0, `lod` the log2 of level-0 texels per pixel: trilinear
// between the levels around `lod` (as the whole image's mip-mapped sampler is), from the finest
// resident tiles at or above them, a new tile fading in over the next coarser one.
fn paged_imagery(p0: vec2<f32>, lod: f32) -> vec3<f32> {
    let levels = u32(frame.imagery_pages.w);
    let l = clamp(lod, 0.0, f32(levels - 1u));
    let k = u32(floor(l));
    let fine = image_sample(p0, k);
    var w = fine.fade;
    if (fine.level == k) {
        w = w * (1.0 - (l - floor(l)));
    }
    if (w >= 1.0 || fine.level + 1u >= levels) {
        return fine.rgb;
    }
    let coarse = image_sample(p0, fine.level + 1u);
    return mix(coarse.rgb, fine.rgb, w);
}

// The draped image's colour at a grid position (linear RGB) and 1 where it covers it, else 0.
// Called first in the fragment entry points, in uniform control flow (implicit mip level and
// derivatives).
fn imagery_at(grid: vec2<f32>) -> vec4<f32> {
    let uv = vec2<f32>(frame.imagery_uv.x + frame.imagery_uv.y * grid.x, frame.imagery_uv.z + frame.imagery_uv.w * grid.y);
    var c = textureSample(imagery_texture, imagery_sampler, uv, 0).rgb;
    let p0 = uv * frame.imagery_pages.xy;
    let lod = log2(max(length(dpdx(p0)), length(dpdy(p0))));
    if (frame.imagery.w > 0.5) {
        var u = uv.x;
        if (frame.imagery.z > 0.5) {
            u = fract(u);
        }
        c = paged_imagery(vec2<f32>(u, uv.y) * frame.imagery_pages.xy, lod);
    }
    let inside_u = frame.imagery.z > 0.5 || (uv.x >= 0.0 && uv.x <= 1.0);
    let inside = inside_u && uv.y >= 0.0 && uv.y <= 1.0;
    return vec4<f32>(c, select(0.0, frame.imagery.x, inside));
}

// Whether post (x, y) was nodata in the DEM (padding and posts outside the grid are not).
fn post_is_void(x: i32, y: i32) -> bool {
    if (frame.nodata.y == 0u) {
        return false;
    }
    let lo = vec2<i32>(frame.valid_window.xy);
    let hi = vec2<i32>(frame.valid_window.zw);
    if (x < lo.x || y < lo.y || x > hi.x || y > hi.y) {
        return false;
    }
    let i = u32(y - lo.y) * u32(hi.x - lo.x + 1) + u32(x - lo.x);
    return ((void_mask[i >> 5u] >> (i & 31u)) & 1u) == 1u;
}

// Whether the post nearest a grid position was nodata: a void post owns the square of half a
// spacing around it.
fn void_at(grid: vec2<f32>) -> bool {
    let p = vec2<i32>(floor(grid + vec2<f32>(0.5)));
    return post_is_void(p.x, p.y);
}

// Where a surface reads its posts: level `level` (every 2^level-th post), from the resident grid
// (slot < 0) or from a cache slot whose texel (0, 0) is level post `origin`.
struct Src {
    level: u32,
    slot: i32,
    origin: vec2<i32>,
};

fn resident() -> Src {
    var s: Src;
    s.level = 0u;
    s.slot = -1;
    s.origin = vec2<i32>(0, 0);
    return s;
}

// The last post index of the source's level.
fn last_post(src: Src) -> i32 {
    return i32((frame.posts - 1u) >> src.level);
}

// Height of post (x, y) of the source's level, metres; posts are clamped to the grid.
fn post_height(src: Src, x: i32, y: i32) -> f32 {
    let last = last_post(src);
    let cx = clamp(x, 0, last);
    let cy = clamp(y, 0, last);
    if (src.slot >= 0) {
        return textureLoad(heights, vec2<i32>(cx, cy) - src.origin, src.slot, 0).r;
    }
    let px = u32(cx);
    let py = u32(cy);
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
    let world = vec3<f32>(
        f32(grid.x) * frame.world_from_grid.x,
        f32(grid.y) * frame.world_from_grid.y,
        z_m * frame.looks.x,
    );
    // Subtract in f32 before projecting: keeps precision near the eye on large terrains.
    let rel = (world - frame.eye_in_world.xyz) * towards_eye;
    var out: VertexOut;
    out.clip = frame.clip_from_rel * vec4<f32>(rel, 1.0);
    out.grid = vec2<f32>(grid);
    out.rel = rel;
    return out;
}

// Heights from the resident grid (with the cache, strips always carry their heights).
@vertex
fn vs_terrain(@location(0) grid: vec2<u32>) -> VertexOut {
    return vertex_at(grid, post_height(resident(), i32(grid.x), i32(grid.y)), 1.0);
}

// Geomorphing: the refinement thread sends the blended height of each strip vertex.
@vertex
fn vs_terrain_morph(@location(0) grid: vec2<u32>, @location(1) morph: vec2<f32>) -> VertexOut {
    return vertex_at(grid, morph.y, 1.0);
}

// Wireframe: the same vertices pulled 0.2% towards the eye so lines win the depth test.
@vertex
fn vs_wire(@location(0) grid: vec2<u32>) -> VertexOut {
    return vertex_at(grid, post_height(resident(), i32(grid.x), i32(grid.y)), 0.998);
}

@vertex
fn vs_wire_morph(@location(0) grid: vec2<u32>, @location(1) morph: vec2<f32>) -> VertexOut {
    return vertex_at(grid, morph.y, 0.998);
}

// Unit normal at post (x, y) of the source's level from central differences (one-sided at the
// border).
fn post_normal(src: Src, x: i32, y: i32) -> vec3<f32> {
    let last = last_post(src);
    let x0 = max(x - 1, 0);
    let x1 = min(x + 1, last);
    let y0 = max(y - 1, 0);
    let y1 = min(y + 1, last);
    let step = f32(1u << src.level);
    // Of the exaggerated surface: slopes scale with the heights.
    let dz_dx = frame.looks.x * (post_height(src, x1, y) - post_height(src, x0, y)) / (f32(x1 - x0) * step * frame.world_from_grid.x);
    let dz_dy = frame.looks.x * (post_height(src, x, y1) - post_height(src, x, y0)) / (f32(y1 - y0) * step * frame.world_from_grid.y);
    return normalize(vec3<f32>(-dz_dx, -dz_dy, 1.0));
}

struct Surface {
    height_m: f32,
    normal: vec3<f32>,
};

// The source's level's cell under a grid position (level-0 posts): its lower-left post.
fn cell_at(src: Src, grid: vec2<f32>) -> vec2<f32> {
    let last = f32(last_post(src));
    let g = clamp(grid / f32(1u << src.level), vec2<f32>(0.0), vec2<f32>(last));
    return min(floor(g), vec2<f32>(last - 1.0));
}

// Bilinear height and normal at a grid position from the source's posts: the full-resolution
// surface under the fragment when the source is level 0.
fn surface_at(src: Src, grid: vec2<f32>) -> Surface {
    let last = f32(last_post(src));
    let g = clamp(grid / f32(1u << src.level), vec2<f32>(0.0), vec2<f32>(last));
    let base = min(floor(g), vec2<f32>(last - 1.0));
    let f = g - base;
    let x = i32(base.x);
    let y = i32(base.y);
    let h = mix(
        mix(post_height(src, x, y), post_height(src, x + 1, y), f.x),
        mix(post_height(src, x, y + 1), post_height(src, x + 1, y + 1), f.x),
        f.y,
    );
    let n = mix(
        mix(post_normal(src, x, y), post_normal(src, x + 1, y), f.x),
        mix(post_normal(src, x, y + 1), post_normal(src, x + 1, y + 1), f.x),
        f.y,
    );
    var s: Surface;
    s.height_m = h;
    s.normal = normalize(n);
    return s;
}

// The cached tile of level k under a grid position: its source and its table entry.
struct Cached {
    src: Src,
    entry: u32,
};

fn cached_at(grid: vec2<f32>, k: u32) -> Cached {
    var c: Cached;
    c.src.level = k;
    let t = i32(frame.cache.y);
    let tile = vec2<i32>(cell_at(c.src, grid)) / t;
    c.entry = cache_table[32u + cache_table[k] + u32(tile.y) * cache_table[16u + k] + u32(tile.x)];
    c.src.slot = i32(c.entry & 0xffffffu) - 1;
    c.src.origin = tile * t - vec2<i32>(1, 1);
    return c;
}

// The finest resident level at or above level k (the coarsest is always resident).
fn finest_cached(grid: vec2<f32>, k: u32) -> Cached {
    let levels = frame.cache.z;
    var level = k;
    var c = cached_at(grid, level);
    loop {
        if (c.entry != 0u || level + 1u >= levels) {
            break;
        }
        level = level + 1u;
        c = cached_at(grid, level);
    }
    // Slot 0 holds the coarsest tile; an absent entry there cannot happen, but stay in bounds.
    c.src.slot = max(c.src.slot, 0);
    return c;
}

// The surface under a fragment: the resident grid, or the finest cached level, blended with the
// next coarser one while it fades in (so a tile's arrival is not a pop).
fn surface(grid: vec2<f32>) -> Surface {
    if (frame.cache.x == 0u) {
        return surface_at(resident(), grid);
    }
    let fine = finest_cached(grid, 0u);
    var s = surface_at(fine.src, grid);
    let fade = f32(fine.entry >> 24u) / 255.0;
    if (fade < 1.0 && fine.src.level + 1u < frame.cache.z) {
        let coarse = finest_cached(grid, fine.src.level + 1u);
        let c = surface_at(coarse.src, grid);
        s.height_m = mix(c.height_m, s.height_m, fade);
        s.normal = normalize(mix(c.normal, s.normal, fade));
    }
    return s;
}

// Viridis at 9 stops, linear RGB (the CPU reference's `VIRIDIS`).
fn viridis(t: f32) -> vec3<f32> {
    var stops = array<vec3<f32>, 9>(
        vec3<f32>(0.057805, 0.000304, 0.088656),
        vec3<f32>(0.064803, 0.021219, 0.187821),
        vec3<f32>(0.048172, 0.066626, 0.250158),
        vec3<f32>(0.030713, 0.138432, 0.270498),
        vec3<f32>(0.019382, 0.223228, 0.270498),
        vec3<f32>(0.013702, 0.341914, 0.250158),
        vec3<f32>(0.035601, 0.473531, 0.191202),
        vec3<f32>(0.155926, 0.617207, 0.097587),
        vec3<f32>(0.982251, 0.799103, 0.018500),
    );
    let k = min(u32(floor(t * 8.0)), 7u);
    return mix(stops[k], stops[k + 1u], t * 8.0 - f32(k));
}

// The tint of a height: hypsometric (land low to high, water shallow to deep), viridis over the
// whole range, or plain grey; linear RGB.
fn ramp(z_m: f32) -> vec3<f32> {
    let kind = u32(frame.looks.y);
    if (kind == 2u) {
        return vec3<f32>(0.8);
    }
    if (kind == 1u) {
        return viridis(clamp((z_m - frame.z_min) / max(frame.z_max - frame.z_min, 1.0), 0.0, 1.0));
    }
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

// Lit, tinted (or draped with `img`, see `imagery_at`), fogged colour of the surface seen along
// `rel` (linear RGB).
fn shade(s: Surface, rel: vec3<f32>, img: vec4<f32>) -> vec3<f32> {
    let lambert = max(dot(s.normal, frame.sun_dir.xyz), 0.0);
    let light = 0.30 + 0.70 * lambert;
    let draped = img.rgb * mix(1.0, light, frame.imagery.y);
    let lit = mix(ramp(s.height_m) * light, draped, img.a);
    let d = length(rel) / frame.fog_distance_m;
    let fog = 1.0 - exp(-d * d);
    return mix(lit, sky(rel), fog);
}

// Padding replicates the DEM's edges out to the 2^n + 1 grid: not terrain, so not drawn; nor are
// the DEM's nodata posts, unless asked to be drawn as sea or as their filled heights.
fn outside_dem(grid: vec2<f32>) -> bool {
    let padding = any(grid < frame.valid_window.xy) || any(grid > frame.valid_window.zw);
    return padding || (frame.nodata.x == 1u && void_at(grid));
}

// The surface under a fragment, or calm shallow water where nodata is drawn as sea.
fn drawn_surface(grid: vec2<f32>) -> Surface {
    if (frame.nodata.x == 2u && void_at(grid)) {
        var s: Surface;
        s.height_m = -0.5;
        s.normal = vec3<f32>(0.0, 0.0, 1.0);
        return s;
    }
    return surface(grid);
}

@fragment
fn fs_terrain(in: VertexOut) -> @location(0) vec4<f32> {
    let img = imagery_at(in.grid);
    if (outside_dem(in.grid)) {
        discard;
    }
    return vec4<f32>(shade(drawn_surface(in.grid), in.rel, img), 1.0);
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
    let img = imagery_at(in.grid);
    if (outside_dem(in.grid)) {
        discard;
    }
    let s = drawn_surface(in.grid);
    var out: Probe;
    out.position = vec4<f32>(in.grid, s.height_m, in.rel.z + frame.eye_in_world.z);
    if (frame.flags == 1u) {
        out.value = vec4<f32>(s.normal, 1.0);
    } else {
        out.value = vec4<f32>(shade(s, in.rel, img), 1.0);
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
