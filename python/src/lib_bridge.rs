//! Every call from the Python module into the spinedrr library, and nothing else: the other files of
//! this crate convert numpy arrays and Python objects and call these functions. Each function makes
//! the same library calls as the matching CLI subcommand, so a Python result equals the CLI's bit for
//! bit; when the library moves a piece of work (issue 10), only this file is re-pointed.

use std::path::Path;
use std::sync::Arc;

use glam::DVec3;
use spinedrr::anatomy::ct::{Placement, VoxelMask, move_volume, place};
use spinedrr::anatomy::landmarks::landmarks_to_json;
use spinedrr::anatomy::{PhantomOptions, Structure, build_phantom, parse_levels};
use spinedrr::registration::LoadedProblem;
use spinedrr::render::volume::{VolumeMethod, VolumeRenderOptions, VolumeRenderer};
use spinedrr::render::{
    RenderScene, SpectralInput, SpectralRenderer, SpectralScene, ThicknessOptions,
    ThicknessRenderer,
};
use spinedrr::spectral::SpectralModel;

pub use spinedrr::analysis::{Landmark, MaskPair};
pub use spinedrr::anatomy::MU_WATER_PER_MM;
pub use spinedrr::anatomy::TriMesh;
pub use spinedrr::anatomy::ct::CtVolume;
pub use spinedrr::geometry::{CArm, Intrinsics, Perturbation, RigidTransform, View};
pub use spinedrr::io::ImageF32;
pub use spinedrr::render::{Backend, SceneMesh};
pub use spinedrr::{Error, Result, VERSION};

/// Shortest round-trip decimal of every parameter, parsed by [`Perturbation::parse`]: keyword
/// arguments get exactly the validation (finite, positive scales) and values of `--perturb`.
pub fn perturbation(
    df: f64,
    alpha: f64,
    dcx: f64,
    dcy: f64,
    skew: f64,
    sx: f64,
    sy: f64,
) -> Result<Perturbation> {
    Perturbation::parse(&format!(
        "df={df},alpha={alpha},dcx={dcx},dcy={dcy},skew={skew},sx={sx},sy={sy}"
    ))
}

/// A view from a row-major `K`, a detector size and a row-major 4 × 4 `world_to_camera`.
pub fn view_from_matrices(
    name: &str,
    k: [[f64; 3]; 3],
    width: u32,
    height: u32,
    world_to_camera: [[f64; 4]; 4],
) -> Result<View> {
    let intrinsics = Intrinsics::from_matrix(k, width, height)?;
    let pose = RigidTransform::from_rows(world_to_camera, "world_to_camera")?;
    Ok(View::new(name, intrinsics, pose))
}

/// `x ~ K [R | t] X` of each world point (the library's one projection function).
pub fn project(view: &View, points: &[[f64; 3]]) -> Vec<[f64; 2]> {
    points
        .iter()
        .map(|&p| view.project(DVec3::from(p)).to_array())
        .collect()
}

/// The phantom as `spinedrr render --phantom LEVELS` builds it.
pub struct PhantomParts {
    /// `(mesh, μ mm⁻¹, object)` of the render scene (differential μ of nested surfaces).
    pub scene: Vec<SceneMesh>,
    /// Landmarks named as `spinedrr compare --landmarks landmarks.json` names them (`LEVEL/name`).
    pub landmarks: Vec<Landmark>,
}

/// Builds the phantom and its render scene (the CLI's `render --phantom` path) and its landmarks,
/// through `landmarks.json`'s text as `spinedrr phantom` writes and `spinedrr compare` reads it.
pub fn phantom(levels: &str, soft_tissue: bool, discs: bool) -> Result<PhantomParts> {
    let opts = PhantomOptions {
        levels: parse_levels(levels)?,
        soft_tissue,
        discs,
        ..PhantomOptions::default()
    };
    let p = build_phantom(&opts)?;
    let scene = spinedrr::render::phantom_scene(&p)?;
    let json = landmarks_to_json(&p.landmarks())?;
    let landmarks = spinedrr::analysis::parse_landmarks(&json, "phantom landmarks")?;
    Ok(PhantomParts {
        scene: scene.meshes,
        landmarks,
    })
}

/// `I0 · exp(−L)` of a line-integral image, as `spinedrr render --intensity I0` writes it.
pub fn intensity(line_integral: &ImageF32, i0: f64) -> Result<ImageF32> {
    Ok(spinedrr::io::DrrValues::new(Some(i0))?.apply(line_integral))
}

pub fn read_mesh(path: &Path) -> Result<TriMesh> {
    spinedrr::anatomy::read_mesh(path)
}

