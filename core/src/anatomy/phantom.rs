//! The parametric lumbar phantom: vertebrae stacked with discs and lordosis, an optional soft-tissue
//! outline, all meshed by the watertight isosurface extractor.
//!
//! **Placement rule.** Each vertebra is built in its local frame ([`super::vertebra`]: body centre at
//! the origin, RAS+ axes). The *middle requested level* — index `(n − 1) / 2` of the sorted requested
//! levels, so L3 for `L1-L5` and the level itself for a single level — has the identity pose: its body
//! centre is the world origin and its axes are the world axes. Every level `L` is tilted about the
//! x axis by `θ_L = lordosis·(i_mid − i_L)` (degrees, `i` = 0 for L1), positive tilting its superior axis
//! toward posterior, so the column is convex anteriorly (lordosis). Adjacent levels are stacked along the
//! mean of their axes with a disc of `disc_mm` between the inferior endplate centre of the upper and the
//! superior endplate centre of the lower vertebra; positions of skipped levels (`L1,L3`) are kept
//! anatomical.
//!
//! **Tissues.** Cortical bone is the shell between the outer surface `f = 0` and the inner surface
//! `f = −cortical_mm` of a vertebra's SDF `f`; cancellous bone is inside the inner surface. Discs are
//! wedges between the endplate planes; the soft-tissue outline is an elliptic cylinder around the spine.

use glam::{DMat3, DMat4, DVec2, DVec3};
use rayon::prelude::*;

use super::decimate::{collapse_short_edges, project_to_zero};
use super::isosurface::{ScalarGrid, check_grid_size, extract_isosurface, remove_small_components};
use super::landmarks::Landmarks;
use super::morphometry::MorphometryTable;
use super::phantom_cache::MeshCache;
use super::sdf::{Frame, Placed, Shape, kidney_distance};
use super::vertebra::{Level, VertebraShape};
use super::{Structure, TriMesh};
use crate::geometry::RigidTransform;
use crate::{Error, Result};

/// Options of [`build_phantom`].
#[derive(Debug, Clone, PartialEq)]
pub struct PhantomOptions {
    pub levels: Vec<Level>,
    /// Grid spacing of the vertebra and disc meshes (mm).
    pub voxel_mm: f64,
    /// Cortical shell thickness (mm).
    pub cortical_mm: f64,
    pub soft_tissue: bool,
    pub discs: bool,
    /// Disc height at the endplate centres (mm).
    pub disc_mm: f64,
    /// Lordotic tilt between adjacent levels (degrees).
    pub lordosis_deg: f64,
    /// After extraction, simplify toward this edge length (mm): collapse edges shorter than 4/5 of it with vertices projected back onto the
    /// SDF ([`super::decimate`]); 0 keeps the raw marching-tetrahedra mesh.
    pub simplify_edge_mm: f64,
    /// Every dimension of the vertebrae (default: the embedded `assets/morphometry/lumbar.toml`).
    pub morphometry: MorphometryTable,
}

impl Default for PhantomOptions {
    fn default() -> Self {
        PhantomOptions {
            levels: Level::ALL.to_vec(),
            voxel_mm: 0.6,
            cortical_mm: 1.2,
            soft_tissue: false,
            discs: true,
            disc_mm: 10.0,
            lordosis_deg: 4.0,
            simplify_edge_mm: 1.0,
            morphometry: MorphometryTable::default(),
        }
    }
}

/// The tissue at a point of the phantom.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Tissue {
    Air,
    SoftTissue,
    Disc,
    Cortical,
    Cancellous,
}

/// One meshed vertebra.
#[derive(Debug, Clone)]
pub struct VertebraModel {
    pub level: Level,
    /// Outer surface, labelled per triangle with its [`Structure`].
    pub cortical: TriMesh,
    /// Inner surface (the outer SDF eroded by the cortical thickness).
    pub cancellous: TriMesh,
    pub landmarks: Landmarks,
    pub shape: VertebraShape,
    /// Pose of the vertebra's local frame in the world.
    pub local_to_world: RigidTransform,
}

impl VertebraModel {
    /// Signed distance of the outer surface at a world point.
    pub fn sdf(&self, p: DVec3) -> f64 {
        self.shape.sdf(self.local_to_world.inverse().apply(p))
    }
}

