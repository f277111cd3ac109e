// Mesh DRRs on the GPU: the raster's signed-depth sum (src/render/raster/summed.rs) with one invocation
// per triangle. Each covered pixel centre of a triangle adds `± μ · (z − z_ref)` to the pixel (exit +,
// entry −; z the camera depth where the pixel's ray meets the triangle's plane, z_ref its mesh's
// reference depth, which cancels in a pixel whose crossings balance), and counts `± 1` and `± mesh` so
// that a pixel that lost or doubled a crossing at a vertex can be told.
//
// Sums are fixed-point integers added with atomics: exact, independent of the order the invocations run
// in, and wrapping (two's complement), so a partial sum may overflow as long as the pixel's total fits;
// the host picks the scale so that every pixel's total does.
//
// The vertices are projected in f64 (the CPU raster's projection; by project.wgsl or the host) and each
// pixel position is passed as hi + lo f32s. Coverage is the 2-D edge-function test on those positions, which has the sign of the CPU
// raster's `(A × B) · K⁻¹ [u, v, 1]ᵀ` (both depths are positive and det K⁻¹ > 0). An edge is evaluated
// from its lower-numbered vertex, so the two triangles sharing it compute exactly opposite values
// (watertight, with the CPU's tie rule for a pixel exactly on it). The offset of a pixel from a vertex,
// (p − a_hi) − a_lo, is exact to ~1e-7 px, so the GPU's coverage can differ from the CPU's only for a
// pixel centre within that of an edge. Such pixels, the unbalanced ones and those an implant may cover
// (an implant displaces the other meshes where it is, which a sum cannot tell) are not left to the sum:
// `rasterise` flags every pixel centre within NEAR_PX of an edge of a triangle it lies in (or on), and
// every pixel centre inside an implant's triangle grown by NEAR_PX, and
// `collect` lists, for every flagged or unbalanced pixel, the triangles whose edges it lies within
// NEAR_PX of or inside; the host evaluates those pixels with the CPU raster's own f64 edge functions and
// pairs their crossings, so they are the CPU raster's values exactly. That also covers a ray through an
// edge or vertex on a silhouette, which meets a mesh with zero length: the CPU's pairing drops it, a sum
// cannot tell it from a crossing.
//
// Depth uses perspective-correct barycentrics: with λ the 2-D barycentric weights of the pixel and
// δ_i = z_i − z_a, z − z_a = z · (λ_b δ_b / z_b + λ_c δ_c / z_c), whose small terms keep f32's relative
// precision (z itself, ~1000 mm, would not: its f32 resolution is 6e-5 mm).
// Shader compilers may rewrite float arithmetic algebraically; nothing here relies on a rounding error
// surviving, so no operation needs hiding from them.

struct Globals {
    // Detector width and height (xy), triangles (z), words per pixel in `acc` (w: 4, or
    // 4 + SLOT_WORDS·SLOTS with the per-mesh slots).
    image: vec4<u32>,
    // The scales of the fixed-point sums: x of Σ ± μ·depth (units per μ·mm), y of a mesh's chord
    // (units per mm of depth); z the silhouettes' chord threshold (mm of ray).
    scale: vec4<f32>,
    // Capacity of `list` in (pixel, triangle) entries and of `host` in pixels (x); the chords (y..z, in
    // units of scale.y, as i32) within rounding of the silhouette threshold, whose pixels the host
    // evaluates.
    list: vec4<u32>,
    // A pixel's ray direction K⁻¹ [u, v, 1]ᵀ (for `finish`): x = ray_x · (u, v, 1), y = ray_y · (u, v, 1).
    ray_x: vec4<f32>,
    ray_y: vec4<f32>,
}