/// A mesh from arrays, checked as a render scene checks it.
pub fn mesh(
    name: &str,
    vertices: &[[f64; 3]],
    faces: &[[u32; 3]],
    labels: Option<Vec<u8>>,
) -> Result<TriMesh> {
    let mut m = TriMesh::new(
        name,
        vertices.iter().map(|&v| DVec3::from(v)).collect(),
        faces.to_vec(),
    );
    if let Some(l) = labels {
        m.labels = l;
    }
    m.validate(&format!("mesh '{name}'"))?;
    Ok(m)
}

pub fn backend(name: &str) -> Result<Backend> {
    Backend::parse(name)
}

/// A [`ThicknessRenderer`] built by [`Backend::renderer`] (`Send + Sync`: it moves between threads).
pub struct Renderer(ThicknessRenderer);

/// What one render returns: the line integral and the outputs asked for.
pub struct Rendered {
    pub image: ImageF32,
    pub depth: Option<ImageF32>,
    /// The silhouettes the CLI writes with `--masks`: the union, per object, per structure present.
    pub masks: Option<RenderedMasks>,
    /// Rays whose crossings did not pair even after retracing (the CLI warns about them).
    pub rays_unrepaired: u64,
    /// The render's counters and time, as the sidecar's `stats` entry.
    pub stats: serde_json::Value,
}

pub struct RenderedMasks {
    pub all: Vec<bool>,
    pub objects: Vec<(String, Vec<bool>)>,
    pub structures: Vec<(String, Vec<bool>)>,
}

impl Renderer {
    /// The scene and backend of `spinedrr render --mesh …` / `--phantom …`.
    pub fn new(meshes: Vec<SceneMesh>, backend: Backend) -> Result<Self> {
        Ok(Renderer(backend.renderer(RenderScene::new(meshes)?)?))
    }

    pub fn backend_name(&self) -> &'static str {
        self.0.backend_name()
    }

    pub fn gpu_adapter(&self) -> Option<String> {
        self.0.gpu_adapter()
    }

    pub fn objects(&self) -> Vec<String> {
        self.0.scene().objects.clone()
    }

    pub fn open_meshes(&self) -> Vec<String> {
        self.0.scene().open_meshes.clone()
    }

    /// One render, with the options and mask selection of `spinedrr render [--masks] [--depth]`.
    pub fn render(&self, view: &View, masks: bool, depth: bool) -> Result<Rendered> {
        let opts = ThicknessOptions {
            masks,
            depth,
            ..ThicknessOptions::default()
        };
        let drr = self.0.render(view, &opts)?;
        let masks = match drr.masks.as_ref() {
            Some(m) => Some(RenderedMasks {
                all: m.union(),
                objects: (drr.objects.iter().enumerate())
                    .map(|(i, name)| (name.clone(), m.object(i)))
                    .collect(),
                structures: Structure::ALL
                    .into_iter()
                    .filter(|&s| s != Structure::Unlabelled)
                    .map(|s| (s.name().to_string(), m.structure(s)))
                    .filter(|(_, mask)| mask.iter().any(|&b| b))
                    .collect(),
            }),
            None => None,
        };
        Ok(Rendered {
            image: drr.line_integral,
            depth: drr.depth,
            masks,
            rays_unrepaired: drr.stats.rays_unrepaired,
            stats: serde_json::to_value(drr.stats).map_err(|e| Error::encode("render stats", e))?,
        })
    }
}

/// A CT prepared as `spinedrr render --ct` prepares it (volume, optional voxel mask, method, μ_water,
/// step, placement), for any number of views: μ and Siddon's running sums are built once.
pub struct CtRenderer {
    cpu: VolumeRenderer,
    /// With `backend="gpu"`: the same CT on the machine's GPU adapter.
    gpu: Option<spinedrr::render::gpu::GpuCtRenderer>,
}

impl CtRenderer {
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        mut ct: CtVolume,
        keep: Option<Vec<bool>>,
        method: &str,
        mu_water: f64,
        step_mm: Option<f64>,
        placement: &str,
        backend: &str,
    ) -> Result<Self> {
        let method: VolumeMethod = method.parse()?;
        let on_gpu = match backend {
            "cpu" => false,
            "gpu" => true,
            _ => {
                return Err(Error::invalid(
                    "backend",
                    format!("{backend:?}: a CT renders on the \"cpu\" or the \"gpu\""),
                ));
            }
        };
        let (mask, _) = place_ct(&mut ct, keep, placement)?;
        let opts = VolumeRenderOptions {
            method,
            mu_water,
            step_mm,
        };
        let cpu = VolumeRenderer::new(&ct, &opts, mask.as_ref())?;
        let gpu = if on_gpu {
            let ctx = spinedrr::render::gpu::GpuContext::shared()?;
            Some(spinedrr::render::gpu::GpuCtRenderer::new(ctx, &cpu)?)
        } else {
            None
        };
        Ok(CtRenderer { cpu, gpu })
    }

    /// The DRR of `view`, as `spinedrr render --ct … --view …` writes it (with `--backend gpu` on the
    /// GPU).
    pub fn render(&self, view: &View) -> Result<ImageF32> {
        view.intrinsics.validate()?;
        match &self.gpu {
            Some(g) => g.render(view),
            None => Ok(self.cpu.render(view)),
        }
    }

    /// The GPU adapter that renders, or `None` on the CPU.
    pub fn adapter(&self) -> Option<String> {
        self.gpu.as_ref().map(|g| g.adapter_name())
    }
}

