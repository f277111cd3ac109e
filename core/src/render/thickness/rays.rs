//! One traced ray's integral: the raw hits of a packet lane refined and paired into `Σ μ L`
//! ([`integrate_lane`], the one place a traced ray is integrated), and a single ray traced on its own
//! ([`trace_single`], for repairs and for tools that aim rays at chosen points).

use glam::DVec3;

use crate::render::pairing::{Crossing, RayIntegral, integrate};
use crate::render::scene::RenderScene;
use crate::render::tracer::{HitTracer, PACKET, RawHit, RayPacket};

/// Per-thread buffers of traced rays.
pub(super) struct Scratch {
    pub hits: [Vec<RawHit>; PACKET],
    crossings: Vec<Crossing>,
}

impl Scratch {
    pub fn new() -> Self {
        Scratch {
            hits: std::array::from_fn(|_| Vec::with_capacity(32)),
            crossings: Vec::with_capacity(64),
        }
    }
}

/// The integral of ray `lane` of `packet`, whose hits a tracer wrote into `scratch.hits`.
pub(super) fn integrate_lane(
    scene: &RenderScene,
    packet: &RayPacket,
    lane: usize,
    scratch: &mut Scratch,
) -> RayIntegral {
    integrate(
        scene,
        packet.origin[lane],
        packet.dir[lane],
        &scratch.hits[lane],
        &mut scratch.crossings,
    )
}

/// Traces one ray (world frame, unit `dir`) with `tracer` and integrates it.
pub(super) fn trace_single(
    tracer: &dyn HitTracer,
    scene: &RenderScene,
    origin: DVec3,
    dir: DVec3,
    scratch: &mut Scratch,
) -> RayIntegral {
    let mut packet = RayPacket::default();
    packet.push(origin, dir);
    tracer.trace_all(&packet, &mut scratch.hits);
    integrate_lane(scene, &packet, 0, scratch)
}
