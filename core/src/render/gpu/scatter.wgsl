// Writes the host's pixel values into an image that stays on the GPU: entry k of `pixels` is (pixel index,
// f32 bits), written to `image[base + index]`. A mesh DRR kept on the GPU for the registration's level
// (`finish` in mesh.wgsl leaves 0 where the host evaluates a pixel) gets its host pixels this way, so only
// those travel up, not the image.

struct Params {
    // x: the image's first element in `image`, y: the entries of `pixels`, z: invocations per row of
    // workgroups (the grid's x extent × 64).
    p: vec4<u32>,
}

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read> pixels: array<vec2<u32>>;
@group(0) @binding(2) var<storage, read_write> image: array<f32>;

@compute @workgroup_size(64, 1, 1)
fn scatter(@builtin(global_invocation_id) gid: vec3<u32>) {
    let k = gid.x + gid.y * P.p.z;
    if k >= P.p.y {
        return;
    }
    let e = pixels[k];
    image[P.p.x + e.x] = bitcast<f32>(e.y);
}