/// Moves `ct` where `spinedrr render --placement PLACEMENT` moves it (with its keep mask, when given):
/// the mask on the CT's grid and the motion applied.
fn place_ct(
    ct: &mut CtVolume,
    keep: Option<Vec<bool>>,
    placement: &str,
) -> Result<(Option<VoxelMask>, RigidTransform)> {
    let placement = Placement::parse(placement, keep.is_some())?;
    let mask = match keep {
        Some(keep) => Some(
            VoxelMask::from_keep(ct, keep)
                .ok_or_else(|| Error::invalid("mask", "keeps no voxel"))?,
        ),
        None => None,
    };
    let motion = place(ct, placement, mask.as_ref())?.motion();
    move_volume(ct, &motion);
    Ok((mask, motion))
}

pub fn ct_volume(
    dims: [usize; 3],
    values: Vec<f32>,
    affine_rows: [[f64; 4]; 4],
) -> Result<CtVolume> {
    let cols = glam::DMat4::from_cols_array_2d(&affine_rows).transpose();
    CtVolume::new(dims, values, cols)
}

/// Every metric of `spinedrr compare`, as the `image`, `silhouettes` and `landmarks` entries of its
/// `metrics.json`.
pub fn compare(
    reference: &ImageF32,
    perturbed: &ImageF32,
    masks: &[MaskPair],
    landmarks: &[Landmark],
    views: Option<(&View, &View)>,
) -> Result<serde_json::Value> {
    let c = spinedrr::analysis::compare(reference, perturbed, masks, landmarks, views)?;
    let enc = |e: serde_json::Error| Error::encode("comparison", e);
    Ok(serde_json::json!({
        "image": serde_json::to_value(&c.image).map_err(enc)?,
        "silhouettes": serde_json::to_value(&c.silhouettes).map_err(enc)?,
        "landmarks": serde_json::to_value(&c.landmarks).map_err(enc)?,
    }))
}

pub fn landmark(name: String, p: [f64; 3]) -> Landmark {
    Landmark {
        name,
        position: DVec3::from(p),
    }
}

pub use spinedrr::registration::RegisterRequest;

/// `spinedrr register` on a problem JSON document: the library's one run of it (view selection, noise,
/// initial pose from the truth), returning the record `R.json` holds.
pub fn register(problem_json: &str, req: &RegisterRequest) -> Result<serde_json::Value> {
    let loaded = LoadedProblem::from_json_str(problem_json, "problem")?;
    Ok(spinedrr::registration::run_request(loaded, req)?.record)
}

/// Shared, immutable mesh handle (render scenes hold meshes by `Arc`).
pub type MeshRef = Arc<TriMesh>;

/// The spectral model of `spinedrr render --spectrum SPEC --filter FILTERS --detector DETECTOR`.
pub fn spectral_model(spectrum: &str, filters: &str, detector: &str) -> Result<SpectralModel> {
    spinedrr::spectral::model_from_specs(spectrum, filters, detector)
}

/// μ/ρ (or μ_en/ρ with `energy_absorption`) of a built-in material at each energy (keV), each energy
/// checked against the tables' range.
pub fn material_coefficients(
    name: &str,
    energies_kev: &[f64],
    energy_absorption: bool,
) -> Result<Vec<f64>> {
    let m = spinedrr::spectral::Material::named(name)?;
    energies_kev
        .iter()
        .map(|&e| {
            spinedrr::spectral::Spectrum::monochromatic(e)?;
            Ok(if energy_absorption {
                m.mu_en_rho(e)
            } else {
                m.mu_rho(e)
            })
        })
        .collect()
}

