//! The intensity-registration experiment: a phantom level's pose registered by matching DRRs rendered
//! with the **assumed** K (true or perturbed) to fixed images rendered with the true K
//! ([`crate::registration::intensity`]), from starts spread uniformly in initial mTRE (van de Kraats et
//! al. 2005). Beside every cell, the landmark registration of the same level under the same assumed K.
//!
//! The anatomy is built once per target ([`prepare`]); a unit shares its moving DRR (renderers and
//! levels of detail, nothing rebuilt), renders the fixed images of its views and runs its starts.

use glam::DVec3;

use super::Context;
use crate::anatomy::{Level, Phantom, PhantomOptions, build_phantom, parse_levels};
use crate::geometry::{RigidTransform, View, rotation_angle_deg, rotation_log};
use crate::io::{ImageF32, XrayModel};
use crate::registration::intensity::{
    IntensityOptions, IntensityProblem, IntensityView, MeshDrr, MovingDrr, SUCCESS_MTRE_MM,
    level_alone, level_targets, mtre_mm, phantom_renderer, projected_tre_px, register_intensity,
    start_at_mtre,
};
use crate::registration::{
    Method, RegistrationOptions, RegistrationProblem, SplitMix64, pose_errors, register,
};
use crate::render::{
    Backend, SpectralRenderer, ThicknessOptions, ThicknessRenderer, add_pedicle_screws,
    phantom_spectral_scene,
};
use crate::study::config::{FixedImage, FixedScope, IntensityCell, IntensitySection, StudyConfig};
use crate::study::schema::{IntensityRow, OPTIMUM_RESTART_MM, UnitRows};
use crate::study::timings::{Phase, Timings};
use crate::study::units::derive_seed;
use crate::{Error, Result};

/// The truth: the phantom is built at the world origin.
const TRUTH: RigidTransform = RigidTransform::IDENTITY;

/// One level prepared for intensity registration.
pub struct IntensityTarget {
    pub name: String,
    /// The level alone (its meshes and the pyramid's levels of detail, built once).
    moving: MeshDrr,
    /// What the fixed images show when it is more than the level ([`FixedScope::Anatomy`]).
    fixed: Option<ThicknessRenderer>,
    /// The spectral fixed images' renderers (the fixed scope's phantom in its materials), without and
    /// with the pedicle screws, when `images` lists them.
    spectral: Option<SpectralRenderer>,
    spectral_screws: Option<SpectralRenderer>,
    /// The level's cortical surface vertices (subsampled): where the mTRE is measured.
    pub targets: Vec<DVec3>,
    pub landmarks: Vec<(String, DVec3)>,
}

/// Builds each target of `[intensity_registration]`: the level alone (moving DRR, target points,
/// landmarks) and, for `fixed = "anatomy"`, the whole phantom with discs and soft tissue.
pub fn prepare(cfg: &StudyConfig, timings: &Timings) -> Result<Vec<IntensityTarget>> {
    let s = &cfg.intensity_registration;
    let build = |levels: Vec<Level>, whole: bool| {
        timings.time(Phase::Anatomy, 1, || {
            build_phantom(&PhantomOptions {
                levels,
                voxel_mm: cfg.anatomy.voxel_mm,
                discs: whole,
                soft_tissue: whole,
                ..PhantomOptions::default()
            })
        })
    };
    let whole = match s.fixed {
        FixedScope::Anatomy => Some(build(Level::ALL.to_vec(), true)?),
        FixedScope::Level => None,
    };
    let finest = s.levels.last().copied().unwrap_or(1).max(1);
    let mut out = Vec::new();
    for name in &s.targets {
        let level = *parse_levels(name)?
            .first()
            .ok_or_else(|| Error::invalid("intensity_registration.targets", format!("'{name}'")))?;
        let own;
        let phantom: &Phantom = match &whole {
            Some(w) => w,
            None => {
                own = build(vec![level], false)?;
                &own
            }
        };
        let alone = level_alone(phantom, level)?;
        let moving = timings.time(Phase::Scene, 1, || -> Result<MeshDrr> {
            // The moving DRR renders with the study's backend (the fixed images with the raster).
            let m = MeshDrr::new(
                cfg.geometry
                    .backend
                    .renderer(crate::render::phantom_scene(&alone)?)?,
            );
            for &b in &s.levels {
                m.at_detail(b / finest)?;
            }
            Ok(m)
        })?;
        let fixed = match &whole {
            Some(w) => Some(timings.time(Phase::Scene, 1, || phantom_renderer(w))?),
            None => None,
        };
        let shown = whole.as_ref().unwrap_or(&alone);
        let spectral_of = |image: FixedImage| -> Result<Option<SpectralRenderer>> {
            if !s.images.contains(&image) {
                return Ok(None);
            }
            timings.time(Phase::Scene, 1, || {
                let mut scene = phantom_spectral_scene(shown)?;
                if image == FixedImage::SpectralScrews {
                    add_pedicle_screws(&mut scene, shown)?;
                }
                SpectralRenderer::new(&scene, s.spectral.model()?, Backend::Raster).map(Some)
            })
        };
        let spectral = spectral_of(FixedImage::Spectral)?;
        let spectral_screws = spectral_of(FixedImage::SpectralScrews)?;
        let landmarks = alone
            .landmarks()
            .into_iter()
            .flat_map(|set| set.points.into_iter())
            .collect();
        out.push(IntensityTarget {
            name: name.clone(),
            moving,
            fixed,
            spectral,
            spectral_screws,
            targets: level_targets(phantom, level)?,
            landmarks,
        });
    }
    Ok(out)
}

