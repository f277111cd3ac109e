//! The assignment of units to shards: the cost model (expected milliseconds of one core per unit and
//! per input a shard prepares) and the longest-processing-time greedy rule over cost-bounded pieces
//! (see the parent module).

use std::collections::{BTreeMap, BTreeSet};

use super::Shard;
use crate::study::config::{Experiment, SEGMENT_TARGET, StudyConfig};
use crate::study::units::Unit;

/// The input group of a target: what must be built before any of its units runs.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub enum InputGroup {
    /// The built-in phantom (its levels and segment are built together).
    Phantom,
    /// A `[[anatomy.meshes]]` target.
    Mesh(String),
    /// A `[[anatomy.ct]]` entry (every level and the segment of one CT).
    Ct(String),
}

/// Each target's input group and the number of vertebrae it holds.
pub(super) fn target_groups(cfg: &StudyConfig) -> BTreeMap<String, (InputGroup, usize)> {
    let mut m = BTreeMap::new();
    let a = &cfg.anatomy;
    for l in &a.levels {
        m.insert(l.clone(), (InputGroup::Phantom, 1));
    }
    if a.segment && !a.levels.is_empty() {
        m.insert(
            SEGMENT_TARGET.to_string(),
            (InputGroup::Phantom, a.levels.len()),
        );
    }
    for mesh in &a.meshes {
        m.insert(mesh.name.clone(), (InputGroup::Mesh(mesh.name.clone()), 1));
    }
    for c in &a.ct {
        let levels = c.level_targets().unwrap_or_default();
        let n = levels.len();
        for (t, _) in levels {
            m.insert(t, (InputGroup::Ct(c.name.clone()), 1));
        }
        if c.segment {
            m.insert(c.segment_target(), (InputGroup::Ct(c.name.clone()), n));
        }
    }
    m
}

/// The cost model: milliseconds of one core, measured on the default study (README, *Benchmarks*:
/// 1024² detector, raster backend) and scaled by the detector's pixel count.
#[derive(Debug, Clone)]
pub struct CostModel {
    groups: BTreeMap<String, (InputGroup, usize)>,
    /// Detector megapixels of a view (after binning).
    megapixels: f64,
    landmarks: bool,
    projection: bool,
    /// The target the calibration experiment measures the vertebra on.
    calibration_target: String,
    /// Intensity registrations of a calibration trial (one per protocol) and how many trials per cell
    /// run them.
    calibration_intensity: (usize, usize),
    /// The intensity registration's finest pyramid binning.
    intensity_finest_bin: u32,
    /// Perturbations of the grid (a screw unit registers once per perturbation).
    perturbations: usize,
}

/// The target the calibration experiment measures the vertebra on: the configured one, else the
/// study's first target (as the experiment's context resolves it).
pub fn calibration_target(cfg: &StudyConfig) -> String {
    cfg.calibration
        .target
        .clone()
        .or_else(|| crate::study::units::targets(cfg).into_iter().next())
        .unwrap_or_default()
}

/// Per megapixel: a thickness DRR of one vertebra, the image and contour metrics of one pair, a CT
/// volume DRR (Siddon); a marker render; a registration trial; building the phantom per level, a CT
/// entry per level (reading, label surface, landmarks), a mesh target.
const RENDER_MS: f64 = 12.0;
const METRICS_MS: f64 = 50.0;
const CT_DRR_MS: f64 = 200.0;
const MARKER_MS: f64 = 0.1;
const LANDMARKS_PER_LEVEL: f64 = 17.0;
const TRIAL_MS: f64 = 0.03;
/// One calibration trial: the estimate and the vertebra's projection-domain metrics under it.
const CALIBRATION_TRIAL_MS: f64 = 2.0;
/// One intensity-based registration of a calibration trial (per megapixel of the detector).
const CALIBRATION_INTENSITY_MS: f64 = 800.0;
const PHANTOM_LEVEL_MS: f64 = 600.0;
/// One intensity registration per view and 64² px of its finest pyramid level (CMA-ES and LM, a few
/// hundred DRRs of one vertebra at the coarse levels, release, one core).
const INTENSITY_START_MS: f64 = 250.0;
const CT_LEVEL_MS: f64 = 1500.0;
const MESH_MS: f64 = 300.0;

