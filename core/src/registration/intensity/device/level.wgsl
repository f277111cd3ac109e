// One resolution level's similarity on the GPU (src/registration/intensity/device/level.rs): the moving
// DRRs of every view (rendered by the CT shader into `raw`, `ss × ss` rays per level pixel) are
// box-averaged to the level (`bin`), smoothed (`blur_rows`, `blur_cols`), turned into features (`features`)
// and compared block by block with the fixed image's normalised features (`blocks`), as
// src/registration/intensity/similarity.rs does on the CPU:
//   â = (x − mean) / √(energy + ε),  r = √w (â − f̂),  S = Σ_k w_k ⟨â_k, f̂_k⟩.
// The residual stays in `residual` (scaled by 1/√V, the stacked residual of the views); each block's
// w·⟨â, f̂⟩ and ‖r‖² go to `sums`, the only numbers an evaluation reads back.
//
// Sums are f32, compensated: each of a workgroup's 256 invocations adds a strided share of a block with
// Kahan's compensation, then the shares are added pairwise as double-f32 (hi + lo). The mean is kept as hi + lo, so
// a feature minus the mean is exact to f32's resolution of the difference, not of the feature: in a patch
// whose values barely vary (a flat stretch of a DRR) the difference is small against the values. As in
// ct.wgsl, every intermediate of a compensated sum passes through `opaque`, so that no shader compiler
// folds the rounding error it keeps away.

struct Params {
    // Level width and height, rays per level pixel along each axis (ss), views.
    size: vec4<u32>,
    // Features per view (F), blocks per view (B), Gaussian radius (taps = 2·radius + 1), and a 0 that
    // `opaque` needs to be a run-time value.
    counts: vec4<u32>,
    // 1/√V (the stacked residual's scale), 1/ss², 0, 0.
    scale: vec4<f32>,
    // The views of one pose, V (x): a dispatch may evaluate several poses (a Jacobian's six differences),
    // size.w = V × poses views, pose after pose, each with the fixed images and blocks of its view mod V.
    poses: vec4<u32>,
}

// One block of one view: its features [start, start + len), √w and the moving normalisation's ε.
struct Block {
    start: u32,
    len: u32,
    sw: f32,
    eps: f32,
}

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read_write> raw: array<f32>;
@group(0) @binding(2) var<storage, read_write> img: array<f32>;
@group(0) @binding(3) var<storage, read_write> tmp: array<f32>;
@group(0) @binding(4) var<storage, read_write> feat: array<f32>;
// Per feature: its pixel (u + w·v; the 3 × 3 neighbourhood's first pixel for a gradient) in bits 0–29,
// its kind in bits 30–31: 0 the value, 1 Sobel x, 2 Sobel y.
@group(0) @binding(5) var<storage, read_write> src: array<u32>;
@group(0) @binding(6) var<storage, read_write> blocks: array<Block>;
@group(0) @binding(7) var<storage, read_write> fixed: array<f32>;
@group(0) @binding(8) var<storage, read_write> residual: array<f32>;
@group(0) @binding(9) var<storage, read_write> sums: array<f32>;
@group(0) @binding(10) var<storage, read_write> taps: array<f32>;

const GROUP: u32 = 256u;

fn linear(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.x + gid.y * nwg.x * GROUP;
}

// The level image of every view: the mean of each pixel's ss × ss rays (summed compensated, so the
// result is the CPU's f64 sum rounded once, ties aside).
@compute @workgroup_size(256, 1, 1)
fn bin(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear(gid, nwg);
    let w = P.size.x;
    let h = P.size.y;
    let ss = P.size.z;
    if (i >= w * h * P.size.w) {
        return;
    }
    let view = i / (w * h);
    let p = i % (w * h);
    let u = p % w;
    let v = p / w;
    let fw = w * ss;
    let base = view * fw * h * ss;
    var s = vec2<f32>(0.0, 0.0);
    for (var dv = 0u; dv < ss; dv++) {
        for (var du = 0u; du < ss; du++) {
            s = kahan(s, raw[base + (v * ss + dv) * fw + u * ss + du]);
        }
    }
    img[i] = (s.x - s.y) * P.scale.y;
}

