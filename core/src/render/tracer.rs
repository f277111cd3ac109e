//! The interface every ray-tracing backend implements: gather all hits of a packet of rays.

use glam::DVec3;

/// Widest packet a backend is handed at once.
pub const PACKET: usize = 8;

/// One ray–triangle hit as the backend found it. `t` is approximate (a backend may trace in f32): the
/// renderer recomputes the exact distance in f64 from the triangle's plane, so backends only need to
/// find *which* triangles a ray crosses.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawHit {
    pub t: f64,
    pub geom: u32,
    pub prim: u32,
}

/// Up to [`PACKET`] rays sharing nothing but the call (structure of arrays is the backend's business).
#[derive(Debug, Clone, Copy)]
pub struct RayPacket {
    pub len: usize,
    pub origin: [DVec3; PACKET],
    pub dir: [DVec3; PACKET],
}

impl Default for RayPacket {
    fn default() -> Self {
        RayPacket {
            len: 0,
            origin: [DVec3::ZERO; PACKET],
            dir: [DVec3::ZERO; PACKET],
        }
    }
}

impl RayPacket {
    pub fn push(&mut self, origin: DVec3, dir: DVec3) {
        self.origin[self.len] = origin;
        self.dir[self.len] = dir;
        self.len += 1;
    }
}

/// A ray-tracing backend that reports every hit along each ray (no closest-hit culling).
pub trait HitTracer: Send + Sync {
    /// Short name for reports (`embree`, `bvh`).
    fn name(&self) -> &'static str;
    /// Appends every hit of ray `i` of the packet to `hits[i]` (lists are cleared by the callee).
    fn trace_all(&self, packet: &RayPacket, hits: &mut [Vec<RawHit>; PACKET]);
    /// Time the acceleration structure took to build (ms).
    fn build_ms(&self) -> f64;
}
