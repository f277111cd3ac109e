//! Mesh files: STL (binary and ASCII), Wavefront OBJ and PLY (ASCII and binary little-endian), chosen by
//! the file extension on writing and by extension plus content on reading.
//!
//! * STL stores each triangle's corners separately; reading **welds** corners with bit-identical
//!   coordinates, so a closed mesh written as STL reads back closed. Binary STL carries the structure
//!   label in the 16-bit attribute word (read back when every word is a known label).
//! * OBJ carries labels as groups (`g body`), PLY as a per-face `uchar label` property.
//! * Errors are [`Error::Format`]/[`Error::Io`] naming the file: missing, truncated, malformed, or
//!   holding no triangles.

mod obj;
mod ply;
mod stl;

use std::collections::HashMap;
use std::path::Path;

use glam::DVec3;

use super::TriMesh;
use crate::{Error, Result};

/// A mesh file format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshFormat {
    StlBinary,
    StlAscii,
    Obj,
    PlyAscii,
    PlyBinary,
}

impl MeshFormat {
    /// The default format for a path's extension: `.stl` binary STL, `.obj`, `.ply` binary PLY.
    pub fn from_path(path: &Path) -> Result<MeshFormat> {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        match ext.as_str() {
            "stl" => Ok(MeshFormat::StlBinary),
            "obj" => Ok(MeshFormat::Obj),
            "ply" => Ok(MeshFormat::PlyBinary),
            _ => Err(Error::format(
                path,
                format!("unknown mesh extension {ext:?} (expected .stl, .obj or .ply)"),
            )),
        }
    }

    /// The file extension (without the dot).
    pub fn extension(self) -> &'static str {
        match self {
            MeshFormat::StlBinary | MeshFormat::StlAscii => "stl",
            MeshFormat::Obj => "obj",
            MeshFormat::PlyAscii | MeshFormat::PlyBinary => "ply",
        }
    }
}

/// Reads a mesh; the format comes from the extension (STL and PLY flavours from the content).
pub fn read_mesh(path: &Path) -> Result<TriMesh> {
    let format = MeshFormat::from_path(path)?;
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let mut mesh = parse_mesh(&bytes, format, path)?;
    if mesh.name.is_empty() {
        mesh.name = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
    }
    Ok(mesh)
}

/// Parses a mesh file's bytes: `format` picks STL, OBJ or PLY (the STL and PLY flavours come from the
/// content), `origin` names the source in errors. The mesh is validated (triangles present, finite
/// vertices, indices in range); its name is the file's own (`solid`, `o`) or empty.
pub fn parse_mesh(bytes: &[u8], format: MeshFormat, origin: &Path) -> Result<TriMesh> {
    let mesh = match format {
        MeshFormat::StlBinary | MeshFormat::StlAscii => stl::parse(bytes, origin)?,
        MeshFormat::Obj => obj::parse(bytes, origin)?,
        MeshFormat::PlyAscii | MeshFormat::PlyBinary => ply::parse(bytes, origin)?,
    };
    if mesh.triangles.is_empty() {
        return Err(Error::format(origin, "the file holds no triangles"));
    }
    mesh.validate(&origin.display().to_string())
        .map_err(|e| Error::format(origin, e.to_string()))?;
    Ok(mesh)
}

/// Writes a mesh in the default format of the path's extension (atomically).
pub fn write_mesh(path: &Path, mesh: &TriMesh) -> Result<()> {
    write_mesh_as(path, mesh, MeshFormat::from_path(path)?)
}

/// Writes a mesh in an explicit format (atomically).
pub fn write_mesh_as(path: &Path, mesh: &TriMesh, format: MeshFormat) -> Result<()> {
    mesh.validate(&format!("mesh {}", mesh.name))?;
    crate::io::write_atomic(path, |w| {
        let r = match format {
            MeshFormat::StlBinary => stl::write_binary(w, mesh),
            MeshFormat::StlAscii => stl::write_ascii(w, mesh),
            MeshFormat::Obj => obj::write(w, mesh),
            MeshFormat::PlyAscii => ply::write(w, mesh, false),
            MeshFormat::PlyBinary => ply::write(w, mesh, true),
        };
        r.map_err(|e| Error::io(path, e))
    })
}

/// Merges vertices with bit-identical coordinates (`-0.0` equals `0.0`), remapping triangles.
pub fn weld_vertices(mesh: &mut TriMesh) {
    let key = |v: DVec3| (v + DVec3::ZERO).to_array().map(f64::to_bits);
    let mut index: HashMap<[u64; 3], u32> = HashMap::with_capacity(mesh.vertices.len());
    let mut verts = Vec::new();
    let remap: Vec<u32> = mesh
        .vertices
        .iter()
        .map(|&v| {
            *index.entry(key(v)).or_insert_with(|| {
                verts.push(v);
                verts.len() as u32 - 1
            })
        })
        .collect();
    for t in &mut mesh.triangles {
        *t = t.map(|i| remap[i as usize]);
    }
    mesh.vertices = verts;
}
