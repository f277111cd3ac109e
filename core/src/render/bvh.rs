//! The reference backend: a pure-Rust f64 bounding-volume hierarchy with the watertight ray–triangle test
//! of Woop, Benthin and Wald (JCGT 2013). It shares the renderer with Embree and serves as its test oracle
//! and as the second entry of the backend benchmarks.

use std::time::Instant;

use glam::DVec3;

use super::scene::RenderScene;
use super::tracer::{HitTracer, PACKET, RawHit, RayPacket};

const LEAF_SIZE: usize = 4;
const BINS: usize = 12;

#[derive(Debug, Clone, Copy)]
struct Aabb {
    lo: DVec3,
    hi: DVec3,
}

impl Aabb {
    const EMPTY: Aabb = Aabb {
        lo: DVec3::splat(f64::INFINITY),
        hi: DVec3::splat(f64::NEG_INFINITY),
    };
    fn grow(&mut self, p: DVec3) {
        self.lo = self.lo.min(p);
        self.hi = self.hi.max(p);
    }
    fn merge(&mut self, o: &Aabb) {
        self.lo = self.lo.min(o.lo);
        self.hi = self.hi.max(o.hi);
    }
    fn area(&self) -> f64 {
        let d = (self.hi - self.lo).max(DVec3::ZERO);
        2.0 * (d.x * d.y + d.y * d.z + d.z * d.x)
    }
}

/// A node: an inner node's children are `first` and `first + 1`; a leaf holds `count` triangles from
/// `first` in the reordered triangle list.
#[derive(Debug, Clone, Copy)]
struct Node {
    bounds: Aabb,
    first: u32,
    count: u32,
}

#[derive(Debug, Clone, Copy)]
struct Tri {
    v: [DVec3; 3],
    geom: u32,
    prim: u32,
}

/// The pure-Rust all-hits backend.
pub struct BvhTracer {
    nodes: Vec<Node>,
    tris: Vec<Tri>,
    build_ms: f64,
}

impl BvhTracer {
    /// Builds a binned-SAH BVH over every triangle of the scene.
    pub fn new(scene: &RenderScene) -> Self {
        let start = Instant::now();
        let mut tris: Vec<Tri> = Vec::with_capacity(scene.triangle_count());
        for (g, m) in scene.meshes.iter().enumerate() {
            for p in 0..m.mesh.triangles.len() {
                tris.push(Tri {
                    v: m.mesh.corners(p),
                    geom: g as u32,
                    prim: p as u32,
                });
            }
        }
        let mut nodes = vec![Node {
            bounds: Aabb::EMPTY,
            first: 0,
            count: tris.len() as u32,
        }];
        let mut centroids: Vec<DVec3> = tris
            .iter()
            .map(|t| (t.v[0] + t.v[1] + t.v[2]) / 3.0)
            .collect();
        let mut stack = vec![0usize];
        while let Some(n) = stack.pop() {
            let (first, count) = (nodes[n].first as usize, nodes[n].count as usize);
            let mut b = Aabb::EMPTY;
            for t in &tris[first..first + count] {
                t.v.iter().for_each(|&p| b.grow(p));
            }
            nodes[n].bounds = b;
            if count <= LEAF_SIZE {
                continue;
            }
            let Some(mid) = split(
                &mut tris[first..first + count],
                &mut centroids[first..first + count],
            ) else {
                continue;
            };
            let left = nodes.len();
            nodes.push(Node {
                bounds: Aabb::EMPTY,
                first: first as u32,
                count: mid as u32,
            });
            nodes.push(Node {
                bounds: Aabb::EMPTY,
                first: (first + mid) as u32,
                count: (count - mid) as u32,
            });
            nodes[n] = Node {
                bounds: b,
                first: left as u32,
                count: 0,
            };
            stack.push(left);
            stack.push(left + 1);
        }
        BvhTracer {
            nodes,
            tris,
            build_ms: start.elapsed().as_secs_f64() * 1e3,
        }
    }

    /// Appends every hit of one ray.
    fn trace_one(&self, org: DVec3, dir: DVec3, out: &mut Vec<RawHit>) {
        let inv = dir.recip();
        let wt = Watertight::new(dir);
        let mut stack: Vec<u32> = Vec::with_capacity(64);
        stack.push(0);
        while let Some(i) = stack.pop() {
            let node = &self.nodes[i as usize];
            if !slab(&node.bounds, org, inv) {
                continue;
            }
            if node.count == 0 {
                stack.push(node.first);
                stack.push(node.first + 1);
                continue;
            }
            for t in &self.tris[node.first as usize..(node.first + node.count) as usize] {
                if let Some(d) = wt.intersect(org, t.v) {
                    out.push(RawHit {
                        t: d,
                        geom: t.geom,
                        prim: t.prim,
                    });
                }
            }
        }
    }
}

