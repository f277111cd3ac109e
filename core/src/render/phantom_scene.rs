//! The phantom as a render scene: attenuation from Hounsfield units, nested surfaces as differential μ.
//!
//! μ comes from [`crate::anatomy::tissue_mu`], `μ(HU) = μ_water · max(0, 1 + HU / 1000)`, the law the CT
//! renderer uses, so a thickness DRR of the phantom and a volume DRR of its synthetic CT integrate the same
//! attenuation.

use std::sync::Arc;

use super::spectral::{SpectralMesh, SpectralScene};
use super::{RenderScene, SceneMesh};
use crate::Result;
use crate::anatomy::screw::{PlannedScrew, ScrewSpec};
use crate::anatomy::{Phantom, Tissue, TriMesh, tissue_hu, tissue_mu};
use crate::spectral::MaterialAt;

/// The phantom's meshes with their μ: per vertebra the cortical surface (object = level name) and the
/// cancellous surface inside it with `μ_cancellous − μ_cortical`; discs (object `discs`); the soft-tissue
/// outline (object `soft_tissue`) with everything inside it made differential against soft tissue.
pub fn phantom_scene(p: &Phantom) -> Result<RenderScene> {
    let background = if p.soft_tissue.is_some() {
        tissue_mu(Tissue::SoftTissue)
    } else {
        0.0
    };
    let (cortical, cancellous, disc) = (
        tissue_mu(Tissue::Cortical),
        tissue_mu(Tissue::Cancellous),
        tissue_mu(Tissue::Disc),
    );
    let mut meshes = Vec::new();
    for v in &p.vertebrae {
        let level = v.level.to_string();
        meshes.push(SceneMesh {
            mesh: Arc::new(v.cortical.clone()),
            mu_per_mm: cortical - background,
            object: level.clone(),
        });
        if !v.cancellous.triangles.is_empty() {
            meshes.push(SceneMesh {
                mesh: Arc::new(v.cancellous.clone()),
                mu_per_mm: cancellous - cortical,
                object: level,
            });
        }
    }
    for d in &p.discs {
        meshes.push(SceneMesh {
            mesh: Arc::new(d.clone()),
            mu_per_mm: disc - background,
            object: "discs".into(),
        });
    }
    if let Some(s) = &p.soft_tissue {
        meshes.push(SceneMesh {
            mesh: Arc::new(s.clone()),
            mu_per_mm: background,
            object: "soft_tissue".into(),
        });
    }
    RenderScene::new(meshes)
}

/// The phantom as a spectral scene: cortical shells of `cortical_bone` (ICRU 44, 1.92 g/cm³), cancellous
/// cores of `cancellous_bone` (1.18 g/cm³), discs and the soft-tissue outline of `soft_tissue` at the
/// water-equivalent density of their CT numbers, `1 + HU/1000` (1.09 and 1.04 g/cm³). Nested surfaces
/// displace what they are inside: a core carries `−ρ_cortical` on the cortical channel, everything inside
/// the outline `−ρ_soft` on the soft-tissue channel.
pub fn phantom_spectral_scene(p: &Phantom) -> Result<SpectralScene> {
    let material =
        |name: &str| crate::spectral::Material::named(name).map(crate::spectral::Channel::Material);
    let channels = vec![
        material("cortical_bone")?,
        material("cancellous_bone")?,
        material("soft_tissue")?,
    ];
    let (cortical, cancellous, soft) = (0, 1, 2);
    let rho = |c: usize| match channels[c] {
        crate::spectral::Channel::Material(m) => m.density_g_cm3,
        crate::spectral::Channel::FixedMu => 0.0,
    };
    let water_equivalent = |t: Tissue| 1.0 + tissue_hu(t) / 1000.0;
    let soft_rho = water_equivalent(Tissue::SoftTissue);
    let mut background = Vec::new();
    if p.soft_tissue.is_some() {
        background.push((soft, -soft_rho));
    }
    let with_background = |mut terms: Vec<(usize, f64)>| {
        terms.extend(background.iter().copied());
        terms
    };
    let mut meshes = Vec::new();
    for v in &p.vertebrae {
        let level = v.level.to_string();
        meshes.push(SpectralMesh {
            mesh: Arc::new(v.cortical.clone()),
            object: level.clone(),
            terms: with_background(vec![(cortical, rho(cortical))]),
            implant: false,
        });
        if !v.cancellous.triangles.is_empty() {
            meshes.push(SpectralMesh {
                mesh: Arc::new(v.cancellous.clone()),
                object: level,
                terms: vec![(cancellous, rho(cancellous)), (cortical, -rho(cortical))],
                implant: false,
            });
        }
    }
    for d in &p.discs {
        meshes.push(SpectralMesh {
            mesh: Arc::new(d.clone()),
            object: "discs".into(),
            terms: with_background(vec![(soft, water_equivalent(Tissue::Disc))]),
            implant: false,
        });
    }
    if let Some(s) = &p.soft_tissue {
        meshes.push(SpectralMesh {
            mesh: Arc::new(s.clone()),
            object: "soft_tissue".into(),
            terms: vec![(soft, soft_rho)],
            implant: false,
        });
    }
    SpectralScene::new(channels, meshes)
}

