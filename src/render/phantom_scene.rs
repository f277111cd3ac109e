//! The phantom as a render scene: attenuation from Hounsfield units, nested surfaces as differential μ.
//!
//! μ comes from [`crate::anatomy::tissue_mu`], `μ(HU) = μ_water · max(0, 1 + HU / 1000)`, the law the CT
//! renderer uses, so a thickness DRR of the phantom and a volume DRR of its synthetic CT integrate the same
//! attenuation.

use std::sync::Arc;

use super::{RenderScene, SceneMesh};
use crate::Result;
use crate::anatomy::{Phantom, Tissue, tissue_mu};

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
