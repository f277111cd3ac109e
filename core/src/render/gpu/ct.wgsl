// CT DRRs on the GPU: one invocation per pixel of one view, the line integral of μ through the clip box
// of the CT (src/render/gpu/ct.rs uploads that box as a 3-D texture, x fastest).
//
// Coordinates are continuous voxel indices relative to the box (voxel i spans [i − ½, i + ½]); t is in
// world millimetres along the ray (d = the index-space image of a unit world direction), as in
// src/render/volume/. WGSL has no f64, and f32 alone is not enough: a ray nearly parallel to a voxel
// plane (every ray of an AP or lateral view is, to its minor axes) crosses that plane at
// t = (plane − e)/d, so an error δ in the entry point e moves the crossing by δ/d along the ray — a
// coordinate of ~500 voxels held in f32 (δ ~ 3e-5) changed real-CT DRRs by up to 1e-4 of their value.
// So the geometry is carried in double-f32 (a value is hi + lo, ~44 bits) where it matters:
// * the ray's point X on the plane through the box's centre parallel to the detector, an affine function
//   of the pixel, X = A·(u, v, 1), and its direction's index-space numerator Mi·(u, v, 1): A and Mi come
//   from the host (f64) split into a hi part of 12 significant bits, whose product with a pixel
//   coordinate below 4096 is exact, and a lo part; the sums of products are error-free (two_sum);
// * the entry point e = X + t0·d is kept as hi + lo, and each plane crossing is computed from its plane's
//   coordinate, ((plane − e_hi) − e_lo)·(1/d) (the two are within a voxel, so plane − e_hi is exact, or
//   off by f32's resolution of a fraction of a voxel near the box's first planes), never by adding Δt to
//   the previous crossing;
// * t is measured from X, and the source sits at t_src = −z_c·|Rᵀ K⁻¹ (u, v, 1)| (z_c: the box centre's
//   depth), before which nothing is integrated;
// * sums of μ·ℓ are compensated (Kahan), so ~550 terms keep ~7 digits.
// Shader compilers may rewrite float arithmetic algebraically (Mesa's NIR, for one, turns
// ((a + b) − a) − b into 0 unless an operation is marked exact, which WGSL cannot say), and that would
// erase exactly the rounding errors these sums keep. So every intermediate of an error-free sum passes
// through `opaque`, an identity the compiler cannot see through (its integer xor takes a zero the host
// passes at run time). WGSL lets an implementation assume no infinities, so "never" is a large finite
// number.

struct View {
    // Rows of Rᵀ K⁻¹: world direction (unnormalised) of pixel (u, v) is (dot(mw0.xyz, p), …), p = (u, v, 1).
    mw0: vec4<f32>,
    mw1: vec4<f32>,
    mw2: vec4<f32>,
    // Rows of Mi, the index-space image of that direction (the world→index map's linear part times
    // Rᵀ K⁻¹), split hi + lo.
    mi_hi: array<vec4<f32>, 3>,
    mi_lo: array<vec4<f32>, 3>,
    // Rows of A, split hi + lo: the ray's point on the box's mid-plane, in box index coordinates, is A·p.
    a_hi: array<vec4<f32>, 3>,
    a_lo: array<vec4<f32>, 3>,
    // The box centre's depth z_c in the camera (x).
    depth: vec4<f32>,
}

struct Globals {
    // Box size in voxels (xyz), number of views (w).
    dims: vec4<u32>,
    // Detector width and height (xy); z is always 0 (see `opaque`).
    image: vec4<u32>,
    // The pixels traced: first column and row (xy), width and height (zw), the union of the views'
    // footprints of the box (the rest of the output stays 0: wgpu zeroes new buffers).
    window: vec4<u32>,
    // Trilinear step h_max in mm (x).
    h_max: vec4<f32>,
}

@group(0) @binding(0) var<uniform> G: Globals;
@group(0) @binding(1) var<storage, read> views: array<View>;
@group(0) @binding(2) var mu: texture_3d<f32>;
@group(0) @binding(3) var<storage, read_write> out: array<f32>;

const NEVER: f32 = 3.0e38;

struct Ray {
    // Entry point into the box (index coordinates) as hi + lo, index-space direction per mm, length
    // inside (mm).
    e: vec3<f32>,
    e_lo: vec3<f32>,
    d: vec3<f32>,
    len: f32,
}