@group(0) @binding(0) var<uniform> G: Globals;
// Per vertex, two entries: (u_hi, v_hi, u_lo, v_lo) and (z, z − z_ref, 0, 0).
@group(0) @binding(1) var<storage, read> verts: array<vec4<f32>>;
// Per triangle: its vertices (global indices) and its mesh (low 16 bits), structure label (next 8) and
// whether its mesh is an implant (bit 24).
@group(0) @binding(2) var<storage, read> tris: array<vec4<u32>>;
// Per mesh: μ (bits), object index.
@group(0) @binding(3) var<storage, read> meshes: array<vec2<u32>>;
// Per pixel: Σ ± μ·(z − z_ref) in fixed point, Σ s, Σ s·mesh, the number of crossings (with HOST set
// when the pixel's centre is near an edge, or it meets more meshes than it has slots), then (when asked)
// SLOTS per-mesh slots of three words: mesh + 1 (low 17 bits; 0: free) with the structure bits of the
// mesh's crossed triangles above them, the mesh's chord Σ ± (z − z_ref) in fixed point, and its nearest
// crossing's depth as !bits. The host keeps a
// mesh in the silhouettes when its chord passes the CPU's threshold (1 µm), as the CPU's pairing does.
@group(0) @binding(4) var<storage, read_write> acc: array<atomic<u32>>;
// `collect`'s list: the number of entries it wanted to write (word 0), then (pixel, triangle) pairs.
@group(0) @binding(5) var<storage, read_write> list: array<atomic<u32>>;
// `finish`'s pixels for the host: how many it wanted to write (word 0), the pixels it finished (1) and
// their crossings (2: low word, 3: high word), then the indices of the pixels the host evaluates.
@group(0) @binding(6) var<storage, read_write> host: array<atomic<u32>>;
// `finish`'s line integrals (mm·μ, 0 where the host evaluates the pixel).
@group(0) @binding(7) var<storage, read_write> image: array<f32>;
// With the slots, `finish`'s other outputs, four words per pixel: the nearest silhouette crossing's depth
// (f32 bits, +inf when none), the object bits (low, high word) and the structure bits.
@group(0) @binding(8) var<storage, read_write> extra: array<u32>;

// Pixel-box margin (px) around the projected corners (as the CPU raster's).
const MARGIN: f32 = 1e-2;
// How close to an edge (px) a pixel centre is left to the CPU: far beyond the ~1e-7 px by which the
// GPU's edge functions can differ from the CPU's.
const NEAR_PX: f32 = 1e-4;
// The flag in a pixel's count word: the host evaluates the pixel.
const HOST: u32 = 0x80000000u;
// Per-mesh slots per pixel (src/render/gpu/mesh.rs's SLOTS), of SLOT_WORDS words.
const SLOTS: u32 = 6u;
const SLOT_WORDS: u32 = 3u;
// A slot's first word: the mesh + 1 in the low ID_BITS bits (meshes number at most 65 536), structure
// bits above.
const ID_BITS: u32 = 17u;
const ID_MASK: u32 = 0x1ffffu;

// One triangle as both passes see it.
struct Tri {
    // Projected corners as hi + lo (px), depths z and z − z_ref (mm).
    hi: array<vec2<f32>, 3>,
    lo: array<vec2<f32>, 3>,
    z: array<f32, 3>,
    dz: array<f32, 3>,
    // Per edge (k → k+1): the corner it is evaluated from, its direction from there, and the factor
    // (±1) that orients it inside-positive.
    anchor: array<u32, 3>,
    dir: array<vec2<f32>, 3>,
    orient: array<f32, 3>,
    // Per edge: whether it owns pixel centres exactly on it.
    own: array<bool, 3>,
    // Faces the source (its crossings are entries).
    entry: bool,
    // Its pixel box within the image: first and last column (xy) and row (zw).
    box: vec4<u32>,
    // False when it covers no pixel centre (degenerate, or its box misses the image).
    live: bool,
}

// The edge function of edge (p, q) at pixel offset o from p: (q − p) × o. `d` is q − p.
fn edge_at(d: vec2<f32>, o: vec2<f32>) -> f32 {
    return d.x * o.y - d.y * o.x;
}

// Whether an oriented edge of direction d (inside on the left: E = d × o > 0) owns pixels exactly on it:
// the CPU's rule on E(u, v) = a·u + b·v + c with a = −d.y, b = d.x.
fn owns(d: vec2<f32>) -> bool {
    return (-d.y > 0.0) || (d.y == 0.0 && d.x > 0.0);
}

// Triangle t's index from the invocation.
fn triangle_index(gid: vec3<u32>, groups: vec3<u32>) -> u32 {
    return gid.x + gid.y * groups.x * 64u;
}

