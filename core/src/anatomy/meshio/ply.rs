//! PLY (Turk 1994): ASCII and binary little-endian. Reads any element/property layout (unknown ones are
//! skipped by type); uses `vertex` x, y, z, `face` `vertex_indices`/`vertex_index` (polygons fanned) and
//! an optional per-face `label`. Writes double-precision vertices, `int` indices and a `uchar label`.

use std::io::{self, Write};
use std::path::Path;

use glam::DVec3;

use crate::anatomy::TriMesh;
use crate::{Error, Result};

#[derive(Clone, Copy)]
enum Ty {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Ty {
    fn parse(s: &str) -> Option<Ty> {
        Some(match s {
            "char" | "int8" => Ty::I8,
            "uchar" | "uint8" => Ty::U8,
            "short" | "int16" => Ty::I16,
            "ushort" | "uint16" => Ty::U16,
            "int" | "int32" => Ty::I32,
            "uint" | "uint32" => Ty::U32,
            "float" | "float32" => Ty::F32,
            "double" | "float64" => Ty::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Ty::I8 | Ty::U8 => 1,
            Ty::I16 | Ty::U16 => 2,
            Ty::I32 | Ty::U32 | Ty::F32 => 4,
            Ty::F64 => 8,
        }
    }

    fn decode(self, b: &[u8]) -> f64 {
        match self {
            Ty::I8 => f64::from(b[0] as i8),
            Ty::U8 => f64::from(b[0]),
            Ty::I16 => f64::from(i16::from_le_bytes([b[0], b[1]])),
            Ty::U16 => f64::from(u16::from_le_bytes([b[0], b[1]])),
            Ty::I32 => f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Ty::U32 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Ty::F32 => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Ty::F64 => f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]),
        }
    }
}

struct Prop {
    name: String,
    /// `Some(count type)` for a list property.
    list: Option<Ty>,
    ty: Ty,
}

struct Element {
    name: String,
    count: usize,
    props: Vec<Prop>,
}

/// Source of values: ASCII tokens or little-endian bytes.
enum Values<'a> {
    Ascii(std::str::SplitAsciiWhitespace<'a>),
    Binary(&'a [u8], usize),
}

impl Values<'_> {
    fn next(&mut self, ty: Ty) -> Option<f64> {
        match self {
            Values::Ascii(it) => it.next()?.parse().ok(),
            Values::Binary(b, pos) => {
                let v = ty.decode(b.get(*pos..*pos + ty.size())?);
                *pos += ty.size();
                Some(v)
            }
        }
    }
}

fn parse_header(text: &str, path: &Path) -> Result<(bool, Vec<Element>)> {
    let bad = |m: String| Error::format(path, m);
    let mut binary = None;
    let mut elements: Vec<Element> = Vec::new();
    for line in text.lines().skip(1) {
        let t: Vec<&str> = line.split_whitespace().collect();
        match t.as_slice() {
            ["format", "ascii", _] => binary = Some(false),
            ["format", "binary_little_endian", _] => binary = Some(true),
            ["format", f, ..] => return Err(bad(format!("unsupported PLY format {f:?}"))),
            ["element", name, n] => elements.push(Element {
                name: name.to_string(),
                count: n
                    .parse()
                    .map_err(|_| bad(format!("bad element count in {line:?}")))?,
                props: Vec::new(),
            }),
            ["property", rest @ ..] => {
                let el = elements
                    .last_mut()
                    .ok_or_else(|| bad("property before element".into()))?;
                let ty =
                    |s: &str| Ty::parse(s).ok_or_else(|| bad(format!("unknown PLY type {s:?}")));
                el.props.push(match rest {
                    ["list", c, i, name] => Prop {
                        name: name.to_string(),
                        list: Some(ty(c)?),
                        ty: ty(i)?,
                    },
                    [t, name] => Prop {
                        name: name.to_string(),
                        list: None,
                        ty: ty(t)?,
                    },
                    _ => return Err(bad(format!("bad property line {line:?}"))),
                });
            }
            _ => {}
        }
    }
    Ok((
        binary.ok_or_else(|| bad("PLY header has no format line".into()))?,
        elements,
    ))
}