/// An intervertebral disc: the prism over the endplates' kidney section between two endplate rim
/// planes, rim rounded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DiscShape {
    frame: Frame,
    a: f64,
    b: f64,
    posterior: f64,
    lower: (DVec3, DVec3),
    upper: (DVec3, DVec3),
}

const DISC_RIM_MM: f64 = 1.5;

impl DiscShape {
    /// Approximate signed distance at a world point (exact across the endplate planes).
    pub fn sdf(&self, p: DVec3) -> f64 {
        let q = self.frame.to_local(p);
        let r = DISC_RIM_MM;
        let d2 = kidney_distance(DVec2::new(q.x, q.y), self.a - r, self.b - r, self.posterior);
        let dz = (-(p - self.lower.0).dot(self.lower.1)).max((p - self.upper.0).dot(self.upper.1));
        let v = DVec2::new(d2, dz + r);
        v.max(DVec2::ZERO).length() + v.max_element().min(0.0) - r
    }
}

/// The built phantom.
#[derive(Debug, Clone)]
pub struct Phantom {
    pub vertebrae: Vec<VertebraModel>,
    pub discs: Vec<TriMesh>,
    pub soft_tissue: Option<TriMesh>,
    pub disc_shapes: Vec<DiscShape>,
    /// The soft-tissue cylinder (world frame), when requested.
    pub soft_tissue_shape: Option<Placed>,
    pub cortical_mm: f64,
}

impl Phantom {
    /// The tissue at a world point (vertebrae over discs over soft tissue over air).
    pub fn classify(&self, p: DVec3) -> Tissue {
        for v in &self.vertebrae {
            let d = v.sdf(p);
            if d < -self.cortical_mm {
                return Tissue::Cancellous;
            }
            if d < 0.0 {
                return Tissue::Cortical;
            }
        }
        if self.disc_shapes.iter().any(|d| d.sdf(p) < 0.0) {
            return Tissue::Disc;
        }
        match &self.soft_tissue_shape {
            Some(s) if s.sdf(p) < 0.0 => Tissue::SoftTissue,
            _ => Tissue::Air,
        }
    }

    /// All landmark sets, cranial to caudal.
    pub fn landmarks(&self) -> Vec<Landmarks> {
        self.vertebrae.iter().map(|v| v.landmarks.clone()).collect()
    }

    /// Each level's planned pedicle-screw target points in world
    /// ([`super::vertebra::VertebraShape::pedicle_targets`]), cranial to caudal.
    pub fn pedicle_targets(&self) -> Vec<Landmarks> {
        self.vertebrae
            .iter()
            .map(|v| v.shape.pedicle_targets(|p| v.local_to_world.apply(p)))
            .collect()
    }
}

/// Poses of every level from the first to the last requested (see the placement rule).
fn level_poses(levels: &[Level], opts: &PhantomOptions) -> Vec<(Level, RigidTransform)> {
    let (disc_mm, lordosis_deg) = (opts.disc_mm, opts.lordosis_deg);
    let (first, last) = (levels[0].index(), levels[levels.len() - 1].index());
    let mid = levels[(levels.len() - 1) / 2].index();
    let tilt =
        |i: usize| DMat3::from_rotation_x((lordosis_deg * (mid as f64 - i as f64)).to_radians());
    // Endplate centres (inside the concave endplates' rims) are `disc_mm` apart.
    let table = &opts.morphometry;
    let half_h =
        |i: usize| table.level(Level::ALL[i]).body_height / 2.0 - table.shape.endplate_concavity_mm;
    let mut centres = [DVec3::ZERO; 5];
    for i in (first..mid).rev() {
        let (rl, ru) = (tilt(i + 1), tilt(i));
        let axis = (rl.z_axis + ru.z_axis).normalize();
        centres[i] =
            centres[i + 1] + rl.z_axis * half_h(i + 1) + axis * disc_mm + ru.z_axis * half_h(i);
    }
    for i in mid + 1..=last {
        let (ru, rl) = (tilt(i - 1), tilt(i));
        let axis = (rl.z_axis + ru.z_axis).normalize();
        centres[i] =
            centres[i - 1] - ru.z_axis * half_h(i - 1) - axis * disc_mm - rl.z_axis * half_h(i);
    }
    (first..=last)
        .map(|i| (Level::ALL[i], RigidTransform::new(tilt(i), centres[i])))
        .collect()
}

