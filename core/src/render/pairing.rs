//! From the surface crossings of one ray to its line integral `Σ_m μ_m · L_m`.
//!
//! A ray tracer's raw hits are refined in f64 from their triangles' planes (`t = (d − n·o) / (n·dir)`), so
//! the tracers produce the same distances once they agree on which triangles a ray crosses; the raster
//! computes the same distance from the triangle's plane in the camera frame. Per mesh, crossings are
//! sorted; when they alternate entry, exit, entry, exit… the length is `Σ (exit − entry)` directly.
//! Otherwise they are clustered (a ray through a shared edge or vertex reports it once per triangle): a
//! cluster whose triangles all face the ray is an entry, all facing away an exit, and a mixed one a
//! tangential touch. The ray is inside where the winding number (entries − exits) is positive; a ray whose
//! winding goes negative or does not return to zero lost a crossing, is reported as invalid, and the
//! renderer repairs it.

use glam::DVec3;

use super::scene::RenderScene;
use super::tracer::RawHit;

/// One refined surface crossing (16 bytes: renders move many of them).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Crossing {
    /// Distance along the ray.
    pub t: f64,
    /// Triangle of the mesh.
    pub prim: u32,
    /// Mesh of the scene (at most [`super::scene::MAX_MESHES`]).
    pub geom: u16,
    /// The triangle faces the ray's origin (the ray enters the mesh there), else it faces away.
    pub entry: bool,
}

/// The result of integrating one ray.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct RayIntegral {
    pub line_integral: f64,
    /// Distance from the origin to the first surface of a mesh the ray passes through (`inf` when none:
    /// grazing touches do not count, as for the silhouettes).
    pub first_t: f64,
    pub object_bits: u64,
    pub structure_bits: u32,
    pub hits: u32,
    /// Entries and exits paired up in every mesh.
    pub valid: bool,
}

/// A ray belongs to a mesh's silhouette when its chord exceeds this (mm). Rays grazing a surface have
/// chords of ~0 whose sign of difference from zero depends on f32 rounding in the backend; a micrometre
/// is far below anything a detector resolves.
pub(crate) const MIN_SILHOUETTE_CHORD_MM: f64 = 1e-3;

/// Rays nearly parallel to a triangle's plane cross it at an ill-conditioned distance; they are dropped
/// (the ray slides along the surface, contributing no length).
const MIN_COS: f64 = 1e-12;

/// Integrates one ray from its raw hits. `scratch` is reused between calls.
pub(crate) fn integrate(
    scene: &RenderScene,
    origin: DVec3,
    dir: DVec3,
    raw: &[RawHit],
    scratch: &mut Vec<Crossing>,
) -> RayIntegral {
    refine(scene, origin, dir, raw, scratch);
    integrate_crossings(scene, scratch, true)
}

/// The crossings of a ray's raw hits, refined from their triangles' planes, into `out` (cleared first).
fn refine(scene: &RenderScene, origin: DVec3, dir: DVec3, raw: &[RawHit], out: &mut Vec<Crossing>) {
    out.clear();
    out.reserve(raw.len());
    for h in raw {
        let Some(plane) = scene
            .planes
            .get(h.geom as usize)
            .and_then(|p| p.get(h.prim as usize))
        else {
            continue;
        };
        let facing = plane.n.dot(dir);
        if facing.is_nan() || facing.abs() < MIN_COS {
            continue;
        }
        let t = (plane.d - plane.n.dot(origin)) / facing;
        out.push(Crossing {
            t,
            prim: h.prim,
            geom: h.geom as u16,
            entry: facing < 0.0,
        });
    }
}

/// Integrates one ray from its crossings (any order; sorted in place), with `t` the distance from the ray's
/// origin in mm. The structure bits are filled only with `structures`.
pub(crate) fn integrate_crossings(
    scene: &RenderScene,
    crossings: &mut [Crossing],
    structures: bool,
) -> RayIntegral {
    sort_crossings(crossings);
    let mut out = RayIntegral {
        first_t: f64::INFINITY,
        valid: true,
        hits: crossings.len() as u32,
        ..Default::default()
    };
    if scene.has_implants()
        && crossings
            .iter()
            .any(|c| scene.implants[usize::from(c.geom)])
    {
        return integrate_with_implants(scene, crossings, structures, out);
    }
    for (g, range) in mesh_groups(crossings) {
        let group = &crossings[range];
        let (length, ok) = pair_alternating(group).map_or_else(|| pair_mesh(group), |l| (l, true));
        out.valid &= ok;
        out.line_integral += scene.meshes[g].mu_per_mm * length;
        mark_silhouette(scene, g, group, length, structures, &mut out);
    }
    out
}

