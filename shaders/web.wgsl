// The web viewer's terrain: one triangle strip of grid posts, positioned on the CPU (metres,
// relative to the scene origin, and where the draped image is), shaded per facet from the
// screen-space derivatives of the position. Kept within WebGL2: one uniform block, one vertex
// buffer, no storage buffers, no
// compute, one texture. Owner: src/web/draw.rs (uniform layout `FrameUniform`, the pipeline).
// CPU reference of the fragment maths: `shade` in src/web/draw.rs — keep the two in step.

struct Frame {
    // Clip space from eye-relative scene space (position − eye, metres): projection × rotation.
    clip_from_rel: mat4x4<f32>,
    // The eye relative to the scene origin (metres); w unused.
    eye_in_scene: vec4<f32>,
    // Unit vector towards the sun; w unused.
    sun_dir: vec4<f32>,
    // Ramp from z_lo to z_hi (scene metres, exaggerated), fog distance (m), and 1 where the
    // target is not sRGB (the shader then encodes, as an sRGB target would).
    ramp: vec4<f32>,
    // 1 when an image is draped, how much the hillshade lights it, 1 when u wraps, 0.
    imagery: vec4<f32>,
};

@group(0) @binding(0) var<uniform> frame: Frame;
// The draped image with its mip levels (sRGB; one white texel when there is none).
@group(0) @binding(1) var image: texture_2d<f32>;
@group(0) @binding(2) var image_sampler: sampler;

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) in_scene: vec3<f32>,
    @location(1) uv: vec2<f32>,
};

@vertex
fn vs_terrain(@location(0) in_scene: vec3<f32>, @location(1) uv: vec2<f32>) -> VertexOut {
    var out: VertexOut;
    out.clip = frame.clip_from_rel * vec4<f32>(in_scene - frame.eye_in_scene.xyz, 1.0);
    out.in_scene = in_scene;
    out.uv = uv;
    return out;
}

// Hypsometric ramp: green lowlands, brown slopes, grey rock, white tops (linear RGB).
fn ramp_colour(t: f32) -> vec3<f32> {
    let c0 = vec3<f32>(0.13, 0.30, 0.10);
    let c1 = vec3<f32>(0.42, 0.36, 0.18);
    let c2 = vec3<f32>(0.45, 0.43, 0.40);
    let c3 = vec3<f32>(0.92, 0.92, 0.95);
    let s = clamp(t, 0.0, 1.0) * 3.0;
    if (s < 1.0) {
        return mix(c0, c1, s);
    }
    if (s < 2.0) {
        return mix(c1, c2, s - 1.0);
    }
    return mix(c2, c3, s - 2.0);
}

const SKY: vec3<f32> = vec3<f32>(0.53, 0.70, 0.88);

// The colour of a facet with unit normal `n` (z up) at height `z` and distance `d` from the eye,
// under the draped image's colour `image` (linear RGB; used where frame.imagery.x is 1).
fn shade(n: vec3<f32>, z: f32, d: f32, image: vec3<f32>) -> vec3<f32> {
    let t = (z - frame.ramp.x) / max(frame.ramp.y - frame.ramp.x, 1e-3);
    let light = 0.25 + 0.75 * max(dot(n, frame.sun_dir.xyz), 0.0);
    let fog = clamp(d / frame.ramp.z, 0.0, 1.0);
    var c = ramp_colour(t) * light;
    if (frame.imagery.x > 0.5) {
        c = image * mix(1.0, light, frame.imagery.y);
    }
    return mix(c, SKY, fog * fog);
}

fn srgb_encode(c: vec3<f32>) -> vec3<f32> {
    let lo = c * 12.92;
    let hi = 1.055 * pow(c, vec3<f32>(1.0 / 2.4)) - 0.055;
    return select(hi, lo, c <= vec3<f32>(0.0031308));
}

@fragment
fn fs_terrain(v: VertexOut) -> @location(0) vec4<f32> {
    // Sampled first, in uniform control flow (implicit mip level).
    var uv = v.uv;
    if (frame.imagery.z > 0.5) {
        uv.x = fract(uv.x);
    }
    let image_rgb = textureSample(image, image_sampler, uv).rgb;
    var n = normalize(cross(dpdx(v.in_scene), dpdy(v.in_scene)));
    if (n.z < 0.0) {
        n = -n;
    }
    let d = length(v.in_scene - frame.eye_in_scene.xyz);
    var c = shade(n, v.in_scene.z, d, image_rgb);
    if (frame.ramp.w > 0.5) {
        c = srgb_encode(c);
    }
    return vec4<f32>(c, 1.0);
}