/// Two titanium (Ti-6Al-4V) pedicle screws per level ([`ScrewSpec::default`]) along the phantom's planned
/// trajectories ([`pedicle_screws`]), added to `scene` as implants named `<level>_screw_<side>`.
pub fn add_pedicle_screws(scene: &mut SpectralScene, phantom: &Phantom) -> Result<()> {
    add_screws(scene, &pedicle_screws(phantom)?)
}

/// The phantom's planned screws: per level and side, its `pedicle_entry` to its `pedicle_tip`, named
/// `<level>_screw_<side>`.
pub fn pedicle_screws(phantom: &Phantom) -> Result<Vec<PlannedScrew>> {
    let mut screws = Vec::new();
    for targets in phantom.pedicle_targets() {
        for side in ["left", "right"] {
            let at = |what: &str| {
                let key = format!("{side}_pedicle_{what}");
                targets.points.get(&key).copied().ok_or_else(|| {
                    crate::Error::invalid("pedicle targets", format!("{}: no {key}", targets.level))
                })
            };
            screws.push(PlannedScrew {
                name: format!("{}_screw_{side}", targets.level),
                entry: at("entry")?,
                tip: at("tip")?,
            });
        }
    }
    Ok(screws)
}

/// Titanium (Ti-6Al-4V) screws of [`ScrewSpec::default`] along `screws` (entry to tip), added to `scene`
/// as implants named after each screw.
pub fn add_screws(scene: &mut SpectralScene, screws: &[PlannedScrew]) -> Result<()> {
    for (object, mesh, material) in screw_implants(screws)? {
        scene.add_implant(mesh, object, material);
    }
    Ok(())
}

/// Implant meshes, each as (object name, mesh, material).
pub type ImplantMeshes = Vec<(String, Arc<TriMesh>, MaterialAt)>;

/// The screws planned by named points (each `PREFIXpedicle_entry` with its `PREFIXpedicle_tip`, see
/// [`crate::anatomy::screw::planned_screws`]) and their meshes ([`screw_implants`]); points without a pair
/// are refused, naming `field`.
pub fn planned_screw_implants(
    points: &[(String, glam::DVec3)],
    field: &str,
) -> Result<(Vec<PlannedScrew>, ImplantMeshes)> {
    let screws = crate::anatomy::screw::planned_screws(points);
    if screws.is_empty() {
        return Err(crate::Error::invalid(
            field,
            "no planned screw — name each trajectory's points PREFIXpedicle_entry and PREFIXpedicle_tip \
             (e.g. left_pedicle_entry, left_pedicle_tip)",
        ));
    }
    let meshes = screw_implants(&screws)?;
    Ok((screws, meshes))
}

/// The meshes of titanium (Ti-6Al-4V) screws of [`ScrewSpec::default`] along `screws`: per screw its
/// shank and its tulip head, each as (screw name, mesh, material).
pub fn screw_implants(screws: &[PlannedScrew]) -> Result<ImplantMeshes> {
    let titanium = MaterialAt::parse("titanium")?;
    let mut out = Vec::new();
    for s in screws {
        let (shank, head) = ScrewSpec::default().meshes(&s.name, s.entry, s.tip)?;
        out.push((s.name.clone(), Arc::new(shank), titanium));
        out.push((s.name.clone(), Arc::new(head), titanium));
    }
    Ok(out)
}
