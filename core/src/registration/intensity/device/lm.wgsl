// The Levenberg–Marquardt products of src/registration/intensity/lm.rs on the GPU, over residuals that
// never leave it (src/registration/intensity/device/lm.rs): the forward-difference Jacobian, the normal
// equations' partial sums per chunk of rows (the host adds the chunks in order, in f64) and Broyden's
// rank-one update.

struct Params {
    // Residuals (n), the stride of the difference columns (a multiple of 64), rows per chunk, 0.
    counts: vec4<u32>,
    // 1/h (x).
    step: vec4<f32>,
    // The step δ (six values) and δ/δᵀδ (six values).
    delta: array<vec4<f32>, 2>,
    d: array<vec4<f32>, 2>,
}

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read_write> r: array<f32>;
// The six difference columns (`jacobian`) or the residual after the step (`secant`).
@group(0) @binding(2) var<storage, read_write> other: array<f32>;
// Six values per residual, row by row.
@group(0) @binding(3) var<storage, read_write> jac: array<f32>;
// 27 per chunk: JᵀJ's upper triangle row by row (21), then −Jᵀr (6).
@group(0) @binding(4) var<storage, read_write> partials: array<f32>;

const GROUP: u32 = 256u;

fn linear(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.x + gid.y * nwg.x * GROUP;
}

fn six(a: array<vec4<f32>, 2>, k: u32) -> f32 {
    return a[k / 4u][k % 4u];
}

@compute @workgroup_size(256, 1, 1)
fn jacobian(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear(gid, nwg);
    if (i >= P.counts.x) {
        return;
    }
    let ri = r[i];
    for (var k = 0u; k < 6u; k++) {
        jac[6u * i + k] = (other[k * P.counts.y + i] - ri) * P.step.x;
    }
}

@compute @workgroup_size(256, 1, 1)
fn secant(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear(gid, nwg);
    if (i >= P.counts.x) {
        return;
    }
    var jd = 0.0;
    for (var k = 0u; k < 6u; k++) {
        jd += jac[6u * i + k] * six(P.delta, k);
    }
    let u = other[i] - r[i] - jd;
    for (var k = 0u; k < 6u; k++) {
        jac[6u * i + k] += u * six(P.d, k);
    }
}

var<workgroup> shared_s: array<f32, 256>;

// One workgroup per chunk of rows: each invocation adds its strided rows' 27 products, then the
// workgroup adds them pairwise, one product at a time.
@compute @workgroup_size(256, 1, 1)
fn normal(
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
) {
    let t = lid.x;
    let chunk = wid.x + wid.y * nwg.x;
    let first = chunk * P.counts.z;
    // A workgroup past the last chunk (the dispatch's rectangle rounds up) writes nothing; uniform
    // across the workgroup.
    if (first >= P.counts.x && chunk > 0u) {
        return;
    }
    let last = min(first + P.counts.z, P.counts.x);
    var acc: array<f32, 27>;
    for (var q = 0u; q < 27u; q++) {
        acc[q] = 0.0;
    }
    for (var i = first + t; i < last; i += GROUP) {
        var j: array<f32, 6>;
        for (var k = 0u; k < 6u; k++) {
            j[k] = jac[6u * i + k];
        }
        let x = r[i];
        var n = 0u;
        for (var p = 0u; p < 6u; p++) {
            for (var q = p; q < 6u; q++) {
                acc[n] += j[p] * j[q];
                n++;
            }
            acc[21u + p] -= j[p] * x;
        }
    }
    for (var q = 0u; q < 27u; q++) {
        shared_s[t] = acc[q];
        workgroupBarrier();
        for (var half = GROUP / 2u; half > 0u; half /= 2u) {
            if (t < half) {
                shared_s[t] += shared_s[t + half];
            }
            workgroupBarrier();
        }
        if (t == 0u) {
            partials[27u * chunk + q] = shared_s[0];
        }
        workgroupBarrier();
    }
}
