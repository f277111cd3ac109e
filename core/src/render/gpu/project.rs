//! Mesh vertices projected on the GPU (`project.wgsl`), for adapters with `SHADER_F64`: the model's
//! vertices are uploaded once in f64, and a render uploads the view's pose, K and each mesh's reference
//! depth instead of every projected vertex (32 bytes a vertex: 7.4 MB a render of the L1–L5 phantom).

use bytemuck::{Pod, Zeroable};

use super::{
    GpuContext, READ, UNIFORM, WRITE, bind_buffers, buffer_layout, compute_pipeline, storage_init,
    uniform_init,
};
use crate::geometry::View;
use crate::render::scene::RenderScene;

/// `Pose` in project.wgsl.
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Pose {
    rows: [[f64; 4]; 3],
    k: [f64; 4],
    k2: [f64; 4],
}

/// Invocations per workgroup (`@workgroup_size(64, 1, 1)` in project.wgsl).
const WORKGROUP: u32 = 64;

/// A scene's vertices on the GPU in f64 and the pipeline that projects them.
pub(super) struct Projector {
    layout: wgpu::BindGroupLayout,
    pipeline: wgpu::ComputePipeline,
    model: wgpu::Buffer,
    vmesh: wgpu::Buffer,
    vertices: u32,
}