impl CostModel {
    /// The model of `cfg` (a validated config).
    pub fn of(cfg: &StudyConfig) -> CostModel {
        let megapixels = cfg
            .carm()
            .ok()
            .and_then(|c| {
                let px: Vec<f64> = cfg
                    .studied_views(&c)
                    .map(|v| f64::from(v.intrinsics.width) * f64::from(v.intrinsics.height))
                    .collect();
                (!px.is_empty()).then(|| px.iter().sum::<f64>() / px.len() as f64 / 1e6)
            })
            .unwrap_or(1.0);
        CostModel {
            groups: target_groups(cfg),
            megapixels,
            landmarks: cfg.runs(Experiment::Landmarks),
            projection: cfg.runs(Experiment::Projection),
            calibration_target: calibration_target(cfg),
            calibration_intensity: (
                cfg.calibration.protocols.len(),
                cfg.calibration.intensity_trials,
            ),
            intensity_finest_bin: cfg
                .intensity_registration
                .levels
                .last()
                .copied()
                .unwrap_or(1),
            perturbations: cfg.perturbations.cells().len(),
        }
    }

    fn target(&self, t: &str) -> (InputGroup, usize) {
        self.groups
            .get(t)
            .cloned()
            .unwrap_or((InputGroup::Phantom, 1))
    }

    /// The render part of a projection unit (also the cost of its reference render).
    fn render_ms(&self, target: &str) -> f64 {
        let (group, n) = self.target(target);
        let n = n as f64;
        let mut ms = 0.0;
        if self.projection {
            ms += self.megapixels * RENDER_MS * n;
            if matches!(group, InputGroup::Ct(_)) {
                ms += self.megapixels * CT_DRR_MS;
            }
        }
        if self.landmarks {
            ms += MARKER_MS * LANDMARKS_PER_LEVEL * n;
        }
        ms
    }

    /// The expected cost of running `u` (ms of one core).
    pub fn unit_cost(&self, u: &Unit) -> f64 {
        match u {
            Unit::Projection { target, .. } => {
                let (_, n) = self.target(target);
                let metrics = if self.projection {
                    self.megapixels * METRICS_MS * (n as f64).sqrt()
                } else {
                    0.0
                };
                self.render_ms(target) + metrics
            }
            Unit::Registration { count, .. } => TRIAL_MS * *count as f64,
            Unit::RegistrationPhysical(c) => TRIAL_MS * c.count as f64,
            // Two noise-free solves.
            Unit::Tracking(_) => 2.0 * TRIAL_MS,
            // One noise-free solve per perturbation.
            Unit::Screws { .. } => self.perturbations as f64 * TRIAL_MS,
            Unit::Calibration(c) => {
                let (protocols, trials) = self.calibration_intensity;
                let intensity = trials.saturating_sub(c.first).min(c.count) * protocols;
                CALIBRATION_TRIAL_MS * c.count as f64
                    + CALIBRATION_INTENSITY_MS * self.megapixels * intensity as f64
            }
            Unit::Intensity(c) => {
                let views = c.views.split('+').count() as f64;
                let finest = f64::from(self.intensity_finest_bin.max(1));
                let tiles = (self.megapixels * 1e6 / (finest * finest) / 4096.0).max(1.0);
                INTENSITY_START_MS * views * tiles.sqrt() * c.starts as f64
            }
        }
    }

    /// What a unit needs prepared: its input group and, for a projection unit, its (target, view)
    /// reference render.
    fn needs(&self, u: &Unit) -> (InputGroup, Option<(String, String)>) {
        match u {
            Unit::Projection { target, view, .. } => {
                (self.target(target).0, Some((target.clone(), view.clone())))
            }
            Unit::Registration { target, .. } | Unit::Screws { target } => {
                (self.target(target).0, None)
            }
            Unit::Tracking(c) => (self.target(&c.target).0, None),
            Unit::RegistrationPhysical(c) => (self.target(&c.target).0, None),
            Unit::Calibration(_) => (self.target(&self.calibration_target).0, None),
            // The experiment builds its own levels (with the study's phantom).
            Unit::Intensity(_) => (InputGroup::Phantom, None),
        }
    }