/// What a spectral render is of: meshes `(mesh, object, MU or MATERIAL[@DENSITY])` (as `--mesh`), the
/// phantom (levels, soft tissue, pedicle screws: `--phantom LEVELS [--soft-tissue] [--screws]`) or a CT
/// (its voxels' keep mask and placement: `--ct … --placement`).
pub enum SpectralAnatomy<'a> {
    Meshes(Vec<(Arc<TriMesh>, String, String)>),
    Phantom(&'a str, bool, bool),
    Ct(CtVolume, Option<Vec<bool>>, &'a str),
}

/// An implant mesh, its `MATERIAL[@DENSITY]` and its optional row-major 4 × 4 pose.
pub type ImplantMesh = (Arc<TriMesh>, String, Option<[[f64; 4]; 4]>);

/// Implants of a spectral render: meshes with `MATERIAL[@DENSITY]` and an optional row-major 4 × 4 pose
/// (`--implant FILE:MATERIAL[:POSE]`), and a plan's named points (`--screws-at`).
#[derive(Default)]
pub struct SpectralImplants {
    pub meshes: Vec<ImplantMesh>,
    pub plan: Vec<(String, [f64; 3])>,
}

impl SpectralImplants {
    /// (object, mesh placed by its pose, material), the plan's screws after the meshes.
    fn resolve(self) -> Result<spinedrr::render::ImplantMeshes> {
        let mut out = Vec::new();
        for (i, (mesh, material, pose)) in self.meshes.into_iter().enumerate() {
            let material = spinedrr::spectral::MaterialAt::parse(&material).map_err(|e| {
                Error::invalid(format!("implants[{i}]"), format!("'{material}': {e}"))
            })?;
            let mesh = match pose {
                Some(rows) => {
                    let pose = RigidTransform::from_rows(rows, &format!("implants[{i}] pose"))?;
                    let mut m = (*mesh).clone();
                    m.transform(&pose);
                    Arc::new(m)
                }
                None => mesh,
            };
            out.push((mesh.name.clone(), mesh, material));
        }
        if !self.plan.is_empty() {
            let points: Vec<(String, DVec3)> = self
                .plan
                .into_iter()
                .map(|(n, p)| (n, DVec3::from_array(p)))
                .collect();
            out.extend(spinedrr::render::planned_screw_implants(&points, "screws_at")?.1);
        }
        Ok(out)
    }
}

/// A spectral render, as `spinedrr render --spectrum …` of the same anatomy and implants: the
/// polychromatic line integral, the sidecar's `spectral` record, and the warnings of meshes partly
/// inside another. A CT's implants are in its file's world and move with its placement, as the CLI's.
pub fn render_spectral(
    anatomy: SpectralAnatomy,
    implants: SpectralImplants,
    model: SpectralModel,
    backend: Backend,
    view: &View,
) -> Result<(ImageF32, serde_json::Value, Vec<String>)> {
    let implants = implants.resolve()?;
    let (scene, warnings) = match anatomy {
        SpectralAnatomy::Ct(mut ct, keep, placement) => {
            let (mask, motion) = place_ct(&mut ct, keep, placement)?;
            let renderer =
                VolumeRenderer::new(&ct, &VolumeRenderOptions::default(), mask.as_ref())?;
            let implants: Vec<_> = implants.into_iter().map(|(_, m, mat)| (m, mat)).collect();
            let moved = spinedrr::render::moved_implants(&implants, &motion);
            view.intrinsics.validate()?;
            let r = spinedrr::render::SpectralCtRenderer::new(&renderer, &ct.values, model)?
                .with_implants(&moved, backend)?;
            // On the gpu backend the material channels render there (and the implants' meshes: `backend`).
            let r = if backend == Backend::Gpu {
                r.on_gpu(spinedrr::render::gpu::GpuContext::shared()?)?
            } else {
                r
            };
            let drr = r.render(view)?;
            return Ok((drr.line_integral, r.summary(), Vec::new()));
        }
        SpectralAnatomy::Phantom(levels, soft_tissue, screws) => {
            let opts = PhantomOptions {
                levels: parse_levels(levels)?,
                soft_tissue,
                ..PhantomOptions::default()
            };
            let p = build_phantom(&opts)?;
            let mut scene = spinedrr::render::phantom_spectral_scene(&p)?;
            if screws {
                spinedrr::render::add_pedicle_screws(&mut scene, &p)?;
            }
            (scene, Vec::new())
        }
        SpectralAnatomy::Meshes(meshes) => {
            let items = meshes
                .into_iter()
                .map(|(mesh, object, a)| {
                    Ok(SpectralInput {
                        mesh,
                        object,
                        attenuation: spinedrr::spectral::parse_attenuation(&a)?,
                        implant: false,
                    })
                })
                .collect::<Result<Vec<_>>>()?;
            SpectralScene::from_meshes(items)?
        }
    };
    let mut scene = scene;
    for (object, mesh, material) in implants {
        scene.add_implant(mesh, object, material);
    }
    let r = SpectralRenderer::new(&scene, model, backend)?;
    let drr = r.render(view)?;
    Ok((drr.line_integral, r.summary(), warnings))
}