// x, through a door the compiler cannot see through: no algebra crosses it.
fn opaque(x: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(x) ^ G.image.z);
}

// a + b exactly, as the rounded sum and its error (Knuth's two-sum).
fn two_sum(a: f32, b: f32) -> vec2<f32> {
    let s = opaque(a + b);
    let bb = opaque(s - a);
    let ea = opaque(a - opaque(s - bb));
    let eb = opaque(b - bb);
    return vec2<f32>(s, ea + eb);
}

// (hi + lo)·p for p = (u, v, 1) with u, v whole numbers below 4096, as hi + lo: each hi[i]·p[i] is exact
// (12 + 12 significant bits), and their sum is error-free.
fn dot_df(hi: vec4<f32>, lo: vec4<f32>, p: vec3<f32>) -> vec2<f32> {
    let s1 = two_sum(hi.x * p.x, hi.y * p.y);
    let s2 = two_sum(s1.x, hi.z * p.z);
    return two_sum(s2.x, s2.y + s1.y + dot(lo.xyz, p));
}

// The ray of pixel (u, v) of view `k`, clipped to the box [−½, n − ½] (slab method) and to the part in
// front of the source; len ≤ 0 when it misses.
fn pixel_ray(k: u32, u: u32, v: u32) -> Ray {
    let w = views[k];
    let p = vec3<f32>(f32(u), f32(v), 1.0);
    let world = length(vec3<f32>(dot(w.mw0.xyz, p), dot(w.mw1.xyz, p), dot(w.mw2.xyz, p)));
    var x: vec3<f32>;
    var x_lo: vec3<f32>;
    var d: vec3<f32>;
    for (var a = 0; a < 3; a++) {
        let xa = dot_df(w.a_hi[a], w.a_lo[a], p);
        x[a] = xa.x;
        x_lo[a] = xa.y;
        let da = dot_df(w.mi_hi[a], w.mi_lo[a], p);
        d[a] = (da.x + da.y) / world;
    }
    let n = vec3<f32>(G.dims.xyz);
    // Rays leave the source: nothing before it counts.
    var t0 = -w.depth.x * world;
    var t1 = NEVER;
    var r: Ray;
    r.d = d;
    r.len = -1.0;
    for (var a = 0; a < 3; a++) {
        let lo = -0.5;
        let hi = n[a] - 0.5;
        if d[a] == 0.0 {
            if x[a] < lo || x[a] > hi {
                return r;
            }
            continue;
        }
        let inv = 1.0 / d[a];
        let ta = (lo - x[a]) * inv;
        let tb = (hi - x[a]) * inv;
        t0 = max(t0, min(ta, tb));
        t1 = min(t1, max(ta, tb));
    }
    for (var a = 0; a < 3; a++) {
        let ea = two_sum(x[a], t0 * d[a]);
        r.e[a] = ea.x;
        r.e_lo[a] = ea.y + x_lo[a];
    }
    r.len = t1 - t0;
    return r;
}

fn out_index(k: u32, u: u32, v: u32) -> u32 {
    return (k * G.image.y + v) * G.image.x + u;
}

// Compensated sum: s.x the sum, s.y the running compensation.
fn kahan(s: vec2<f32>, x: f32) -> vec2<f32> {
    let y = opaque(x - s.y);
    let t = opaque(s.x + y);
    return vec2<f32>(t, opaque(t - s.x) - y);
}

// The entry points: invocation `gid` traces its pixel of the window, view gid.z, with the method's
// integral, and writes it (0 where the ray misses the box).
@compute @workgroup_size(8, 8, 1)
fn siddon(@builtin(global_invocation_id) gid: vec3<u32>) {
    trace(gid, false);
}

@compute @workgroup_size(8, 8, 1)
fn trilinear(@builtin(global_invocation_id) gid: vec3<u32>) {
    trace(gid, true);
}

fn trace(gid: vec3<u32>, by_trilinear: bool) {
    if gid.x >= G.window.z || gid.y >= G.window.w || gid.z >= G.dims.w {
        return;
    }
    let u = gid.x + G.window.x;
    let v = gid.y + G.window.y;
    let r = pixel_ray(gid.z, u, v);
    var value = 0.0;
    if r.len > 0.0 {
        if by_trilinear {
            value = trilinear_integral(r);
        } else {
            value = siddon_integral(r);
        }
    }
    out[out_index(gid.z, u, v)] = value;
}