    /// The cost of building an input group (ms of one core).
    pub fn setup_cost(&self, g: &InputGroup) -> f64 {
        match g {
            InputGroup::Phantom => {
                let levels = self
                    .groups
                    .values()
                    .filter(|(g, n)| *g == InputGroup::Phantom && *n == 1)
                    .count();
                // The segment is meshed again as a whole.
                PHANTOM_LEVEL_MS * (2 * levels) as f64
            }
            InputGroup::Mesh(_) => MESH_MS,
            InputGroup::Ct(name) => {
                let levels = self
                    .groups
                    .values()
                    .filter(|(g, n)| matches!(g, InputGroup::Ct(c) if c == name) && *n == 1)
                    .count();
                CT_LEVEL_MS * levels.max(1) as f64
            }
        }
    }
}

/// The shard (0..n) of each unit, in unit order (see the module documentation). Deterministic: ties
/// go to the earlier item and the lower shard.
pub fn assign(cfg: &StudyConfig, units: &[Unit], n: usize) -> Vec<usize> {
    assign_with(&CostModel::of(cfg), units, n)
}

/// A piece of work placed whole: a run of projection units of one (target, view), or one
/// registration unit.
struct Item {
    units: Vec<usize>,
    cost: f64,
    group: InputGroup,
    pair: Option<(String, String)>,
    /// The reference render its pair needs (paid once per shard).
    ref_ms: f64,
}

/// The items of `units`: each (target, view)'s projection units cut into runs of at most about
/// `total / (3 n)` (so the greedy rule has enough pieces to balance with) and each registration unit
/// alone.
fn items(model: &CostModel, units: &[Unit], costs: &[f64], n: usize) -> Vec<Item> {
    let total: f64 = costs.iter().sum();
    let biggest = costs.iter().copied().fold(0.0, f64::max);
    let limit = (total / (3 * n) as f64).max(biggest);
    type Bundle = (Option<(String, String)>, InputGroup, Vec<usize>);
    let mut bundles: Vec<Bundle> = Vec::new();
    for (i, u) in units.iter().enumerate() {
        let (group, pair) = model.needs(u);
        match (
            &pair,
            bundles.iter_mut().find(|b| b.0.is_some() && b.0 == pair),
        ) {
            (Some(_), Some(b)) => b.2.push(i),
            _ => bundles.push((pair, group, vec![i])),
        }
    }
    let mut out = Vec::new();
    for (pair, group, idx) in bundles {
        let cost: f64 = idx.iter().map(|&i| costs[i]).sum();
        let ref_ms = match &units[idx[0]] {
            Unit::Projection { target, .. } => model.render_ms(target),
            Unit::Registration { .. }
            | Unit::RegistrationPhysical(_)
            | Unit::Calibration(_)
            | Unit::Intensity(_)
            | Unit::Tracking(_)
            | Unit::Screws { .. } => 0.0,
        };
        let pieces = ((cost / limit).ceil() as usize).clamp(1, idx.len());
        let per = idx.len().div_ceil(pieces);
        for chunk in idx.chunks(per) {
            out.push(Item {
                units: chunk.to_vec(),
                cost: chunk.iter().map(|&i| costs[i]).sum(),
                group: group.clone(),
                pair: pair.clone(),
                ref_ms,
            });
        }
    }
    out
}