/// Binned SAH split of a triangle range; returns the size of the left part, or `None` for a leaf.
fn split(tris: &mut [Tri], centroids: &mut [DVec3]) -> Option<usize> {
    let mut cb = Aabb::EMPTY;
    centroids.iter().for_each(|&c| cb.grow(c));
    let ext = cb.hi - cb.lo;
    let axis = if ext.x >= ext.y && ext.x >= ext.z {
        0
    } else if ext.y >= ext.z {
        1
    } else {
        2
    };
    if ext[axis] <= 0.0 {
        return None;
    }
    let bin_of =
        |c: DVec3| (((c[axis] - cb.lo[axis]) / ext[axis] * BINS as f64) as usize).min(BINS - 1);
    let mut bins = [(Aabb::EMPTY, 0usize); BINS];
    for (t, &c) in tris.iter().zip(centroids.iter()) {
        let b = &mut bins[bin_of(c)];
        t.v.iter().for_each(|&p| b.0.grow(p));
        b.1 += 1;
    }
    let mut best = (f64::INFINITY, 0);
    for s in 1..BINS {
        let (mut l, mut r) = (Aabb::EMPTY, Aabb::EMPTY);
        let (mut nl, mut nr) = (0, 0);
        for b in &bins[..s] {
            l.merge(&b.0);
            nl += b.1;
        }
        for b in &bins[s..] {
            r.merge(&b.0);
            nr += b.1;
        }
        if nl == 0 || nr == 0 {
            continue;
        }
        let cost = l.area() * nl as f64 + r.area() * nr as f64;
        if cost < best.0 {
            best = (cost, s);
        }
    }
    if best.0.is_infinite() {
        return None;
    }
    // Partition in place, keeping centroids in step with triangles.
    let mut i = 0;
    let mut j = tris.len();
    while i < j {
        if bin_of(centroids[i]) < best.1 {
            i += 1;
        } else {
            j -= 1;
            tris.swap(i, j);
            centroids.swap(i, j);
        }
    }
    Some(i)
}

/// Ray–box slab test (inclusive, so rays grazing a face are not lost).
#[inline]
fn slab(b: &Aabb, org: DVec3, inv: DVec3) -> bool {
    let t0 = (b.lo - org) * inv;
    let t1 = (b.hi - org) * inv;
    let tmin = t0.min(t1);
    let tmax = t0.max(t1);
    // f64::min/max ignore a NaN (0 · ∞ for an axis-parallel ray on a slab plane), keeping the box.
    let near = tmin.x.max(tmin.y).max(tmin.z).max(0.0);
    let far = tmax.x.min(tmax.y).min(tmax.z);
    near <= far
}

/// Per-ray constants of the watertight test: the ray is sheared to +z so edge functions are exact
/// 2D cross products, evaluated identically for a shared edge from both sides.
struct Watertight {
    k: [usize; 3],
    s: DVec3,
}

impl Watertight {
    fn new(dir: DVec3) -> Self {
        let a = dir.abs();
        let kz = if a.x >= a.y && a.x >= a.z {
            0
        } else if a.y >= a.z {
            1
        } else {
            2
        };
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        if dir[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        Watertight {
            k: [kx, ky, kz],
            s: DVec3::new(dir[kx] / dir[kz], dir[ky] / dir[kz], 1.0 / dir[kz]),
        }
    }

    #[inline]
    fn intersect(&self, org: DVec3, v: [DVec3; 3]) -> Option<f64> {
        let [kx, ky, kz] = self.k;
        let s = self.s;
        let a = v[0] - org;
        let b = v[1] - org;
        let c = v[2] - org;
        let (ax, ay) = (a[kx] - s.x * a[kz], a[ky] - s.y * a[kz]);
        let (bx, by) = (b[kx] - s.x * b[kz], b[ky] - s.y * b[kz]);
        let (cx, cy) = (c[kx] - s.x * c[kz], c[ky] - s.y * c[kz]);
        let u = cx * by - cy * bx;
        let w_v = ax * cy - ay * cx;
        let w = bx * ay - by * ax;
        if (u < 0.0 || w_v < 0.0 || w < 0.0) && (u > 0.0 || w_v > 0.0 || w > 0.0) {
            return None;
        }
        let det = u + w_v + w;
        if det == 0.0 {
            return None;
        }
        let t = (u * s.z * a[kz] + w_v * s.z * b[kz] + w * s.z * c[kz]) / det;
        (t > 0.0).then_some(t)
    }
}

impl HitTracer for BvhTracer {
    fn name(&self) -> &'static str {
        "bvh"
    }

    fn build_ms(&self) -> f64 {
        self.build_ms
    }

    fn trace_all(&self, packet: &RayPacket, hits: &mut [Vec<RawHit>; PACKET]) {
        for (i, out) in hits.iter_mut().enumerate().take(packet.len) {
            out.clear();
            self.trace_one(packet.origin[i], packet.dir[i], out);
        }
    }
}