/// Sorts crossings by (mesh, distance): few per ray, so an insertion sort beats the general sort.
fn sort_crossings(crossings: &mut [Crossing]) {
    for i in 1..crossings.len() {
        let c = crossings[i];
        let mut j = i;
        while j > 0 && before(&c, &crossings[j - 1]) {
            crossings[j] = crossings[j - 1];
            j -= 1;
        }
        crossings[j] = c;
    }
}

/// The union of every mesh's inside intervals along one ray from its raw hits (sorted, disjoint, `t` in
/// mm from the origin), and whether every mesh's crossings paired up. `scratch` is reused between calls.
pub(crate) fn union_intervals(
    scene: &RenderScene,
    origin: DVec3,
    dir: DVec3,
    raw: &[RawHit],
    scratch: &mut Vec<Crossing>,
) -> (Vec<(f64, f64)>, bool) {
    refine(scene, origin, dir, raw, scratch);
    sort_crossings(scratch);
    let mut all = Vec::new();
    let mut ok = true;
    for (_, range) in mesh_groups(scratch) {
        ok &= mesh_intervals(&scratch[range], &mut all);
    }
    (merge_intervals(all), ok)
}

/// Intervals merged into a sorted, disjoint union.
fn merge_intervals(mut v: Vec<(f64, f64)>) -> Vec<(f64, f64)> {
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut merged: Vec<(f64, f64)> = Vec::with_capacity(v.len());
    for (a, b) in v {
        match merged.last_mut() {
            Some(last) if a <= last.1 => last.1 = last.1.max(b),
            _ => merged.push((a, b)),
        }
    }
    merged
}

/// The runs of `crossings` (sorted by mesh, then distance) that belong to one mesh: `(mesh, range)`.
#[inline]
fn mesh_groups(
    crossings: &[Crossing],
) -> impl Iterator<Item = (usize, std::ops::Range<usize>)> + '_ {
    let mut start = 0;
    std::iter::from_fn(move || {
        if start >= crossings.len() {
            return None;
        }
        let geom = crossings[start].geom;
        let mut end = start + 1;
        while end < crossings.len() && crossings[end].geom == geom {
            end += 1;
        }
        let range = start..end;
        start = end;
        Some((usize::from(geom), range))
    })
}

/// A mesh whose inside `length` along the ray passes [`MIN_SILHOUETTE_CHORD_MM`] puts the ray in its
/// object's silhouette (and, with `structures`, in its crossed triangles' structures) and may be its
/// first surface.
#[inline]
fn mark_silhouette(
    scene: &RenderScene,
    g: usize,
    group: &[Crossing],
    length: f64,
    structures: bool,
    out: &mut RayIntegral,
) {
    if length > MIN_SILHOUETTE_CHORD_MM {
        out.first_t = out.first_t.min(group[0].t);
        out.object_bits |= 1u64 << scene.object_of_mesh[g];
        if structures {
            let mesh = &scene.meshes[g].mesh;
            for c in group {
                out.structure_bits |= 1u32 << mesh.label(c.prim as usize) as u32;
            }
        }
    }
}