// Siddon's exact radiological path (Jacobs' incremental form): the voxel sequence the ray crosses, each
// voxel's μ times the length of the ray inside it.
fn siddon_integral(r: Ray) -> f32 {
    let n = vec3<i32>(G.dims.xyz);
    // The voxel of the entry point (clamped: the entry face itself rounds either way).
    var idx = clamp(vec3<i32>(floor(r.e + 0.5)), vec3<i32>(0), n - 1);
    var dir_step = vec3<i32>(0);
    var plane = vec3<f32>(0.0);
    var inv = vec3<f32>(0.0);
    var tn = vec3<f32>(NEVER);
    for (var a = 0; a < 3; a++) {
        if r.d[a] > 0.0 {
            dir_step[a] = 1;
            plane[a] = f32(idx[a]) + 0.5;
        } else if r.d[a] < 0.0 {
            dir_step[a] = -1;
            plane[a] = f32(idx[a]) - 0.5;
        }
        if dir_step[a] != 0 {
            inv[a] = 1.0 / r.d[a];
            tn[a] = (opaque(plane[a] - r.e[a]) - r.e_lo[a]) * inv[a];
        }
    }
    var t = 0.0;
    var s = vec2<f32>(0.0);
    let max_steps = n.x + n.y + n.z + 3;
    for (var i = 0; i < max_steps; i++) {
        let tm = min(tn.x, min(tn.y, tn.z));
        let te = min(tm, r.len);
        s = kahan(s, textureLoad(mu, idx, 0).x * (te - t));
        t = te;
        if tm >= r.len {
            break;
        }
        // Cross the nearest plane (one axis at a time: a tie costs a zero-length step).
        var a = 2;
        if tn.x == tm {
            a = 0;
        } else if tn.y == tm {
            a = 1;
        }
        idx[a] += dir_step[a];
        plane[a] += f32(dir_step[a]);
        tn[a] = (opaque(plane[a] - r.e[a]) - r.e_lo[a]) * inv[a];
        if idx[a] < 0 || idx[a] >= n[a] {
            break;
        }
    }
    return s.x;
}

// Trilinear μ at box coordinate p: the eight voxel centres around it, coordinates clamped to the box
// (see src/render/volume/trilinear.rs for why the box's clamp equals the whole grid's).
fn axis_cell(x: f32, n: i32) -> vec3<f32> {
    let c = clamp(x, 0.0, f32(n - 1));
    let i0 = min(i32(floor(c)), max(n - 2, 0));
    let i1 = min(i0 + 1, n - 1);
    return vec3<f32>(f32(i0), f32(i1), c - f32(i0));
}

fn voxel(i: f32, j: f32, k: f32) -> f32 {
    return textureLoad(mu, vec3<i32>(i32(i), i32(j), i32(k)), 0).x;
}

fn lerp(a: f32, b: f32, f: f32) -> f32 {
    return a + (b - a) * f;
}

fn mu_at(p: vec3<f32>) -> f32 {
    let n = vec3<i32>(G.dims.xyz);
    let x = axis_cell(p.x, n.x);
    let y = axis_cell(p.y, n.y);
    let z = axis_cell(p.z, n.z);
    let c00 = lerp(voxel(x.x, y.x, z.x), voxel(x.y, y.x, z.x), x.z);
    let c10 = lerp(voxel(x.x, y.y, z.x), voxel(x.y, y.y, z.x), x.z);
    let c01 = lerp(voxel(x.x, y.x, z.y), voxel(x.y, y.x, z.y), x.z);
    let c11 = lerp(voxel(x.x, y.y, z.y), voxel(x.y, y.y, z.y), x.z);
    return lerp(lerp(c00, c10, y.z), lerp(c01, c11, y.z), z.z);
}

// Midpoint rule over the clipped ray: N = ⌈len / step⌉ samples of trilinear μ, h = len / N. N jumps
// where len crosses a whole number of steps (in an AP view, on rings around the central ray): within f32's
// rounding of such a ring a ray may take one sample more or fewer than the f64 CPU renderer's.
fn trilinear_integral(r: Ray) -> f32 {
    let count = max(u32(ceil(r.len / G.h_max.x)), 1u);
    let h = r.len / f32(count);
    var s = vec2<f32>(0.0);
    for (var i = 0u; i < count; i++) {
        s = kahan(s, mu_at(r.e + (r.e_lo + r.d * ((f32(i) + 0.5) * h))));
    }
    return s.x * h;
}
