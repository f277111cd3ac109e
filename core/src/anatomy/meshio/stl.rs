//! STL: binary (80-byte header, `u32` count, 50 bytes per triangle) and ASCII (`solid … endsolid`).

use std::io::{self, Write};
use std::path::Path;

use glam::DVec3;

use super::weld_vertices;
use crate::anatomy::{Structure, TriMesh};
use crate::{Error, Result};

/// Parses either flavour: binary when the size matches `84 + 50·n`, ASCII when it starts with `solid`.
pub fn parse(bytes: &[u8], path: &Path) -> Result<TriMesh> {
    if bytes.len() >= 84 {
        let n = u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as u64;
        if bytes.len() as u64 == 84 + 50 * n {
            return parse_binary(bytes, n as usize);
        }
    }
    let head = String::from_utf8_lossy(&bytes[..bytes.len().min(512)]).to_string();
    if head.trim_start().starts_with("solid") && !head.contains('\0') {
        return parse_ascii(bytes, path);
    }
    if bytes.len() >= 84 {
        let n = u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as u64;
        return Err(Error::format(
            path,
            format!(
                "binary STL truncated or corrupt: {n} triangles need {} bytes, the file has {}",
                84 + 50 * n,
                bytes.len()
            ),
        ));
    }
    Err(Error::format(
        path,
        "not an STL file (too short for binary, no `solid` header)",
    ))
}

fn parse_binary(bytes: &[u8], n: usize) -> Result<TriMesh> {
    let mut mesh = TriMesh::default();
    let mut attrs = Vec::with_capacity(n);
    let f = |o: usize| f32::from_le_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]]);
    for t in 0..n {
        let base = 84 + 50 * t + 12; // skip the facet normal
        let first = mesh.vertices.len() as u32;
        for c in 0..3 {
            let o = base + 12 * c;
            mesh.vertices
                .push(DVec3::new(f(o).into(), f(o + 4).into(), f(o + 8).into()));
        }
        mesh.triangles.push([first, first + 1, first + 2]);
        attrs.push(u16::from_le_bytes([bytes[base + 36], bytes[base + 37]]));
    }
    let known = |a: u16| a <= u8::MAX as u16 && Structure::from_u8(a as u8).is_some();
    if attrs.iter().any(|&a| a != 0) && attrs.iter().all(|&a| known(a)) {
        mesh.labels = attrs.iter().map(|&a| a as u8).collect();
    }
    weld_vertices(&mut mesh);
    Ok(mesh)
}

fn parse_ascii(bytes: &[u8], path: &Path) -> Result<TriMesh> {
    let text =
        std::str::from_utf8(bytes).map_err(|_| Error::format(path, "ASCII STL is not UTF-8"))?;
    let mut mesh = TriMesh::default();
    let mut ended = false;
    for (no, line) in text.lines().enumerate() {
        let mut tok = line.split_whitespace();
        match tok.next() {
            Some("solid") if no == 0 || mesh.name.is_empty() => {
                mesh.name = tok.collect::<Vec<_>>().join(" ");
            }
            Some("vertex") => {
                let mut c = [0.0; 3];
                for v in &mut c {
                    *v = tok
                        .next()
                        .and_then(|s| s.parse::<f32>().ok())
                        .map(f64::from)
                        .ok_or_else(|| {
                            Error::format(
                                path,
                                format!("line {}: bad vertex {:?}", no + 1, line.trim()),
                            )
                        })?;
                }
                mesh.vertices.push(DVec3::from_array(c));
            }
            Some("endloop") => {
                let n = mesh.vertices.len() as u32;
                if n == 0 || !n.is_multiple_of(3) || n / 3 != mesh.triangles.len() as u32 + 1 {
                    return Err(Error::format(
                        path,
                        format!(
                            "line {}: a facet loop does not have exactly 3 vertices",
                            no + 1
                        ),
                    ));
                }
                mesh.triangles.push([n - 3, n - 2, n - 1]);
            }
            Some("endsolid") => ended = true,
            _ => {}
        }
    }
    if !ended {
        return Err(Error::format(path, "ASCII STL truncated: no `endsolid`"));
    }
    weld_vertices(&mut mesh);
    Ok(mesh)
}

fn normal(m: &TriMesh, i: usize) -> DVec3 {
    let [a, b, c] = m.corners(i);
    (b - a).cross(c - a).normalize_or_zero()
}

pub fn write_binary(w: &mut impl Write, m: &TriMesh) -> io::Result<()> {
    let mut header = [b' '; 80];
    let text = format!("{} {} {}", crate::io::TOOL, crate::VERSION, m.name);
    let n = text.len().min(80);
    header[..n].copy_from_slice(&text.as_bytes()[..n]);
    w.write_all(&header)?;
    w.write_all(&(m.triangles.len() as u32).to_le_bytes())?;
    for i in 0..m.triangles.len() {
        let mut rec = Vec::with_capacity(50);
        for v in std::iter::once(normal(m, i)).chain(m.corners(i)) {
            for c in v.to_array() {
                rec.extend_from_slice(&(c as f32).to_le_bytes());
            }
        }
        rec.extend_from_slice(&u16::from(m.labels.get(i).copied().unwrap_or(0)).to_le_bytes());
        w.write_all(&rec)?;
    }
    Ok(())
}

pub fn write_ascii(w: &mut impl Write, m: &TriMesh) -> io::Result<()> {
    let name = m.name.replace(char::is_whitespace, "_");
    writeln!(w, "solid {name}")?;
    for i in 0..m.triangles.len() {
        let n = normal(m, i);
        writeln!(
            w,
            "facet normal {:e} {:e} {:e}",
            n.x as f32, n.y as f32, n.z as f32
        )?;
        writeln!(w, "  outer loop")?;
        for v in m.corners(i) {
            // f32 like binary STL, so both flavours round-trip to the same vertices.
            writeln!(
                w,
                "    vertex {:e} {:e} {:e}",
                v.x as f32, v.y as f32, v.z as f32
            )?;
        }
        writeln!(w, "  endloop")?;
        writeln!(w, "endfacet")?;
    }
    writeln!(w, "endsolid {name}")
}
