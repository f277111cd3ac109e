//! A parametric pedicle screw: a threaded shank with a conical tip and a tulip head, as closed meshes
//! placed along a planned trajectory (entry point to tip).
//!
//! The shank is a surface of revolution whose radius follows a helical V-thread,
//! `r(θ, z) = r_core + depth · (1 − |2 frac(z / pitch − θ / 2π) − 1|)`, tapering linearly to a point over the
//! tip. The default thread is the pitch of ISO 5835's 6.5 mm cancellous-bone thread (HB 6.5: 6.5 mm major
//! diameter, 2.75 mm pitch) with a 4.5 mm core, the proportions of a common lumbar pedicle screw; the
//! tulip head is a solid cylinder (12 mm across, 14 mm tall) standing on the entry point, outside the
//! bone. Lengths follow the trajectory: the tip of the shank is the planned tip point.

use std::f64::consts::TAU;

use glam::{DMat3, DVec3};

use super::TriMesh;
use crate::{Error, Result};

/// The screw's dimensions (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScrewSpec {
    /// Thread (major) diameter.
    pub major_diameter: f64,
    /// Core (minor) diameter.
    pub core_diameter: f64,
    /// Thread pitch.
    pub pitch: f64,
    /// Length of the conical tip.
    pub tip_length: f64,
    /// Tulip head diameter and height.
    pub head_diameter: f64,
    pub head_height: f64,
}

impl Default for ScrewSpec {
    fn default() -> Self {
        ScrewSpec {
            major_diameter: 6.5,
            core_diameter: 4.5,
            pitch: 2.75,
            tip_length: 4.0,
            head_diameter: 12.0,
            head_height: 14.0,
        }
    }
}

/// Facets around the axis and rings per pitch of the tessellation.
const AROUND: u32 = 24;
const RINGS_PER_PITCH: f64 = 6.0;

impl ScrewSpec {
    fn check(&self, length: f64) -> Result<()> {
        let s = self;
        let ok = s.core_diameter > 0.0
            && s.major_diameter > s.core_diameter
            && s.pitch > 0.0
            && s.tip_length > 0.0
            && s.head_diameter > 0.0
            && s.head_height > 0.0
            && length > s.tip_length
            && length <= 200.0;
        if ok
            && [s.major_diameter, s.pitch, s.head_diameter, s.head_height]
                .iter()
                .all(|v| v.is_finite())
        {
            Ok(())
        } else {
            Err(Error::invalid(
                "screw",
                format!(
                    "{s:?} of length {length} mm: diameters, pitch, tip and head must be positive, the \
                         major diameter above the core, the length above the tip (at most 200 mm)"
                ),
            ))
        }
    }

    /// The shank (threaded, conical tip) and the tulip head of a screw whose proximal end is at `entry`
    /// and whose tip is at `tip`, named `NAME_shank` and `NAME_head`.
    pub fn meshes(&self, name: &str, entry: DVec3, tip: DVec3) -> Result<(TriMesh, TriMesh)> {
        let axis = tip - entry;
        let length = axis.length();
        self.check(length)?;
        let frame = frame_along(axis / length);
        let place = |p: DVec3| entry + frame * p;
        let shank = self
            .shank(length)
            .into_iter()
            .map(place)
            .collect::<Vec<_>>();
        let (shank_v, shank_t) = (shank, shank_triangles(self.rings(length)));
        let mut shank = TriMesh::new(format!("{name}_shank"), shank_v, shank_t);
        shank.orient_outward();
        let r = self.head_diameter / 2.0;
        let mut head = cylinder(r, -self.head_height, 0.0);
        head.iter_mut().for_each(|p| *p = place(*p));
        let mut head = TriMesh::new(format!("{name}_head"), head, cylinder_triangles());
        head.orient_outward();
        Ok((shank, head))
    }

    fn rings(&self, length: f64) -> u32 {
        ((length / self.pitch * RINGS_PER_PITCH).ceil() as u32).max(2)
    }

    /// Shank vertices in the screw frame (z from 0 at the entry to `length` at the tip): rings of
    /// [`AROUND`] vertices, then the proximal centre and the apex.
    fn shank(&self, length: f64) -> Vec<DVec3> {
        let rings = self.rings(length);
        let (core, depth) = (
            self.core_diameter / 2.0,
            (self.major_diameter - self.core_diameter) / 2.0,
        );
        let mut v = Vec::with_capacity((rings as usize + 1) * AROUND as usize + 2);
        for i in 0..=rings {
            let z = length * f64::from(i) / f64::from(rings);
            let taper = ((length - z) / self.tip_length).min(1.0);
            for k in 0..AROUND {
                let theta = TAU * f64::from(k) / f64::from(AROUND);
                let s = (z / self.pitch - theta / TAU).rem_euclid(1.0);
                let r = (core + depth * (1.0 - (2.0 * s - 1.0).abs())) * taper;
                v.push(DVec3::new(r * theta.cos(), r * theta.sin(), z));
            }
        }
        v.push(DVec3::ZERO);
        v.push(DVec3::new(0.0, 0.0, length));
        v
    }
}

