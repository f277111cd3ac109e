//! The benchmark floor of the thickness renderer: Embree's own closest-hit query for exactly the rays a
//! traced render shoots (same tiles, same culling, same packets), so the benchmark can say how close the
//! all-hits render comes to the cheapest query Embree answers.

use std::time::Instant;

use rayon::prelude::*;

use super::EmbreeScene;
use crate::geometry::View;
use crate::io::ImageF32;
use crate::render::scene::RenderScene;
use crate::render::thickness::ThicknessOptions;
use crate::render::thickness::tiles::{Camera, TILE, TilePlan};
use crate::render::tracer::PACKET;

impl EmbreeScene {
    /// The first-hit distance image of `view` for the pixels a traced render of `scene` with `opts`
    /// would trace, and its time (ms). `self` must be built from `scene` without hit recording.
    pub fn first_hit_floor(
        &self,
        scene: &RenderScene,
        view: &View,
        opts: &ThicknessOptions,
    ) -> (ImageF32, f64) {
        let start = Instant::now();
        let cam = Camera::new(view);
        let plan = TilePlan::new(scene, view, opts.cull);
        let w = cam.width as usize;
        let mut img = ImageF32::zeros(cam.width, cam.height);
        img.data
            .par_chunks_mut(w * TILE as usize)
            .enumerate()
            .for_each(|(ty, band)| {
                let rows = band.len() / w;
                let mut t = [0f32; PACKET];
                plan.for_each_packet(&cam, ty, rows, |packet, pixels| {
                    self.first_hit(packet, &mut t);
                    for (lane, &(u, r)) in pixels.iter().enumerate() {
                        band[r * w + u] = t[lane];
                    }
                });
            });
        (img, start.elapsed().as_secs_f64() * 1e3)
    }
}