// Σ_k tap_k · x_k with the taps as hi + lo (`taps` holds the pairs), each product split exactly by fma
// and every sum compensated (Ogita, Rump & Oishi's Dot2): the CPU's f64 sum rounded once, ties aside.
struct Dot {
    s: f32,
    c: f32,
}

fn dot_add(acc: Dot, k: u32, x: f32) -> Dot {
    var out = acc;
    for (var part = 0u; part < 2u; part++) {
        let t = taps[2u * k + part];
        let p = opaque(t * x);
        let e = opaque(fma(t, x, -p));
        let sum = opaque(out.s + p);
        let z = opaque(sum - out.s);
        let q = opaque(opaque(out.s - opaque(sum - z)) + opaque(p - z));
        out.s = sum;
        out.c = out.c + q + e;
    }
    return out;
}

// Gaussian smoothing with replicated borders (io::gaussian_blur): rows into `tmp` ...
@compute @workgroup_size(256, 1, 1)
fn blur_rows(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear(gid, nwg);
    let w = P.size.x;
    let h = P.size.y;
    if (i >= w * h * P.size.w) {
        return;
    }
    let row = i - i % w;
    let u = i32(i % w);
    let r = i32(P.counts.z);
    var s = Dot(0.0, 0.0);
    for (var k = -r; k <= r; k++) {
        let x = clamp(u + k, 0, i32(w) - 1);
        s = dot_add(s, u32(k + r), img[row + u32(x)]);
    }
    tmp[i] = s.s + s.c;
}

// ... then columns back into `img`.
@compute @workgroup_size(256, 1, 1)
fn blur_cols(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear(gid, nwg);
    let w = P.size.x;
    let h = P.size.y;
    if (i >= w * h * P.size.w) {
        return;
    }
    let base = i - i % (w * h);
    let u = (i % (w * h)) % w;
    let v = i32((i % (w * h)) / w);
    let r = i32(P.counts.z);
    var s = Dot(0.0, 0.0);
    for (var k = -r; k <= r; k++) {
        let y = u32(clamp(v + k, 0, i32(h) - 1));
        s = dot_add(s, u32(k + r), tmp[base + y * w + u]);
    }
    img[i] = s.s + s.c;
}

// Every view's features.
@compute @workgroup_size(256, 1, 1)
fn features(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear(gid, nwg);
    let f = P.counts.x;
    if (i >= f * P.size.w) {
        return;
    }
    let w = P.size.x;
    let code = src[i % f];
    let base = (i / f) * w * P.size.y;
    let p = base + (code & 0x3fffffffu);
    let kind = code >> 30u;
    if (kind == 0u) {
        feat[i] = img[p];
        return;
    }
    // Sobel on rows v, v + 1, v + 2 and columns u, u + 1, u + 2 (analysis::sobel_at).
    let r0 = p;
    let r1 = p + w;
    let r2 = p + 2u * w;
    if (kind == 1u) {
        feat[i] = img[r0 + 2u] - img[r0] + 2.0 * (img[r1 + 2u] - img[r1]) + img[r2 + 2u] - img[r2];
    } else {
        feat[i] = img[r2] - img[r0] + 2.0 * (img[r2 + 1u] - img[r0 + 1u]) + img[r2 + 2u] - img[r0 + 2u];
    }
}

// x, through a door the compiler cannot see through: no algebra crosses it.
fn opaque(x: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(x) ^ P.counts.w);
}

// Kahan's step: the running sum (x) and its compensation (y) after adding `v`.
fn kahan(acc: vec2<f32>, v: f32) -> vec2<f32> {
    let y = opaque(v - acc.y);
    let t = opaque(acc.x + y);
    return vec2<f32>(t, opaque(opaque(t - acc.x) - y));
}

