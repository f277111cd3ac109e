//! The intensity registration's loop on the GPU for an anatomy on the gpu backend: per evaluation the
//! moving DRRs, the pyramid's box average, the smoothing and the similarity run there ([`DeviceLevel`],
//! `level.wgsl`), and so do the Levenberg–Marquardt products — the forward-difference Jacobian (its six
//! poses in one dispatch of each shader where the buffers can hold them), `JᵀJ`,
//! `Jᵀr` and Broyden's updates (`lm.rs`, `lm.wgsl`): the residuals never leave the GPU, and an evaluation
//! reads back two numbers per block and view, a Jacobian's normal equations 27 per chunk of rows.
//!
//! A CT's DRRs render in the level's own dispatches; mesh DRRs leave a few pixels to the host
//! (`render::thickness::gpu`), which evaluates them and writes them into the image on the GPU, so for
//! meshes the lists of those pixels come back and their values go up, never the images ([`Source`]).

mod level;
mod lm;
mod lm_kernels;
mod source;

pub use level::{DeviceLevel, DeviceResidual};
pub use lm::DeviceJacobian;
pub use source::Source;

/// Invocations per workgroup of `level.wgsl` and `lm.wgsl`.
const GROUP: u32 = 256;

/// The dispatch of one invocation per element of `n`: workgroups `(x, y, 1)`, at most `max` a side
/// (the shaders index `x + y · nwg.x · GROUP`).
fn grid(n: u64, max: u32) -> [u32; 3] {
    let groups = n.div_ceil(u64::from(GROUP)).max(1);
    let x = groups.min(u64::from(max));
    [x as u32, groups.div_ceil(x) as u32, 1]
}