/// The fixed image of `t` in the true `view` in the model `image`: the line integral (monochromatic,
/// or the spectral `−ln(I/I0)`), through the X-ray model (Poisson at `photons`, blur, log) when
/// `photons > 0`, its noise seeded per (target, view) — the same noise draws for both models. `cfg` is the
/// study's (its section and seed).
fn fixed_image(
    cfg: &StudyConfig,
    t: &IntensityTarget,
    view: &View,
    image: FixedImage,
) -> Result<ImageF32> {
    let s = &cfg.intensity_registration;
    let spectral = match image {
        FixedImage::Mono => None,
        FixedImage::Spectral => Some(&t.spectral),
        FixedImage::SpectralScrews => Some(&t.spectral_screws),
    };
    let li = match (spectral, &t.fixed) {
        (Some(Some(r)), _) => r.render(view)?.line_integral,
        (Some(None), _) => {
            return Err(Error::Internal(format!(
                "no {image} renderer prepared for '{}'",
                t.name
            )));
        }
        (None, Some(r)) => {
            r.render(view, &ThicknessOptions::image_only())?
                .line_integral
        }
        (None, None) => MovingDrr::Mesh(t.moving.share()?).render_at(view, &TRUTH)?,
    };
    if s.photons <= 0.0 {
        return Ok(li);
    }
    let seed = derive_seed(cfg.seed, &format!("int-fixed/{}/{}", t.name, view.name), 0);
    Ok(XrayModel::new(s.photons, s.blur_px, seed, true)?.apply(&li))
}

/// The registration settings of the section (the CMA-ES seeded per start).
fn options(s: &IntensitySection, seed: u64) -> Result<IntensityOptions> {
    let d = IntensityOptions::default();
    Ok(IntensityOptions {
        similarity: s.similarity()?,
        levels: s.levels.clone(),
        global: s.global,
        cmaes: crate::registration::intensity::CmaesOptions { seed, ..d.cmaes },
        ..d
    })
}

/// The pose of the landmark registration of `landmarks` seen exactly through `truth` views and solved
/// with `assumed` views (K and pose; direct LM, started at the truth); `None` when it fails.
fn landmark_optimum(
    landmarks: &[(String, DVec3)],
    truth: &[View],
    assumed: &[View],
) -> Option<RigidTransform> {
    landmark_registration(landmarks, truth, assumed).map(|r| r.pose)
}

/// The landmark registration of `landmarks` observed exactly through `truth` and solved with `assumed`
/// (direct LM from the truth); `None` when the solve fails.
pub(super) fn landmark_registration(
    landmarks: &[(String, DVec3)],
    truth: &[View],
    assumed: &[View],
) -> Option<crate::registration::RegistrationResult> {
    let names = landmarks.iter().map(|(n, _)| n.clone()).collect();
    let points = landmarks.iter().map(|(_, p)| *p).collect();
    let solve = || -> Result<crate::registration::RegistrationResult> {
        let observed = RegistrationProblem::synthesize(names, points, truth, &TRUTH)?;
        let problem = observed.with_views(|v| {
            assumed
                .iter()
                .find(|a| a.name == v.name)
                .cloned()
                .ok_or_else(|| Error::Internal(format!("no assumed view '{}'", v.name)))
        })?;
        let opts = RegistrationOptions {
            init: Some(TRUTH),
            ..RegistrationOptions::default()
        };
        register(&problem, Method::Direct, &opts)
    };
    solve().ok()
}