impl Projector {
    /// Uploads `scene`'s vertices (world frame, f64) and each one's mesh, and compiles the shader; to be
    /// called only on a device with `SHADER_F64`.
    pub fn new(ctx: &GpuContext, scene: &RenderScene) -> Projector {
        let device = &ctx.device;
        let mut model: Vec<[f64; 4]> = Vec::new();
        let mut vmesh: Vec<u32> = Vec::new();
        for (g, m) in scene.meshes.iter().enumerate() {
            model.extend(m.mesh.vertices.iter().map(|p| [p.x, p.y, p.z, 0.0]));
            vmesh.extend(std::iter::repeat_n(g as u32, m.mesh.vertices.len()));
        }
        let vertices = model.len() as u32;
        let model = storage_init(device, "mesh vertices (f64)", bytemuck::cast_slice(&model));
        let vmesh = storage_init(device, "mesh of each vertex", bytemuck::cast_slice(&vmesh));
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("project.wgsl"),
            source: wgpu::ShaderSource::Wgsl(include_str!("project.wgsl").into()),
        });
        let (layout, pipeline_layout) =
            buffer_layout(device, "project", &[UNIFORM, READ, READ, READ, WRITE]);
        let pipeline = compute_pipeline(device, &pipeline_layout, &module, "project");
        Projector {
            layout,
            pipeline,
            model,
            vmesh,
            vertices,
        }
    }

    /// Records the projection of every vertex through `view` into `verts` (mesh.wgsl's layout), with
    /// mesh `g`'s reference depth `z_ref[g]`.
    pub fn encode(
        &self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        view: &View,
        z_ref: &[f64],
        verts: &wgpu::Buffer,
    ) {
        if self.vertices == 0 {
            return;
        }
        let (r, t) = (
            view.world_to_camera.rotation,
            view.world_to_camera.translation,
        );
        let k = &view.intrinsics;
        let pose = Pose {
            rows: std::array::from_fn(|i| [r.x_axis[i], r.y_axis[i], r.z_axis[i], t[i]]),
            k: [k.fx, k.fy, k.skew, k.cx],
            k2: [k.cy, f64::from(self.vertices), 0.0, 0.0],
        };
        let device = &ctx.device;
        let uniform = uniform_init(device, "projection", bytemuck::bytes_of(&pose));
        let z_ref = storage_init(device, "reference depths", bytemuck::cast_slice(z_ref));
        let bind = bind_buffers(
            device,
            "project",
            &self.layout,
            &[&uniform, &self.model, &self.vmesh, &z_ref, verts],
        );
        let groups = self.vertices.div_ceil(WORKGROUP);
        let max = ctx.max_workgroups();
        let mut pass = encoder.begin_compute_pass(&Default::default());
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &bind, &[]);
        pass.dispatch_workgroups(groups.min(max), groups.div_ceil(max), 1);
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use glam::DVec3;

    use crate::anatomy::TriMesh;
    use crate::geometry::{CArm, View};
    use crate::render::gpu::{GpuContext, GpuMeshRenderer};
    use crate::render::{RenderScene, SceneMesh};

    /// The vertices projected on the GPU (f64) and by the host give the same sums: the line integrals,
    /// and with the slots the depth and silhouettes, of every pixel neither leaves to the host, on a
    /// sphere inside a box and a second box, in AP and LAT. (Without `SHADER_F64` only the host
    /// projects, and there is nothing to compare.)
    #[test]
    fn gpu_and_host_projections_give_the_same_sums() {
        let ctx = GpuContext::shared().unwrap();
        if !ctx.has_f64() {
            return;
        }
        let meshes = [
            (
                TriMesh::cuboid("box", DVec3::splat(-30.0), DVec3::splat(30.0)),
                0.5,
            ),
            (
                TriMesh::icosphere("ball", DVec3::new(4.0, -3.0, 2.0), 18.0, 4),
                1.5,
            ),
            (
                TriMesh::cuboid(
                    "other",
                    DVec3::new(35.0, -10.0, -40.0),
                    DVec3::new(60.0, 25.0, 5.0),
                ),
                1.0,
            ),
        ];
        let scene = RenderScene::new(
            meshes
                .into_iter()
                .map(|(m, mu)| SceneMesh {
                    mesh: Arc::new(m),
                    mu_per_mm: mu,
                    object: "o".into(),
                })
                .collect(),
        )
        .unwrap();
        let mut gpu = GpuMeshRenderer::new(ctx, &scene).unwrap();
        assert!(gpu.project.is_some());
        let carm = CArm::default_paper();
        for name in ["ap", "lat"] {
            // The detector binned by 4 (256² px; the pixel centre mapping of registration's pyramid).
            let detector = carm.view(name).unwrap();
            let mut k = detector.intrinsics;
            (k.fx, k.fy, k.skew) = (k.fx / 4.0, k.fy / 4.0, k.skew / 4.0);
            (k.cx, k.cy) = ((k.cx - 1.5) / 4.0, (k.cy - 1.5) / 4.0);
            (k.width, k.height) = (k.width / 4, k.height / 4);
            let view = View {
                intrinsics: k,
                ..detector.clone()
            };
            for full in [false, true] {
                let project = gpu.project.take();
                let host = gpu.rasterise(&scene, &view, full).unwrap().unwrap();
                gpu.project = project;
                let on_gpu = gpu.rasterise(&scene, &view, full).unwrap().unwrap();
                let (a, b) = (host.finished, on_gpu.finished);
                let peak = a.image.iter().fold(0f32, |m, &x| m.max(x));
                assert!(peak > 20.0, "{name}: the boxes must be in view ({peak})");
                let mut compared = 0;
                for (i, (x, y)) in a.image.iter().zip(&b.image).enumerate() {
                    let i = i as u32;
                    if a.pixels.binary_search(&i).is_ok() || b.pixels.binary_search(&i).is_ok() {
                        continue;
                    }
                    // f32 values to ~60 μ·mm; the two fixed-point scales may differ by a power of two.
                    assert!((x - y).abs() <= 1e-4, "{name}: pixel {i}: {x} vs {y}");
                    compared += u32::from(*x > 0.0);
                    if full {
                        // Depth (f32 bits), object and structure bits.
                        let k = 4 * i as usize;
                        assert_eq!(a.extra[k..k + 4], b.extra[k..k + 4], "{name}: pixel {i}");
                    }
                }
                assert!(compared > 1000, "{name}: {compared} pixels compared");
                assert_eq!(a.rays, b.rays, "{name}");
                assert_eq!(a.extra.len(), if full { 4 * a.image.len() } else { 0 });
            }
        }
    }
}
