// The spectral energy sum on the GPU (src/render/gpu/energy.rs), one invocation per pixel: the CPU's
// kernel (src/spectral/kernel.rs) over the channel maps the CT shader left in `maps` (channel c's pixels
// from c·stride):
//   y_b = −ln w_b + Σ_c t_cb · a_c,  m = min_b y_b,  L = m − ln Σ_b exp(−min(y_b − m, 87)),
// 0 where every channel is 0 (a ray that misses the CT). WGSL's exp and log are within a few ulp.

struct Params {
    // Pixels, channels, padded bins per channel, the channel stride in `maps` (values).
    counts: vec4<u32>,
}

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read_write> maps: array<f32>;
// t[c · padded + b] (0 in the padding).
@group(0) @binding(2) var<storage, read_write> table: array<f32>;
// −ln w_b (1e30 in the padding and for bins of weight 0).
@group(0) @binding(3) var<storage, read_write> neg_log_w: array<f32>;
@group(0) @binding(4) var<storage, read_write> out: array<f32>;

const CLAMP: f32 = 87.0;

fn y_of(i: u32, b: u32) -> f32 {
    var y = neg_log_w[b];
    for (var c = 0u; c < P.counts.y; c++) {
        let a = maps[c * P.counts.w + i];
        if (a != 0.0) {
            y += table[c * P.counts.z + b] * a;
        }
    }
    return y;
}

@compute @workgroup_size(256, 1, 1)
fn energy_sum(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.x + gid.y * nwg.x * 256u;
    if (i >= P.counts.x) {
        return;
    }
    var any = false;
    for (var c = 0u; c < P.counts.y; c++) {
        any = any || maps[c * P.counts.w + i] != 0.0;
    }
    if (!any) {
        out[i] = 0.0;
        return;
    }
    var m = 3.0e38;
    for (var b = 0u; b < P.counts.z; b++) {
        m = min(m, y_of(i, b));
    }
    var sum = 0.0;
    for (var b = 0u; b < P.counts.z; b++) {
        sum += exp(-min(y_of(i, b) - m, CLAMP));
    }
    out[i] = m - log(sum);
}