/// Runs every start of one cell's bin.
pub fn run(ctx: &Context, cell: &IntensityCell) -> Result<UnitRows> {
    let s = &ctx.cfg.intensity_registration;
    let t = ctx
        .intensity
        .iter()
        .find(|t| t.name == cell.target)
        .ok_or_else(|| {
            Error::Internal(format!("intensity target '{}' not prepared", cell.target))
        })?;
    let truth_views = IntensitySection::view_names(&cell.views)
        .into_iter()
        .map(|n| ctx.carm.view(n).cloned())
        .collect::<Result<Vec<View>>>()?;
    let pert = cell.perturbation();
    let assumed = truth_views
        .iter()
        .map(|v| v.perturbed(&pert))
        .collect::<Result<Vec<View>>>()?;
    let views = truth_views
        .iter()
        .zip(&assumed)
        .map(|(tv, av)| {
            Ok(IntensityView {
                fixed: ctx.timings.time(Phase::RenderTarget, 1, || {
                    fixed_image(&ctx.cfg, t, tv, cell.image)
                })?,
                view: av.clone(),
            })
        })
        .collect::<Result<Vec<_>>>()?;
    let problem = IntensityProblem {
        moving: MovingDrr::Mesh(t.moving.share()?),
        views,
        targets: t.targets.clone(),
    };
    let landmark_pose = landmark_optimum(&t.landmarks, &truth_views, &assumed);
    let landmark = landmark_pose.map_or(f64::NAN, |l| mtre_mm(&l, &TRUTH, &t.targets));
    let (centre, rho) = (problem.centre(), problem.rho_mm());
    // The intensity optimum under this K: the registration started at the truth (local stage only).
    // Its mTRE is the calibration's bias, free of capture failures; a start "reached" it when it ends
    // within the success radius of it. Each bin searches it once: the first from the truth, every
    // other from OPTIMUM_RESTART_MM away (a direction seeded per bin, the same for every fixed-image
    // model), so the cell's searches show how reproducible the optimum is (the summary's spread).
    let optimum_start_mtre = if cell.bin == 0 {
        0.0
    } else {
        OPTIMUM_RESTART_MM
    };
    let optimum_init = if cell.bin == 0 {
        TRUTH
    } else {
        let mut rng = SplitMix64::new(derive_seed(ctx.cfg.seed, &cell.seed_key(), u64::MAX));
        start_at_mtre(
            &TRUTH,
            &t.targets,
            centre,
            rho,
            OPTIMUM_RESTART_MM,
            &mut rng,
        )
    };
    let optimum = ctx.timings.time(Phase::Registration, 1, || {
        register_intensity(
            &problem,
            &optimum_init,
            &IntensityOptions {
                global: false,
                ..options(s, 0)?
            },
        )
    });
    let optimum = optimum.ok().map(|r| r.pose);
    let optimum_mtre = optimum.map_or(f64::NAN, |o| mtre_mm(&o, &TRUTH, &t.targets));
    let (optimum_to_landmark, optimum_to_landmark_centre, optimum_to_landmark_rot) =
        match (&optimum, &landmark_pose) {
            (Some(o), Some(l)) => (
                mtre_mm(o, l, &t.targets),
                (o.apply(centre) - l.apply(centre)).length(),
                rotation_angle_deg(o.rotation * l.rotation.transpose()),
            ),
            _ => (f64::NAN, f64::NAN, f64::NAN),
        };
    let key = cell.seed_key();
    let mut rng = SplitMix64::new(derive_seed(ctx.cfg.seed, &key, 0));
    let ptre = |name: &str, pose: &RigidTransform| {
        truth_views
            .iter()
            .find(|v| v.name == name)
            .map_or(f64::NAN, |v| projected_tre_px(v, pose, &TRUTH, &t.targets))
    };
    let mut rows = UnitRows::default();
    for start in 0..cell.starts {
        let initial = cell.lo_mm + (cell.hi_mm - cell.lo_mm) * rng.uniform();
        let init = start_at_mtre(&TRUTH, &t.targets, centre, rho, initial, &mut rng);
        let opts = options(s, derive_seed(ctx.cfg.seed, &key, 1 + start as u64))?;
        let solved = ctx.timings.time(Phase::Registration, 1, || {
            register_intensity(&problem, &init, &opts)
        });
        // A failed registration is a measurement too: NaN errors, not a lost study.
        let (pose, similarity, evaluations, converged) = match solved {
            Ok(r) => (Some(r.pose), r.similarity, r.evaluations, r.converged),
            Err(_) => (None, f64::NAN, 0, false),
        };
        let nan = f64::NAN;
        let to_optimum = match (&pose, &optimum) {
            (Some(p), Some(o)) => mtre_mm(p, o, &t.targets),
            _ => nan,
        };
        let (fin, err, rv, tr, pa, pl) = match &pose {
            Some(p) => (
                mtre_mm(p, &TRUTH, &t.targets),
                pose_errors(p, &TRUTH),
                rotation_log(p.rotation),
                p.translation,
                ptre("ap", p),
                ptre("lat", p),
            ),
            None => (
                nan,
                pose_errors(&TRUTH, &TRUTH),
                DVec3::splat(nan),
                DVec3::splat(nan),
                nan,
                nan,
            ),
        };
        let (rot_err_deg, trans_err_mm) = match pose {
            Some(_) => (err.rot_err_deg, err.trans_err_mm),
            None => (nan, nan),
        };
        rows.intensity.push(IntensityRow {
            target: cell.target.clone(),
            views: cell.views.clone(),
            df_px: cell.df_px,
            piercing_px: cell.piercing_px,
            physical: cell.physical.map(|p| p.to_string()).unwrap_or_default(),
            fixed_image: cell.image.name().to_string(),
            bin: cell.bin,
            bin_lo_mm: cell.lo_mm,
            bin_hi_mm: cell.hi_mm,
            start,
            initial_mtre_mm: initial,
            final_mtre_mm: fin,
            success: fin < SUCCESS_MTRE_MM,
            rot_err_deg,
            trans_err_mm,
            ptre_ap_px: pa,
            ptre_lat_px: pl,
            similarity,
            evaluations,
            converged,
            rx: rv.x,
            ry: rv.y,
            rz: rv.z,
            tx_mm: tr.x,
            ty_mm: tr.y,
            tz_mm: tr.z,
            landmark_mtre_mm: landmark,
            optimum_start_mtre_mm: optimum_start_mtre,
            optimum_mtre_mm: optimum_mtre,
            optimum_to_landmark_mm: optimum_to_landmark,
            optimum_to_landmark_centre_mm: optimum_to_landmark_centre,
            optimum_to_landmark_rot_deg: optimum_to_landmark_rot,
            to_optimum_mm: to_optimum,
            reached_optimum: to_optimum < SUCCESS_MTRE_MM,
        });
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(photons: f64) -> StudyConfig {
        StudyConfig::from_toml_str(
            &format!(
                r#"seed = 5
experiments = ["intensity-registration"]
[anatomy]
levels = ["L3"]
segment = false
voxel_mm = 1.6
[intensity_registration]
targets = ["L3"]
views = ["lat"]
fixed = "level"
photons = {photons:?}
images = ["spectral+screws"]
"#
            ),
            "test",
        )
        .unwrap()
    }

    /// The realistic fixed image — the spectrum, the screws — takes the X-ray model's quantum noise from its
    /// own signal: against the noise-free image L, `−ln(N/I0)` with `N ~ Poisson(λ = I0 · e^{−L})` has mean
    /// `L + 1/(2λ)` and variance `1/λ` (the delta method to second order, accurate at the λ ≥ 1350 counts
    /// kept here): the standardised differences have mean 0 and variance 1. The law holds pixel by pixel
    /// whatever the scene, so the scene is the level alone on a 1.6-mm phantom grid (~38 000 pixels in
    /// range): the unit tests compile unoptimised under `make test`, where the whole phantom at 0.8 mm
    /// took 43 s to build and render.
    #[test]
    fn spectral_fixed_images_with_screws_take_the_poisson_noise_of_their_own_signal() {
        let (noisy_cfg, clean_cfg) = (config(1e4), config(0.0));
        let t = &prepare(&noisy_cfg, &Timings::default()).unwrap()[0];
        let view = noisy_cfg.carm().unwrap().view("lat").unwrap().clone();
        let image = FixedImage::SpectralScrews;
        let noisy = fixed_image(&noisy_cfg, t, &view, image).unwrap();
        let clean = fixed_image(&clean_cfg, t, &view, image).unwrap();
        let z: Vec<f64> = noisy
            .data
            .iter()
            .zip(&clean.data)
            .filter(|(_, l)| (0.2..2.0).contains(*l))
            .map(|(n, l)| {
                // λ counts; E[−ln(N/I0)] = L + 1/(2λ) to second order, Var = 1/λ.
                let lambda = 1e4 * (-f64::from(*l)).exp();
                (f64::from(*n) - f64::from(*l) - 0.5 / lambda) * lambda.sqrt()
            })
            .collect();
        assert!(z.len() > 20_000, "{} pixels", z.len());
        let mean = z.iter().sum::<f64>() / z.len() as f64;
        let var = z.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / z.len() as f64;
        assert!(mean.abs() < 0.03, "mean {mean}");
        assert!((var - 1.0).abs() < 0.03, "variance {var}");
    }
}