/// [`assign`] with a given cost model: the longest-processing-time greedy rule over [`items`], each
/// to the shard that would finish it first counting the input group and reference it would have to
/// prepare.
pub fn assign_with(model: &CostModel, units: &[Unit], n: usize) -> Vec<usize> {
    let n = n.max(1);
    let costs: Vec<f64> = units.iter().map(|u| model.unit_cost(u)).collect();
    let items = items(model, units, &costs, n);
    let mut order: Vec<usize> = (0..items.len()).collect();
    order.sort_by(|&a, &b| items[b].cost.total_cmp(&items[a].cost).then(a.cmp(&b)));
    let mut load = vec![0.0f64; n];
    let mut groups: Vec<BTreeSet<InputGroup>> = vec![BTreeSet::new(); n];
    let mut refs: Vec<BTreeSet<(String, String)>> = vec![BTreeSet::new(); n];
    let mut setup: BTreeMap<InputGroup, f64> = BTreeMap::new();
    let mut out = vec![0usize; units.len()];
    for i in order {
        let it = &items[i];
        let group_ms = *setup
            .entry(it.group.clone())
            .or_insert_with(|| model.setup_cost(&it.group));
        let finish = |s: usize| {
            let mut t = load[s] + it.cost;
            if !groups[s].contains(&it.group) {
                t += group_ms;
            }
            if let Some(p) = &it.pair
                && !refs[s].contains(p)
            {
                t += it.ref_ms;
            }
            t
        };
        let mut best = 0;
        let mut best_t = finish(0);
        for s in 1..n {
            let t = finish(s);
            if t < best_t {
                (best, best_t) = (s, t);
            }
        }
        load[best] = best_t;
        groups[best].insert(it.group.clone());
        if let Some(p) = &it.pair {
            refs[best].insert(p.clone());
        }
        for &u in &it.units {
            out[u] = best;
        }
    }
    out
}

/// The expected finishing time (ms of one core) of each of `n` shards under `assignment`, with the
/// preparation each shard does.
pub fn shard_loads(model: &CostModel, units: &[Unit], assignment: &[usize], n: usize) -> Vec<f64> {
    let mut load = vec![0.0; n];
    let mut seen: BTreeSet<(usize, InputGroup)> = BTreeSet::new();
    let mut seen_ref: BTreeSet<(usize, String, String)> = BTreeSet::new();
    for (u, &s) in units.iter().zip(assignment) {
        load[s] += model.unit_cost(u);
        let (g, pair) = model.needs(u);
        if seen.insert((s, g.clone())) {
            load[s] += model.setup_cost(&g);
        }
        if let (Some((t, v)), Unit::Projection { target, .. }) = (pair, u)
            && seen_ref.insert((s, t, v))
        {
            load[s] += model.render_ms(target);
        }
    }
    load
}

/// The units of `shard`, in unit order.
pub fn units_of<'a>(cfg: &StudyConfig, units: &'a [Unit], shard: Shard) -> Vec<&'a Unit> {
    let a = assign(cfg, units, shard.count);
    units
        .iter()
        .zip(a)
        .filter(|(_, s)| *s == shard.index)
        .map(|(u, _)| u)
        .collect()
}

/// Which shards of `n` hold at least one of the `missing` units (by their positions in `units`).
pub fn shards_with(cfg: &StudyConfig, units: &[Unit], missing: &[usize], n: usize) -> Vec<usize> {
    let a = assign(cfg, units, n);
    let s: BTreeSet<usize> = missing.iter().map(|&i| a[i]).collect();
    s.into_iter().collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The default study's assignment to 4 shards: balanced (every shard within 10 % of the mean
    /// expected load) and clustered (few (target, view) references rendered twice).
    #[test]
    fn default_study_is_balanced_over_four_shards() {
        let cfg = StudyConfig::default();
        let units = crate::study::units::enumerate_units(&cfg).unwrap();
        let model = CostModel::of(&cfg);
        let a = assign_with(&model, &units, 4);
        let loads = shard_loads(&model, &units, &a, 4);
        let mean = loads.iter().sum::<f64>() / 4.0;
        for l in &loads {
            assert!((l - mean).abs() < 0.1 * mean, "{loads:?}");
        }
        let mut pairs: BTreeMap<(String, String), BTreeSet<usize>> = BTreeMap::new();
        for (u, s) in units.iter().zip(&a) {
            if let Unit::Projection { target, view, .. } = u {
                pairs
                    .entry((target.clone(), view.clone()))
                    .or_default()
                    .insert(*s);
            }
        }
        // Each reference is rendered by few shards: at most 1.5 × as many renders as unsharded.
        let renders: usize = pairs.values().map(|s| s.len()).sum();
        assert!(
            2 * renders <= 3 * pairs.len(),
            "{renders} renders: {pairs:?}"
        );
    }
}