/// [`integrate_crossings`] of a scene with implants, from crossings sorted by (mesh, distance): each mesh's
/// inside intervals; the union of the implants' intervals; every other mesh's length less its overlap with
/// that union (what an implant occupies is only the implant).
fn integrate_with_implants(
    scene: &RenderScene,
    crossings: &[Crossing],
    structures: bool,
    mut out: RayIntegral,
) -> RayIntegral {
    // Per mesh group (few per ray): the mesh, its inside intervals, its crossings.
    type Group<'c> = (usize, Vec<(f64, f64)>, &'c [Crossing]);
    let mut groups: Vec<Group> = Vec::new();
    for (g, range) in mesh_groups(crossings) {
        let mut iv = Vec::new();
        out.valid &= mesh_intervals(&crossings[range.clone()], &mut iv);
        groups.push((g, iv, &crossings[range]));
    }
    let merged = merge_intervals(
        groups
            .iter()
            .filter(|g| scene.implants[g.0])
            .flat_map(|g| g.1.iter().copied())
            .collect(),
    );
    for (g, iv, group) in &groups {
        let length: f64 = iv.iter().map(|(a, b)| b - a).sum();
        let counted = if scene.implants[*g] {
            length
        } else {
            let overlap: f64 = iv
                .iter()
                .flat_map(|&(a, b)| {
                    merged
                        .iter()
                        .map(move |&(c, d)| (b.min(d) - a.max(c)).max(0.0))
                })
                .sum();
            length - overlap
        };
        out.line_integral += scene.meshes[*g].mu_per_mm * counted;
        mark_silhouette(scene, *g, group, length, structures, &mut out);
    }
    out
}

/// Order of crossings: by mesh, then by distance (finite: crossings at grazing angles were dropped).
#[inline]
fn before(a: &Crossing, b: &Crossing) -> bool {
    a.geom < b.geom || (a.geom == b.geom && a.t < b.t)
}

/// Two crossings of one mesh closer than this (mm, plus a relative part) are one crossing; `a ≤ b` (sorted).
#[inline]
fn same_point(a: f64, b: f64) -> bool {
    b - a <= 1e-7 + 1e-10 * a.abs().max(b.abs())
}

/// The common case of [`pair_mesh`], without its clustering: sorted crossings that alternate entry, exit,
/// entry, exit… enclose `Σ (exit − entry)`. Two of them at the same point (a ray through a shared edge
/// or vertex) either break the alternation (two entries: left to `pair_mesh`) or are an entry and exit
/// there (a tangential touch, whose zero length is the same either way). `None` when they do not alternate.
#[inline]
fn pair_alternating(crossings: &[Crossing]) -> Option<f64> {
    if !crossings.len().is_multiple_of(2) {
        return None;
    }
    let mut length = 0.0;
    let mut alternate = true;
    for p in crossings.chunks_exact(2) {
        alternate &= p[0].entry & !p[1].entry;
        length += p[1].t - p[0].t;
    }
    alternate.then_some(length)
}

/// Total inside length of one mesh from its sorted crossings, and whether they paired up.
///
/// Inside is a positive winding number: entries raise it, exits lower it, so overlapping closed pieces of one
/// surface (or a self-intersecting surface) count their union once. The crossings pair up when the winding
/// never goes negative and returns to zero. Crossings at the same point (a ray through a shared edge or
/// vertex reports it once per triangle) form one cluster: an entry when all face the ray, an exit when all
/// face away, a tangential touch otherwise.
fn pair_mesh(crossings: &[Crossing]) -> (f64, bool) {
    let mut length = 0.0;
    let ok = walk_intervals(crossings, |a, b| length += b - a);
    (length, ok)
}

/// The inside intervals of one mesh from its sorted crossings (the winding rule of [`pair_mesh`]), into
/// `out`; whether the crossings paired up.
fn mesh_intervals(crossings: &[Crossing], out: &mut Vec<(f64, f64)>) -> bool {
    walk_intervals(crossings, |a, b| out.push((a, b)))
}