fn setup(t: u32) -> Tri {
    var r: Tri;
    r.live = false;
    let idx = tris[t].xyz;
    for (var i = 0u; i < 3u; i++) {
        let a = verts[2u * idx[i]];
        let b = verts[2u * idx[i] + 1u];
        r.hi[i] = a.xy;
        r.lo[i] = a.zw;
        r.z[i] = b.x;
        r.dz[i] = b.y;
    }
    // Twice the signed area: the orientation (exits have S > 0, entries S < 0, as det on the CPU).
    let d01 = (r.hi[1] - r.hi[0]) + (r.lo[1] - r.lo[0]);
    let d02 = (r.hi[2] - r.hi[0]) + (r.lo[2] - r.lo[0]);
    let s_area = d01.x * d02.y - d01.y * d02.x;
    if !(s_area != 0.0) || abs(s_area) > 3.0e38 {
        return r;
    }
    let sign = select(-1.0, 1.0, s_area > 0.0);
    r.entry = s_area < 0.0;
    for (var k = 0u; k < 3u; k++) {
        let k1 = (k + 1u) % 3u;
        var p = k;
        var q = k1;
        var flip = 1.0;
        if idx[k1] < idx[k] {
            p = k1;
            q = k;
            flip = -1.0;
        }
        r.anchor[k] = p;
        r.dir[k] = (r.hi[q] - r.hi[p]) + (r.lo[q] - r.lo[p]);
        r.orient[k] = flip * sign;
        r.own[k] = owns(r.dir[k] * r.orient[k]);
    }
    let w = G.image.x;
    let h = G.image.y;
    let pmin = min(min(r.hi[0], r.hi[1]), r.hi[2]) - MARGIN;
    let pmax = max(max(r.hi[0], r.hi[1]), r.hi[2]) + MARGIN;
    if pmax.x < 0.0 || pmax.y < 0.0 || pmin.x > f32(w - 1u) || pmin.y > f32(h - 1u) {
        return r;
    }
    r.box = vec4<u32>(
        u32(max(ceil(pmin.x), 0.0)),
        u32(min(floor(pmax.x), f32(w - 1u))),
        u32(max(ceil(pmin.y), 0.0)),
        u32(min(floor(pmax.y), f32(h - 1u))),
    );
    r.live = r.box.x <= r.box.y && r.box.z <= r.box.w;
    return r;
}

// The oriented edge functions of pixel (u, v) (inside: all positive).
fn edges(r: Tri, u: u32, v: u32) -> vec3<f32> {
    let p = vec2<f32>(f32(u), f32(v));
    var e: vec3<f32>;
    for (var k = 0u; k < 3u; k++) {
        let a = r.anchor[k];
        e[k] = edge_at(r.dir[k], (p - r.hi[a]) - r.lo[a]) * r.orient[k];
    }
    return e;
}

// Whether the pixel with edge functions e lies inside the triangle grown by NEAR_PX, and whether it
// lies within NEAR_PX of an edge (E / |d| is the distance from the edge's line, px).
fn near_edge(r: Tri, e: vec3<f32>) -> vec2<bool> {
    var grown = true;
    var near = false;
    for (var k = 0u; k < 3u; k++) {
        let tol = NEAR_PX * length(r.dir[k]);
        grown = grown && e[k] > -tol;
        near = near || abs(e[k]) <= tol;
    }
    return vec2<bool>(grown, near);
}