/// Triangles of the shank's rings (the last ring, radius 0, collapses onto the apex; its triangles are
/// degenerate slivers of zero area only where the radius is 0) plus the proximal cap fan.
fn shank_triangles(rings: u32) -> Vec<[u32; 3]> {
    let n = AROUND;
    let centre = (rings + 1) * n;
    let mut t = Vec::new();
    for i in 0..rings - 1 {
        for k in 0..n {
            let (a, b) = (i * n + k, i * n + (k + 1) % n);
            let (c, d) = (a + n, b + n);
            t.push([a, b, d]);
            t.push([a, d, c]);
        }
    }
    // The ring before the apex closes onto the apex vertex.
    let apex = centre + 1;
    let last = (rings - 1) * n;
    for k in 0..n {
        t.push([last + k, last + (k + 1) % n, apex]);
        t.push([centre, (k + 1) % n, k]);
    }
    t
}

/// A closed cylinder of radius `r` from z0 to z1: two rings of [`AROUND`] and two centres.
fn cylinder(r: f64, z0: f64, z1: f64) -> Vec<DVec3> {
    let mut v = Vec::new();
    for z in [z0, z1] {
        for k in 0..AROUND {
            let a = TAU * f64::from(k) / f64::from(AROUND);
            v.push(DVec3::new(r * a.cos(), r * a.sin(), z));
        }
    }
    v.push(DVec3::new(0.0, 0.0, z0));
    v.push(DVec3::new(0.0, 0.0, z1));
    v
}

fn cylinder_triangles() -> Vec<[u32; 3]> {
    let n = AROUND;
    let (c0, c1) = (2 * n, 2 * n + 1);
    let mut t = Vec::new();
    for k in 0..n {
        let k1 = (k + 1) % n;
        t.push([k, k1, n + k1]);
        t.push([k, n + k1, n + k]);
        t.push([c0, k1, k]);
        t.push([c1, n + k, n + k1]);
    }
    t
}

/// A rotation taking +z to `dir` (unit).
fn frame_along(dir: DVec3) -> DMat3 {
    let helper = if dir.x.abs() < 0.9 {
        DVec3::X
    } else {
        DVec3::Y
    };
    let x = helper.cross(dir).normalize();
    let y = dir.cross(x);
    DMat3::from_cols(x, y, dir)
}

/// A planned screw: its name (the entry landmark's name without `pedicle_entry`), entry and tip (world mm).
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedScrew {
    pub name: String,
    pub entry: DVec3,
    pub tip: DVec3,
}

/// The planned screws among `points`: each `PREFIXpedicle_entry` with a `PREFIXpedicle_tip`, in name order.
pub fn planned_screws(points: &[(String, DVec3)]) -> Vec<PlannedScrew> {
    let mut out: Vec<PlannedScrew> = points
        .iter()
        .filter_map(|(n, entry)| {
            let prefix = n.strip_suffix("pedicle_entry")?;
            let tip_name = format!("{prefix}pedicle_tip");
            let (_, tip) = points.iter().find(|(m, _)| *m == tip_name)?;
            Some(PlannedScrew {
                name: prefix.trim_end_matches(['_', '-']).to_string(),
                entry: *entry,
                tip: *tip,
            })
        })
        .collect();
    out.sort_by(|a, b| a.name.cmp(&b.name));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn screws_pair_each_entry_with_the_tip_of_its_prefix() {
        let p = |x: f64| DVec3::new(x, 0.0, 0.0);
        let points = vec![
            ("L2/right_pedicle_tip".to_string(), p(4.0)),
            ("left_pedicle_entry".to_string(), p(1.0)),
            ("L2/right_pedicle_entry".to_string(), p(3.0)),
            ("left_pedicle_tip".to_string(), p(2.0)),
            ("left_pedicle_isthmus".to_string(), p(9.0)),
            ("right_pedicle_entry".to_string(), p(5.0)),
        ];
        let s = planned_screws(&points);
        let names: Vec<&str> = s.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["L2/right", "left"]);
        assert_eq!((s[0].entry, s[0].tip), (p(3.0), p(4.0)));
        assert_eq!((s[1].entry, s[1].tip), (p(1.0), p(2.0)));
    }

    #[test]
    fn the_screw_is_closed_and_its_volume_lies_between_core_and_major_cylinders() {
        let spec = ScrewSpec::default();
        let (entry, tip) = (DVec3::new(10.0, -40.0, 5.0), DVec3::new(5.0, 0.0, 2.0));
        let (shank, head) = spec.meshes("L3_left", entry, tip).unwrap();
        assert!(shank.check().is_watertight() && head.check().is_watertight());
        let l = (tip - entry).length();
        let (rc, rm) = (spec.core_diameter / 2.0, spec.major_diameter / 2.0);
        let v = shank.volume();
        let cyl = |r: f64| std::f64::consts::PI * r * r * (l - spec.tip_length);
        assert!(
            v > cyl(rc) && v < cyl(rm) + cyl(rm) * spec.tip_length / l,
            "{v}"
        );
        // A V-thread fills half the annulus between core and major radius (on average over a turn).
        let mid = cyl(rc) + 0.5 * (cyl(rm) - cyl(rc));
        assert!((v - mid).abs() < 0.08 * mid, "{v} vs {mid}");
        // The apex is the tip point; the head stands behind the entry, outside the trajectory.
        assert!(shank.vertices.iter().any(|p| (*p - tip).length() < 1e-9));
        let behind = (entry - tip).normalize();
        assert!(
            head.vertices
                .iter()
                .all(|p| (*p - entry).dot(behind) >= -1e-9)
        );
        assert!(spec.meshes("x", entry, entry + DVec3::X * 2.0).is_err());
    }
}