pub fn parse(bytes: &[u8], path: &Path) -> Result<TriMesh> {
    if !bytes.starts_with(b"ply") {
        return Err(Error::format(path, "not a PLY file (no `ply` magic)"));
    }
    let end = bytes
        .windows(10)
        .position(|w| w == b"end_header")
        .ok_or_else(|| Error::format(path, "PLY header has no `end_header`"))?;
    let body_start = bytes[end..]
        .iter()
        .position(|&b| b == b'\n')
        .map_or(bytes.len(), |p| end + p + 1);
    let header = String::from_utf8_lossy(&bytes[..end]);
    let (binary, elements) = parse_header(&header, path)?;
    let mut values = if binary {
        Values::Binary(bytes, body_start)
    } else {
        let text = std::str::from_utf8(&bytes[body_start..])
            .map_err(|_| Error::format(path, "ASCII PLY body is not UTF-8"))?;
        Values::Ascii(text.split_ascii_whitespace())
    };
    // Every row reads at least one byte, so more rows than the body has bytes is a corrupt header; checked
    // (per element and in total) before the rows are read, so huge counts can neither allocate nor spin.
    let body_len = bytes.len() - body_start;
    if let Some(el) = elements.iter().find(|e| e.count > body_len) {
        return Err(Error::format(
            path,
            format!(
                "PLY element {} declares {} rows but the body holds only {body_len} bytes",
                el.name, el.count
            ),
        ));
    }
    let rows: usize = elements.iter().map(|e| e.count).sum();
    if rows > body_len {
        return Err(Error::format(
            path,
            format!(
                "PLY elements declare {rows} rows in all but the body holds only {body_len} bytes"
            ),
        ));
    }
    let mut mesh = TriMesh::default();
    let mut fans = Vec::new(); // triangles per face, to repeat a face's label over its fan
    for el in &elements {
        for row in 0..el.count {
            let truncated = || {
                Error::format(
                    path,
                    format!("PLY truncated or malformed in {} {row}", el.name),
                )
            };
            let mut xyz = [0.0; 3];
            for p in &el.props {
                if let Some(count_ty) = p.list {
                    let n = values.next(count_ty).ok_or_else(truncated)?;
                    if !(n >= 0.0 && n.fract() == 0.0 && n <= body_len as f64) {
                        return Err(Error::format(
                            path,
                            format!("PLY {} {row}: bad list length {n}", el.name),
                        ));
                    }
                    let n = n as usize;
                    // Grows with the values read, not with the declared length.
                    let mut idx = Vec::with_capacity(n.min(64));
                    for _ in 0..n {
                        idx.push(values.next(p.ty).ok_or_else(truncated)?);
                    }
                    if el.name == "face" && (p.name == "vertex_indices" || p.name == "vertex_index")
                    {
                        fans.push(add_polygon(&mut mesh, &idx, path)?);
                    }
                } else {
                    let v = values.next(p.ty).ok_or_else(truncated)?;
                    match (el.name.as_str(), p.name.as_str()) {
                        ("vertex", "x") => xyz[0] = v,
                        ("vertex", "y") => xyz[1] = v,
                        ("vertex", "z") => xyz[2] = v,
                        ("face", "label") => mesh.labels.push(v as u8),
                        _ => {}
                    }
                }
            }
            if el.name == "vertex" {
                mesh.vertices.push(DVec3::from_array(xyz));
            }
        }
    }
    if fans.len() == mesh.labels.len() {
        mesh.labels = mesh
            .labels
            .iter()
            .zip(&fans)
            .flat_map(|(&l, &n)| std::iter::repeat_n(l, n))
            .collect();
    } else {
        mesh.labels.clear();
    }
    Ok(mesh)
}

/// Fans a polygon into triangles; returns how many.
fn add_polygon(mesh: &mut TriMesh, idx: &[f64], path: &Path) -> Result<usize> {
    if idx.len() < 3
        || idx
            .iter()
            .any(|&i| i < 0.0 || i.fract() != 0.0 || i > u32::MAX as f64)
    {
        return Err(Error::format(path, format!("bad PLY face {idx:?}")));
    }
    for k in 1..idx.len() - 1 {
        mesh.triangles
            .push([idx[0] as u32, idx[k] as u32, idx[k + 1] as u32]);
    }
    Ok(idx.len() - 2)
}

pub fn write(w: &mut impl Write, m: &TriMesh, binary: bool) -> io::Result<()> {
    let format = if binary {
        "binary_little_endian"
    } else {
        "ascii"
    };
    writeln!(
        w,
        "ply\nformat {format} 1.0\ncomment {} {} millimetres",
        crate::io::TOOL,
        crate::VERSION
    )?;
    writeln!(w, "element vertex {}", m.vertices.len())?;
    writeln!(w, "property double x\nproperty double y\nproperty double z")?;
    writeln!(
        w,
        "element face {}\nproperty list uchar int vertex_indices",
        m.triangles.len()
    )?;
    let labelled = !m.labels.is_empty();
    if labelled {
        writeln!(w, "property uchar label")?;
    }
    writeln!(w, "end_header")?;
    for v in &m.vertices {
        if binary {
            for c in v.to_array() {
                w.write_all(&c.to_le_bytes())?;
            }
        } else {
            writeln!(w, "{} {} {}", v.x, v.y, v.z)?;
        }
    }
    for (i, t) in m.triangles.iter().enumerate() {
        let label = m.labels.get(i).copied().unwrap_or(0);
        if binary {
            w.write_all(&[3])?;
            for &k in t {
                w.write_all(&(k as i32).to_le_bytes())?;
            }
            if labelled {
                w.write_all(&[label])?;
            }
        } else if labelled {
            writeln!(w, "3 {} {} {} {label}", t[0], t[1], t[2])?;
        } else {
            writeln!(w, "3 {} {} {}", t[0], t[1], t[2])?;
        }
    }
    Ok(())
}