@compute @workgroup_size(64, 1, 1)
fn rasterise(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let t = triangle_index(gid, groups);
    if t >= G.image.z {
        return;
    }
    let r = setup(t);
    if !r.live {
        return;
    }
    let g = tris[t].w & 0xffffu;
    let label = (tris[t].w >> 16u) & 0xffu;
    let implant = ((tris[t].w >> 24u) & 1u) != 0u;
    let mu = bitcast<f32>(meshes[g].x);
    let s = select(1, -1, r.entry);
    let weight = f32(s) * mu * G.scale.x;
    let zlo = min(min(r.dz[0], r.dz[1]), r.dz[2]);
    let zhi = max(max(r.dz[0], r.dz[1]), r.dz[2]);
    let w = G.image.x;
    let stride = G.image.w;
    for (var v = r.box.z; v <= r.box.w; v++) {
        for (var u = r.box.x; u <= r.box.y; u++) {
            let e = edges(r, u, v);
            let pix = (v * w + u) * stride;
            let near = near_edge(r, e);
            // An implant displaces what it occupies: the length of every other mesh inside it is not
            // counted, which a sum cannot tell. Every pixel it may cover goes to the host, which pairs
            // its crossings as the CPU does.
            if near.x && (near.y || implant) {
                atomicOr(&acc[pix + 3u], HOST);
            }
            var inside = true;
            for (var k = 0u; k < 3u; k++) {
                inside = inside && (e[k] > 0.0 || (e[k] == 0.0 && r.own[k]));
            }
            if !inside {
                continue;
            }
            // Barycentric weights: vertex i's is the edge opposite it (edge i+1) over the sum.
            let total = e[0] + e[1] + e[2];
            let l0 = e[1] / total;
            let l1 = e[2] / total;
            let l2 = e[0] / total;
            let zp = 1.0 / (l0 / r.z[0] + l1 / r.z[1] + l2 / r.z[2]);
            let d1 = (r.dz[1] - r.dz[0]) / r.z[1];
            let d2 = (r.dz[2] - r.dz[0]) / r.z[2];
            let rel = clamp(r.dz[0] + zp * (l1 * d1 + l2 * d2), zlo, zhi);
            let q = i32(round(weight * rel));
            atomicAdd(&acc[pix], bitcast<u32>(q));
            atomicAdd(&acc[pix + 1u], bitcast<u32>(s));
            atomicAdd(&acc[pix + 2u], bitcast<u32>(s * i32(g)));
            atomicAdd(&acc[pix + 3u], 1u);
            if stride > 4u {
                add_to_slot(pix, g, i32(round(f32(s) * rel * G.scale.y)), r.z[0] + (rel - r.dz[0]), label);
            }
        }
    }
}

// Claims the slot at word b for mesh id (mesh + 1), or finds it already claimed by it.
fn claim(b: u32, id: u32) -> bool {
    loop {
        let r = atomicCompareExchangeWeak(&acc[b], 0u, id);
        if r.exchanged || (r.old_value & ID_MASK) == id {
            return true;
        }
        if r.old_value != 0u {
            return false;
        }
    }
    return false;
}

// Adds a crossing of mesh g (signed chord term dq, depth z, structure label) to pixel pix's slot of g,
// or flags the pixel for the host when its slots are taken by other meshes.
fn add_to_slot(pix: u32, g: u32, dq: i32, z: f32, label: u32) {
    for (var j = 0u; j < SLOTS; j++) {
        let b = pix + 4u + SLOT_WORDS * j;
        if claim(b, g + 1u) {
            atomicOr(&acc[b], 1u << (ID_BITS + label));
            atomicAdd(&acc[b + 1u], bitcast<u32>(dq));
            atomicMax(&acc[b + 2u], ~bitcast<u32>(z));
            return;
        }
    }
    atomicOr(&acc[pix + 3u], HOST);
}

// Whether the pixel at word a can be taken from the sums: balanced, not flagged, and no mesh's chord
// within rounding of the silhouette threshold.
fn clean(a: u32, stride: u32) -> bool {
    if atomicLoad(&acc[a + 1u]) != 0u || atomicLoad(&acc[a + 2u]) != 0u
        || (atomicLoad(&acc[a + 3u]) & HOST) != 0u {
        return false;
    }
    if stride > 4u {
        for (var j = 0u; j < SLOTS; j++) {
            let b = a + 4u + SLOT_WORDS * j;
            let c = bitcast<i32>(atomicLoad(&acc[b + 1u]));
            if atomicLoad(&acc[b]) != 0u && c >= bitcast<i32>(G.list.y) && c <= bitcast<i32>(G.list.z) {
                return false;
            }
        }
    }
    return true;
}

// After `rasterise`: lists (pixel, triangle) for every pixel the host must evaluate (not `clean`) and
// every triangle that pixel lies in, on, or within NEAR_PX of.
@compute @workgroup_size(64, 1, 1)
fn collect(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let t = triangle_index(gid, groups);
    if t >= G.image.z {
        return;
    }
    let r = setup(t);
    if !r.live {
        return;
    }
    let w = G.image.x;
    let stride = G.image.w;
    for (var v = r.box.z; v <= r.box.w; v++) {
        for (var u = r.box.x; u <= r.box.y; u++) {
            let pix = v * w + u;
            let a = pix * stride;
            if clean(a, stride) {
                continue;
            }
            if !near_edge(r, edges(r, u, v)).x {
                continue;
            }
            let k = atomicAdd(&list[0], 1u);
            if k < G.list.x {
                atomicStore(&list[1u + 2u * k], pix);
                atomicStore(&list[2u + 2u * k], t);
            }
        }
    }
}