var<workgroup> shared_a: array<f32, 256>;
var<workgroup> shared_b: array<f32, 256>;

// The sum over the workgroup of each invocation's hi + lo value, as hi + lo, in every invocation: pairs
// added as double-f32 (the two his by Knuth's two-sum, their error and the los carried in lo), so the
// tree's roundings are kept too.
fn reduce_df(t: u32, v: vec2<f32>) -> vec2<f32> {
    shared_a[t] = v.x;
    shared_b[t] = v.y;
    workgroupBarrier();
    for (var half = GROUP / 2u; half > 0u; half /= 2u) {
        if (t < half) {
            let a = shared_a[t];
            let b = shared_a[t + half];
            let s = opaque(a + b);
            let z = opaque(s - a);
            let err = opaque(opaque(a - opaque(s - z)) + opaque(b - z));
            shared_a[t] = s;
            shared_b[t] = shared_b[t] + shared_b[t + half] + err;
        }
        workgroupBarrier();
    }
    let out = vec2<f32>(shared_a[0], shared_b[0]);
    workgroupBarrier();
    return out;
}

// A Kahan accumulator (sum, compensation) as hi + lo.
fn df(k: vec2<f32>) -> vec2<f32> {
    return vec2<f32>(k.x, -k.y);
}

// One workgroup per block of one view (x + y·nwg.x: the block, z: the view): mean, energy, then the
// normalised residual and the block's sums.
@compute @workgroup_size(256, 1, 1)
fn block_sums(
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let nb = P.counts.y;
    let b = wid.x + wid.y * nwg.x;
    // Uniform across the workgroup: every invocation returns or none does.
    if (b >= nb) {
        return;
    }
    let t = lid.x;
    let view = wid.z;
    let own = view % P.poses.x;
    let blk = blocks[own * nb + b];
    let off = view * P.counts.x + blk.start;
    let fixed_off = own * P.counts.x + blk.start;
    var s = vec2<f32>(0.0, 0.0);
    for (var k = t; k < blk.len; k += GROUP) {
        s = kahan(s, feat[off + k]);
    }
    // The block's sum as hi + lo, then the mean as hi + lo: m_hi = sum/n rounded, m_lo = the rest / n.
    let total = reduce_df(t, df(s));
    let n = f32(max(blk.len, 1u));
    let sum_hi = opaque(total.x + total.y);
    let sum_lo = opaque(total.y - opaque(sum_hi - total.x));
    let m_hi = sum_hi / n;
    let m_lo = (opaque(fma(-m_hi, n, sum_hi)) + sum_lo) / n;
    var e = vec2<f32>(0.0, 0.0);
    for (var k = t; k < blk.len; k += GROUP) {
        let c = opaque(feat[off + k] - m_hi) - m_lo;
        e = kahan(e, c * c);
    }
    let energy_parts = reduce_df(t, df(e));
    let energy = energy_parts.x + energy_parts.y;
    let d = sqrt(energy + blk.eps);
    var scale = 0.0;
    if (d > 0.0) {
        scale = 1.0 / d;
    }
    var dot = vec2<f32>(0.0, 0.0);
    var rr = vec2<f32>(0.0, 0.0);
    for (var k = t; k < blk.len; k += GROUP) {
        let a = (opaque(feat[off + k] - m_hi) - m_lo) * scale;
        let fb = fixed[fixed_off + k];
        dot = kahan(dot, a * fb);
        let r = blk.sw * (a - fb);
        rr = kahan(rr, r * r);
        residual[off + k] = r * P.scale.x;
    }
    let dd = reduce_df(t, df(dot));
    let rd = reduce_df(t, df(rr));
    let ds = vec2<f32>(dd.x + dd.y, rd.x + rd.y);
    if (t == 0u) {
        sums[2u * (view * nb + b)] = blk.sw * blk.sw * ds.x;
        sums[2u * (view * nb + b) + 1u] = ds.y;
    }
}
