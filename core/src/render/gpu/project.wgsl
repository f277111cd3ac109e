// The vertices of a mesh DRR projected on the GPU in f64 (used when the adapter has SHADER_F64): the same
// per-vertex entries the host otherwise writes for mesh.wgsl — (u_hi, v_hi, u_lo, v_lo) and
// (z, z − z_ref, 0, 0) — from the model's f64 vertices uploaded once, so that a render uploads a pose
// instead of every vertex. The host's projection is `c = R p + t`, `u = fx·x/z + s·y/z + cx`,
// `v = fy·y/z + cy` in f64; a driver may contract a product and a sum into one rounding here, which moves
// a position by ~1e-13 px, far inside the 1e-4 px from an edge within which mesh.wgsl leaves a pixel to
// the host (whose f64 vertices are its own).

struct Pose {
    // Rows of [R | t] (world → camera).
    r0: vec4<f64>,
    r1: vec4<f64>,
    r2: vec4<f64>,
    // fx, fy, skew, cx.
    k: vec4<f64>,
    // cy (x); the number of vertices (y).
    k2: vec4<f64>,
}

@group(0) @binding(0) var<uniform> P: Pose;
// The model's vertices (x, y, z, 0), world frame.
@group(0) @binding(1) var<storage, read> model: array<vec4<f64>>;
// Each vertex's mesh.
@group(0) @binding(2) var<storage, read> vmesh: array<u32>;
// Each mesh's reference depth z_ref in this view.
@group(0) @binding(3) var<storage, read> zref: array<f64>;
// mesh.wgsl's `verts`: two entries per vertex.
@group(0) @binding(4) var<storage, read_write> verts: array<vec4<f32>>;

// `v` as hi + lo in f32 (hi the nearest f32, lo the rest rounded), as the host's `split`.
fn split(v: f64) -> vec2<f32> {
    let hi = f32(v);
    return vec2<f32>(hi, f32(v - f64(hi)));
}

@compute @workgroup_size(64, 1, 1)
fn project(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let i = gid.x + gid.y * groups.x * 64u;
    if f64(i) >= P.k2.y {
        return;
    }
    let p = model[i];
    let c = vec3<f64>(
        P.r0.x * p.x + P.r0.y * p.y + P.r0.z * p.z + P.r0.w,
        P.r1.x * p.x + P.r1.y * p.y + P.r1.z * p.z + P.r1.w,
        P.r2.x * p.x + P.r2.y * p.y + P.r2.z * p.z + P.r2.w,
    );
    let inv_z = 1.0lf / c.z;
    let x = c.x * inv_z;
    let y = c.y * inv_z;
    let u = split(P.k.x * x + P.k.z * y + P.k.w);
    let v = split(P.k.y * y + P.k2.x);
    verts[2u * i] = vec4<f32>(u.x, v.x, u.y, v.y);
    verts[2u * i + 1u] = vec4<f32>(f32(c.z), f32(c.z - zref[vmesh[i]]), 0.0, 0.0);
}