/// Meshes `f` (local frame) on a grid covering `bounds` (+ margin) with spacing `voxel`, then maps the
/// mesh to world by `to_world`. Returns the grid so several iso-levels can share it.
fn sample(
    bounds: (DVec3, DVec3),
    voxel: f64,
    to_world: &RigidTransform,
    band: [f64; 2],
    f: impl Fn(DVec3) -> f64 + Sync,
) -> Result<ScalarGrid> {
    let lo = bounds.0 - DVec3::splat(2.0 * voxel);
    let n = ((bounds.1 + DVec3::splat(2.0 * voxel) - lo) / voxel).ceil();
    check_grid_size(
        &format!("voxel_mm {voxel}"),
        (n + DVec3::ONE).to_array(),
        std::mem::size_of::<f32>(),
    )?;
    let dims = [n.x as usize + 1, n.y as usize + 1, n.z as usize + 1];
    let index_to_local = DMat4::from_translation(lo) * DMat4::from_scale(DVec3::splat(voxel));
    // Gradient-norm margin 4: the elliptic distances stay below ~3 for our aspect ratios (tested).
    let mut grid = ScalarGrid::from_fn_banded(dims, index_to_local, f, band, 4.0)?;
    grid.index_to_world = to_world.to_mat4() * index_to_local;
    Ok(grid)
}

/// Simplifies `m` (when enabled) with vertices projected onto the zero set of `f` (world frame).
fn simplify(m: TriMesh, opts: &PhantomOptions, f: &(dyn Fn(DVec3) -> f64 + Sync)) -> TriMesh {
    if opts.simplify_edge_mm <= 0.0 {
        return m;
    }
    let project = |p: DVec3| project_to_zero(f, p);
    collapse_short_edges(&m, opts.simplify_edge_mm, 6, Some(&project))
}

/// A vertebra's cortical (outer, labelled per triangle) and cancellous (inner) surfaces in world.
fn mesh_vertebra(
    shape: &VertebraShape,
    pose: &RigidTransform,
    opts: &PhantomOptions,
) -> Result<(TriMesh, TriMesh)> {
    let band = [-opts.cortical_mm, 0.0];
    let grid = sample(shape.bounds(), opts.voxel_mm, pose, band, |p| shape.sdf(p))?;
    let name = shape.level.name();
    let inv = pose.inverse();
    let outer = |p: DVec3| shape.sdf(inv.apply(p));
    let inner = |p: DVec3| shape.sdf(inv.apply(p)) + opts.cortical_mm;
    let mut cortical = simplify(extract_isosurface(&grid, 0.0)?, opts, &outer);
    cortical.name = format!("{name}_cortical");
    cortical.labels = (0..cortical.triangles.len())
        .into_par_iter()
        .map(|i| {
            let [a, b, c] = cortical.corners(i);
            let n = inv.apply_vector((b - a).cross(c - a)).normalize_or_zero();
            shape.structure_at(inv.apply((a + b + c) / 3.0), n) as u8
        })
        .collect();
    let raw = extract_isosurface(&grid, -opts.cortical_mm as f32)?;
    let mut cancellous = simplify(remove_small_components(&raw, 1.0), opts, &inner);
    cancellous.name = format!("{name}_cancellous");
    Ok((cortical, cancellous))
}

fn disc_between(
    upper: (&VertebraShape, &RigidTransform),
    lower: (&VertebraShape, &RigidTransform),
) -> DiscShape {
    let (su, pu) = upper;
    let (sl, pl) = lower;
    let top = (
        pu.apply(DVec3::new(0.0, 0.0, -su.morphometry.body_height / 2.0)),
        pu.rotation.z_axis,
    );
    let bottom = (
        pl.apply(DVec3::new(0.0, 0.0, sl.morphometry.body_height / 2.0)),
        pl.rotation.z_axis,
    );
    let mean = (pu.rotation.z_axis + pl.rotation.z_axis).normalize();
    let y = mean.cross(DVec3::X).normalize();
    let frame = Frame {
        origin: (top.0 + bottom.0) / 2.0,
        axes: DMat3::from_cols(DVec3::X, y, mean),
    };
    let m = (su.morphometry, sl.morphometry);
    DiscShape {
        frame,
        a: m.0.endplate_width.min(m.1.endplate_width) / 2.0 - 1.0,
        b: m.0.endplate_depth.min(m.1.endplate_depth) / 2.0 - 1.0,
        posterior: su.params.posterior_concavity_mm,
        lower: bottom,
        upper: top,
    }
}