var<workgroup> finished: atomic<u32>;
var<workgroup> finished_hits: atomic<u32>;

// After `rasterise`: each pixel's line integral, Σ ± μ·depth times the ray's length per unit depth
// |K⁻¹ [u, v, 1]ᵀ|, into `image`, and with the slots its silhouettes and depth into `extra` (a mesh
// counts when its chord along the ray passes the threshold: outside the band `clean` sends to the host,
// f32 decides that as the host's f64 does), so that the host reads back one f32 (with the slots, five
// words) per pixel instead of every word of `acc` and finishes only the pixels listed in `host` (not
// `clean`; their triangles are in `list`). The line integral's f32 conversion and product round to within
// 2 ulp of the host's f64.
@compute @workgroup_size(64, 1, 1)
fn finish(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
) {
    if lid == 0u {
        atomicStore(&finished, 0u);
        atomicStore(&finished_hits, 0u);
    }
    workgroupBarrier();
    let w = G.image.x;
    let stride = G.image.w;
    let pix = triangle_index(gid, groups);
    if pix < w * G.image.y {
        let a = pix * stride;
        let count = atomicLoad(&acc[a + 3u]) & ~HOST;
        var value = 0.0;
        // Depth (+inf: none), object bits (two words), structure bits.
        var more = vec4<u32>(0x7f800000u, 0u, 0u, 0u);
        if atomicLoad(&acc[a + 3u]) != 0u {
            if clean(a, stride) {
                let p = vec3<f32>(f32(pix % w), f32(pix / w), 1.0);
                let path = length(vec3<f32>(dot(G.ray_x.xyz, p), dot(G.ray_y.xyz, p), 1.0));
                value = f32(bitcast<i32>(atomicLoad(&acc[a]))) / G.scale.x * path;
                if stride > 4u {
                    more = silhouettes(a, path);
                }
                atomicAdd(&finished, 1u);
                atomicAdd(&finished_hits, count);
            } else {
                let k = atomicAdd(&host[0], 1u);
                if k < G.list.x {
                    atomicStore(&host[4u + k], pix);
                }
            }
        }
        image[pix] = value;
        if stride > 4u {
            for (var k = 0u; k < 4u; k++) {
                extra[4u * pix + k] = more[k];
            }
        }
    }
    workgroupBarrier();
    if lid == 0u {
        atomicAdd(&host[1], atomicLoad(&finished));
        let hits = atomicLoad(&finished_hits);
        if atomicAdd(&host[2], hits) > 0xffffffffu - hits {
            atomicAdd(&host[3], 1u);
        }
    }
}

// A clean pixel's silhouettes from its slots (the host's rule): the meshes whose chord along the ray
// (depth chord × path per unit depth) passes the threshold give their object and structure bits and their
// nearest crossing's depth. Returns (depth bits, object bits low, high, structure bits).
fn silhouettes(a: u32, path: f32) -> vec4<u32> {
    var first = bitcast<f32>(0x7f800000u);
    var bits = vec3<u32>(0u, 0u, 0u);
    for (var j = 0u; j < SLOTS; j++) {
        let b = a + 4u + SLOT_WORDS * j;
        let id = atomicLoad(&acc[b]);
        if id == 0u {
            continue;
        }
        let chord = f32(bitcast<i32>(atomicLoad(&acc[b + 1u]))) / G.scale.y;
        if chord * path > G.scale.z {
            let object = meshes[(id & ID_MASK) - 1u].y;
            if object < 32u {
                bits.x |= 1u << object;
            } else {
                bits.y |= 1u << (object - 32u);
            }
            bits.z |= id >> ID_BITS;
            first = min(first, bitcast<f32>(~atomicLoad(&acc[b + 2u])));
        }
    }
    return vec4<u32>(bitcast<u32>(first), bits);
}
