//! Wavefront OBJ: `v x y z` and `f a b c …` (1-based, negative = relative, `a/b/c` forms accepted,
//! polygons fanned); structure labels as `g <structure name>` groups.

use std::io::{self, Write};
use std::path::Path;

use glam::DVec3;

use crate::anatomy::{Structure, TriMesh};
use crate::{Error, Result};

pub fn parse(bytes: &[u8], path: &Path) -> Result<TriMesh> {
    let text =
        std::str::from_utf8(bytes).map_err(|_| Error::format(path, "OBJ is not UTF-8 text"))?;
    let mut mesh = TriMesh::default();
    let mut group: Option<Structure> = None;
    let mut any_group = false;
    for (no, line) in text.lines().enumerate() {
        let bad =
            |what: &str| Error::format(path, format!("line {}: {what}: {:?}", no + 1, line.trim()));
        let mut tok = line.split_whitespace();
        match tok.next() {
            Some("v") => {
                let mut c = [0.0; 3];
                for v in &mut c {
                    *v = tok
                        .next()
                        .and_then(|s| s.parse().ok())
                        .ok_or_else(|| bad("bad vertex"))?;
                }
                mesh.vertices.push(DVec3::from_array(c));
            }
            Some("f") => {
                let n = mesh.vertices.len() as i64;
                let idx = tok
                    .map(|t| {
                        let i: i64 = t
                            .split('/')
                            .next()
                            .unwrap_or("")
                            .parse()
                            .map_err(|_| bad("bad face"))?;
                        let i = if i < 0 { n + i } else { i - 1 };
                        if i < 0 || i >= n {
                            return Err(bad("face index out of range"));
                        }
                        Ok(i as u32)
                    })
                    .collect::<Result<Vec<u32>>>()?;
                if idx.len() < 3 {
                    return Err(bad("face with fewer than 3 vertices"));
                }
                for k in 1..idx.len() - 1 {
                    mesh.triangles.push([idx[0], idx[k], idx[k + 1]]);
                    mesh.labels.push(group.map_or(0, |s| s as u8));
                }
            }
            Some("g") => {
                let name = tok.next().unwrap_or("");
                group = Structure::ALL.iter().copied().find(|s| s.name() == name);
                any_group |= group.is_some();
            }
            Some("o") if mesh.name.is_empty() => mesh.name = tok.collect::<Vec<_>>().join(" "),
            _ => {}
        }
    }
    if !any_group {
        mesh.labels.clear();
    }
    Ok(mesh)
}

pub fn write(w: &mut impl Write, m: &TriMesh) -> io::Result<()> {
    writeln!(w, "# {} {}, millimetres", crate::io::TOOL, crate::VERSION)?;
    writeln!(w, "o {}", m.name.replace(char::is_whitespace, "_"))?;
    for v in &m.vertices {
        // `{}` prints the shortest string that parses back to the same f64.
        writeln!(w, "v {} {} {}", v.x, v.y, v.z)?;
    }
    let mut current: Option<u8> = None;
    for (i, t) in m.triangles.iter().enumerate() {
        if let Some(&l) = m.labels.get(i)
            && current != Some(l)
        {
            writeln!(w, "g {}", m.label(i).name())?;
            current = Some(l);
        }
        writeln!(w, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1)?;
    }
    Ok(())
}