fn check_options(o: &PhantomOptions) -> Result<()> {
    if o.levels.is_empty() {
        return Err(Error::invalid("levels", "no level requested"));
    }
    let positive = |name: &str, v: f64, max: f64| {
        if v.is_finite() && v > 0.0 && v <= max {
            Ok(())
        } else {
            Err(Error::invalid(name, format!("{v} is outside (0, {max}]")))
        }
    };
    positive("voxel_mm", o.voxel_mm, 5.0)?;
    positive("cortical_mm", o.cortical_mm, 4.0)?;
    positive("disc_mm", o.disc_mm, 30.0)?;
    if !(o.lordosis_deg.is_finite() && o.lordosis_deg.abs() <= 15.0) {
        return Err(Error::invalid(
            "lordosis_deg",
            format!("{} is outside [-15, 15]", o.lordosis_deg),
        ));
    }
    Ok(())
}

/// Builds and meshes the phantom described by `opts`, through the process-wide mesh cache when one is
/// enabled ([`super::phantom_cache::enable`]; the `spinedrr` binary does), else afresh.
pub fn build_phantom(opts: &PhantomOptions) -> Result<Phantom> {
    build_phantom_with(opts, super::phantom_cache::global())
}

/// Builds the phantom, taking its meshes from `cache` when it holds them for these options and this
/// build of the code (and storing them there otherwise); `None` meshes afresh. The result is the same
/// bit for bit either way.
pub fn build_phantom_with(opts: &PhantomOptions, cache: Option<&MeshCache>) -> Result<Phantom> {
    check_options(opts)?;
    let mut levels = opts.levels.clone();
    levels.sort();
    levels.dedup();
    let placed: Vec<(VertebraShape, RigidTransform)> = level_poses(&levels, opts)
        .into_iter()
        .filter(|(l, _)| levels.contains(l))
        .map(|(l, p)| (VertebraShape::new(l, &opts.morphometry), p))
        .collect();
    let mut disc_shapes = Vec::new();
    let mut disc_names = Vec::new();
    if opts.discs {
        for w in placed.windows(2) {
            let (upper, lower) = (&w[0], &w[1]);
            if lower.0.level.index() != upper.0.level.index() + 1 {
                continue;
            }
            disc_shapes.push(disc_between((&upper.0, &upper.1), (&lower.0, &lower.1)));
            disc_names.push(format!("{}-{}_disc", upper.0.level, lower.0.level));
        }
    }
    let count = 2 * placed.len() + disc_shapes.len() + usize::from(opts.soft_tissue);
    let build = || mesh_phantom(&placed, &disc_shapes, &disc_names, opts);
    let mut meshes = match cache {
        Some(c) => c.meshes(&mesh_identity(opts), count, build)?,
        None => build()?,
    }
    .into_iter();
    let mut next = || meshes.next().expect("as many meshes as counted");
    let vertebrae: Vec<VertebraModel> = placed
        .into_iter()
        .map(|(shape, pose)| VertebraModel {
            level: shape.level,
            cortical: next(),
            cancellous: next(),
            landmarks: shape.landmarks(|p| pose.apply(p)),
            shape,
            local_to_world: pose,
        })
        .collect();
    let discs = disc_shapes.iter().map(|_| next()).collect();
    let soft_tissue_shape = opts
        .soft_tissue
        .then(|| soft_tissue_cylinder(&vertebrae.iter().map(|v| &v.cortical).collect::<Vec<_>>()));
    let soft_tissue = opts.soft_tissue.then(&mut next);
    Ok(Phantom {
        vertebrae,
        discs,
        soft_tissue,
        disc_shapes,
        soft_tissue_shape,
        cortical_mm: opts.cortical_mm,
    })
}