/// Calls `interval(entry, exit)` for each stretch where the winding number of the sorted `crossings` is
/// positive (see [`pair_mesh`]); whether they paired up (the winding never went negative and returned to 0).
fn walk_intervals(crossings: &[Crossing], mut interval: impl FnMut(f64, f64)) -> bool {
    let mut winding: i32 = 0;
    let mut inside_since = 0.0;
    let mut ok = true;
    let mut i = 0;
    while i < crossings.len() {
        let t = crossings[i].t;
        let (mut all_in, mut all_out) = (crossings[i].entry, !crossings[i].entry);
        let mut j = i + 1;
        while j < crossings.len() && same_point(crossings[j - 1].t, crossings[j].t) {
            all_in &= crossings[j].entry;
            all_out &= !crossings[j].entry;
            j += 1;
        }
        let step = i32::from(all_in) - i32::from(all_out);
        if winding == 0 && step > 0 {
            inside_since = t;
        }
        winding += step;
        if winding < 0 {
            ok = false;
            winding = 0;
        } else if winding == 0 && step < 0 {
            interval(inside_since, t);
        }
        i = j;
    }
    ok && winding == 0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn c(t: f64, facing: f64) -> Crossing {
        Crossing {
            t,
            prim: 0,
            geom: 0,
            entry: facing < 0.0,
        }
    }

    #[test]
    fn pairs_entries_and_exits() {
        let (l, ok) = pair_mesh(&[c(1.0, -1.0), c(3.0, 1.0), c(5.0, -0.5), c(5.5, 0.2)]);
        assert!(ok);
        assert!((l - 2.5).abs() < 1e-12);
    }

    #[test]
    fn duplicates_at_shared_edges_count_once() {
        let (l, ok) = pair_mesh(&[c(1.0, -1.0), c(1.0 + 1e-12, -0.3), c(3.0, 1.0), c(3.0, 0.4)]);
        assert!(ok);
        assert!((l - 2.0).abs() < 1e-12);
    }

    #[test]
    fn tangential_touch_is_ignored() {
        let (l, ok) = pair_mesh(&[c(2.0, -1.0), c(2.0, 1.0)]);
        assert!(ok && l == 0.0);
    }

    #[test]
    fn overlapping_pieces_count_their_union_once() {
        let (l, ok) = pair_mesh(&[c(1.0, -1.0), c(2.0, -1.0), c(3.0, 1.0), c(4.0, 1.0)]);
        assert!(ok);
        assert!((l - 3.0).abs() < 1e-12);
    }

    #[test]
    fn missing_exit_is_invalid() {
        assert!(!pair_mesh(&[c(1.0, -1.0), c(2.0, -1.0), c(3.0, 1.0)]).1);
        assert!(!pair_mesh(&[c(1.0, -1.0), c(2.0, 1.0), c(3.0, 1.0)]).1);
        assert!(!pair_mesh(&[c(1.0, -1.0)]).1);
        assert!(!pair_mesh(&[c(1.0, 1.0)]).1);
    }

    /// Every entry/exit pattern of up to 8 crossings, at sorted depths that often coincide or nearly so:
    /// wherever the alternating shortcut answers, its length is that of its entry–exit intervals, and when
    /// no two crossings are close enough to be clustered the general winding-number pairing agrees. (With
    /// three or more crossings at one point the reading is ambiguous, a touch next to an entry, and the
    /// general pairing's clusters may read it differently.)
    #[test]
    fn alternating_shortcut_agrees_with_the_general_pairing() {
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        let mut answered = 0;
        for n in 0..=8usize {
            // Entries at even positions (bit i set: entry): the patterns the shortcut answers, tried often.
            let alternating = 0x5555_5555u32 & ((1u32 << n) - 1);
            for pattern in 0..1u32 << n {
                let tries = if pattern == alternating { 500 } else { 6 };
                for _ in 0..tries {
                    let mut t: Vec<f64> = (0..n)
                        .map(|_| {
                            let r = next();
                            // Five depths, some a hair apart (one cluster) or exactly equal.
                            (r % 5) as f64 * 2.5 + [0.0, 0.0, 3e-9, 0.4][(r >> 8) as usize % 4]
                        })
                        .collect();
                    t.sort_by(f64::total_cmp);
                    let cs: Vec<Crossing> = t
                        .iter()
                        .enumerate()
                        .map(|(i, &t)| c(t, if pattern >> i & 1 == 1 { -1.0 } else { 1.0 }))
                        .collect();
                    if let Some(l) = pair_alternating(&cs) {
                        let intervals: f64 = t.chunks(2).map(|p| p[1] - p[0]).sum();
                        assert_eq!(l, intervals, "{cs:?}");
                        if t.windows(2).all(|p| !same_point(p[0], p[1])) {
                            answered += 1;
                            let (general, ok) = pair_mesh(&cs);
                            assert!(ok, "{cs:?}");
                            assert!((l - general).abs() < 1e-12, "{l} vs {general}: {cs:?}");
                        }
                    }
                }
            }
        }
        assert!(answered > 1000, "only {answered} answers to compare");
    }
}