/// What a phantom's meshes depend on besides the code, written out in full: the options (`{:?}`, whose
/// floats round-trip) with the levels sorted and deduplicated. The mesh cache's identity of an entry.
pub fn mesh_identity(opts: &PhantomOptions) -> String {
    let mut levels = opts.levels.clone();
    levels.sort();
    levels.dedup();
    format!(
        "{:?}",
        PhantomOptions {
            levels,
            ..opts.clone()
        }
    )
}

/// Every mesh of the phantom, in the order [`build_phantom_with`] assembles them: each vertebra's
/// cortical and cancellous surfaces, the discs, the soft tissue.
fn mesh_phantom(
    placed: &[(VertebraShape, RigidTransform)],
    disc_shapes: &[DiscShape],
    disc_names: &[String],
    opts: &PhantomOptions,
) -> Result<Vec<TriMesh>> {
    let vertebrae = placed
        .par_iter()
        .map(|(shape, pose)| mesh_vertebra(shape, pose, opts))
        .collect::<Result<Vec<_>>>()?;
    let soft_tissue = match opts.soft_tissue {
        true => {
            let cortical: Vec<&TriMesh> = vertebrae.iter().map(|v| &v.0).collect();
            Some(mesh_soft_tissue(&soft_tissue_cylinder(&cortical))?)
        }
        false => None,
    };
    let mut meshes: Vec<TriMesh> = vertebrae.into_iter().flat_map(|(a, b)| [a, b]).collect();
    for (d, name) in disc_shapes.iter().zip(disc_names) {
        meshes.push(mesh_disc(d, opts, name)?);
    }
    meshes.extend(soft_tissue);
    Ok(meshes)
}

fn mesh_disc(d: &DiscShape, opts: &PhantomOptions, name: &str) -> Result<TriMesh> {
    let voxel = opts.voxel_mm;
    let half = DVec3::new(
        d.a,
        d.b,
        (d.upper.0 - d.lower.0).length() / 2.0 + d.a.max(d.b) * 0.1 + 2.0,
    );
    let to_world = RigidTransform::new(d.frame.axes, d.frame.origin);
    let grid = sample((-half, half), voxel, &to_world, [0.0, 0.0], |q| {
        d.sdf(d.frame.to_parent(q))
    })?;
    let mut m = simplify(extract_isosurface(&grid, 0.0)?, opts, &|p| d.sdf(p));
    m.name = name.to_string();
    Ok(m)
}

/// A 300 × 220 mm elliptic cylinder (rim rounded by 10 mm) around the vertebrae, 30 mm beyond them in z,
/// its centre 20 mm anterior of the body centres so the back is ~25 mm behind the spinous tips.
fn soft_tissue_cylinder(cortical: &[&TriMesh]) -> Placed {
    let (mut zlo, mut zhi) = (f64::INFINITY, f64::NEG_INFINITY);
    for m in cortical {
        if let Some((lo, hi)) = m.bounds() {
            zlo = zlo.min(lo.z);
            zhi = zhi.max(hi.z);
        }
    }
    if !zlo.is_finite() {
        (zlo, zhi) = (-20.0, 20.0);
    }
    Placed {
        frame: Frame::at(DVec3::new(0.0, 20.0, (zlo + zhi) / 2.0)),
        shape: Shape::EllipticCylinder {
            a: 150.0,
            b: 110.0,
            half_h: (zhi - zlo) / 2.0 + 30.0,
            radius: 10.0,
        },
    }
}

fn mesh_soft_tissue(s: &Placed) -> Result<TriMesh> {
    let h = s.shape.half_extent();
    let to_world = RigidTransform::new(s.frame.axes, s.frame.origin);
    let grid = sample((-h, h), 3.0, &to_world, [0.0, 0.0], |q| s.shape.sdf(q))?;
    let f = |p: DVec3| s.sdf(p);
    let project = |p: DVec3| project_to_zero(&f, p);
    // 3 mm grid, then simplified toward 8 mm edges: an outline, not anatomy.
    let mut m = collapse_short_edges(&extract_isosurface(&grid, 0.0)?, 8.0, 6, Some(&project));
    m.name = "soft_tissue".into();
    m.labels = vec![Structure::SoftTissue as u8; m.triangles.len()];
    Ok(m)
}
