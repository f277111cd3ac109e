//! NIfTI-1 volumes in and out (`.nii`, `.nii.gz`) through the `nifti` crate.
//!
//! World affine per the NIfTI-1 standard (`nifti1.h`, "3D IMAGE (VOLUME) ORIENTATION AND LOCATION IN
//! SPACE"): method 3 (`sform_code > 0`: `srow_x/y/z`) is preferred, else method 2 (`qform_code > 0`:
//! the quaternion `(b, c, d)` with `a = √(1 − b² − c² − d²)`, spacings `pixdim[1..3]`, `qfac = pixdim[0]`
//! and offsets `qoffset_xyz`), else method 1 (`pixdim` scaling only). Both methods 2 and 3 map into the
//! RAS+ frame. Spatial units (`xyzt_units`) are converted to millimetres. Voxel values are rescaled as
//! `value · scl_slope + scl_inter` when `scl_slope ≠ 0`. The crate reads NIfTI-1 only; a NIfTI-2 file
//! (`sizeof_hdr = 540`) is reported as such.

use std::fs::File;
use std::io::{BufReader, Cursor, Read};
use std::path::{Path, PathBuf};

use glam::{DMat3, DMat4, DQuat, DVec3, DVec4};
use nifti::{InMemNiftiVolume, NiftiError, NiftiHeader, NiftiType};

use super::nifti_header::{HEADER_BYTES, check_header};

use super::{CtVolume, LabelMap, Volume};
use crate::{Error, Result};

/// Reads a CT volume (any integer or float datatype) as Hounsfield units, `scl_slope`/`scl_inter` applied.
/// A volume holding NaN or infinite voxels is refused (with their count and the first one).
pub fn read_ct(path: &Path) -> Result<CtVolume> {
    read_ct_from(open(path)?, path)
}

/// [`read_ct`] of a file's bytes (gzip or not, detected by the magic); `origin` names it in errors.
pub fn read_ct_from(source: impl Read, origin: &Path) -> Result<CtVolume> {
    let (header, values) = read_f32(source, origin)?;
    check_finite(&header, &values, origin)?;
    check_hounsfield(&header, &values, origin)?;
    volume_from(origin, &header, values)
}

/// Largest |HU| a CT voxel may hold: far beyond the extended CT scale (≈ 30 000 HU, dense metal) and
/// any padding value (−32 768), so only a file that does not hold Hounsfield units is refused.
pub const MAX_ABS_HU: f32 = 100_000.0;

/// True when every voxel is a whole number from 0 to 255 — a label map, not a CT: a CT's air is
/// −1000 HU and its bone exceeds 255 HU.
pub fn looks_like_label_map(values: &[f32]) -> bool {
    !values.is_empty()
        && values
            .iter()
            .all(|&v| (0.0..=255.0).contains(&v) && v.fract() == 0.0)
}

/// Reads a segmentation label map. Values must be integers in `0..=65535` (any datatype).
pub fn read_labels(path: &Path) -> Result<LabelMap> {
    read_labels_from(open(path)?, path)
}

/// [`read_labels`] of a file's bytes (gzip or not); `origin` names it in errors.
pub fn read_labels_from(source: impl Read, origin: &Path) -> Result<LabelMap> {
    let (header, values) = read_f32(source, origin)?;
    let mut labels = Vec::with_capacity(values.len());
    for (n, &v) in values.iter().enumerate() {
        if !(v >= 0.0 && v <= u16::MAX as f32 && v.fract() == 0.0) {
            return Err(Error::format(
                origin,
                format!("voxel {n} has value {v}, not a label (an integer in 0..=65535)"),
            ));
        }
        labels.push(v as u16);
    }
    volume_from(origin, &header, labels)
}

fn open(path: &Path) -> Result<BufReader<File>> {
    Ok(BufReader::new(
        File::open(path).map_err(|e| Error::io(path, e))?,
    ))
}

/// Refuses non-finite voxels, naming how many and the first (linear index and `(i, j, k)`).
fn check_finite(h: &NiftiHeader, values: &[f32], origin: &Path) -> Result<()> {
    let Some(first) = values.iter().position(|v| !v.is_finite()) else {
        return Ok(());
    };
    let count = values.iter().filter(|v| !v.is_finite()).count();
    let (nx, ny) = (h.dim[1].max(1) as usize, h.dim[2].max(1) as usize);
    let (i, j, k) = (first % nx, first / nx % ny, first / (nx * ny));
    Err(Error::format(
        origin,
        format!(
            "{count} voxel(s) are not finite (NaN or infinite, after scl_slope/scl_inter); the \
             first is voxel {first} at (i, j, k) = ({i}, {j}, {k}) with value {}: replace them \
             with a Hounsfield value (e.g. -1000 for air) before rendering",
            values[first]
        ),
    ))
}

/// Refuses voxels beyond ±[`MAX_ABS_HU`], naming how many and the first: such a file is not in
/// Hounsfield units, and its μ would overflow every ray through it.
fn check_hounsfield(h: &NiftiHeader, values: &[f32], origin: &Path) -> Result<()> {
    let beyond = |v: &f32| v.abs() > MAX_ABS_HU;
    let Some(first) = values.iter().position(beyond) else {
        return Ok(());
    };
    let count = values.iter().filter(|v| beyond(v)).count();
    let (nx, ny) = (h.dim[1].max(1) as usize, h.dim[2].max(1) as usize);
    let (i, j, k) = (first % nx, first / nx % ny, first / (nx * ny));
    Err(Error::format(
        origin,
        format!(
            "{count} voxel(s) lie beyond ±{MAX_ABS_HU} HU (after scl_slope/scl_inter); the first is voxel \
             {first} at (i, j, k) = ({i}, {j}, {k}) with value {:e}: a CT holds Hounsfield units, from \
             −1000 (air) to about 30 000 (dense metal on an extended scale)",
            values[first]
        ),
    ))
}

/// Writes a CT volume as float32 NIfTI-1 (gzip-compressed when the name ends in `.gz`), atomically.
pub fn write_ct(path: &Path, vol: &CtVolume) -> Result<()> {
    write_volume(path, vol, &vol.values)
}

/// Writes a label map as uint8 NIfTI-1 when every label fits in a byte, else uint16, atomically.
pub fn write_labels(path: &Path, vol: &LabelMap) -> Result<()> {
    if vol.values.iter().all(|&v| v <= u8::MAX as u16) {
        let bytes: Vec<u8> = vol.values.iter().map(|&v| v as u8).collect();
        write_volume(path, vol, &bytes)
    } else {
        write_volume(path, vol, &vol.values)
    }
}

/// The index→world affine (mm, RAS+) of a NIfTI-1 header: sform, else qform, else pixdim (see module doc).
pub fn affine_from_header(h: &NiftiHeader) -> std::result::Result<DMat4, String> {
    let unit_mm = match h.xyzt_units & 0o7 {
        1 => 1000.0,
        3 => 1e-3,
        _ => 1.0,
    };
    let m = if h.sform_code > 0 {
        let r = |row: [f32; 4]| DVec4::from_array(row.map(f64::from));
        DMat4::from_cols(r(h.srow_x), r(h.srow_y), r(h.srow_z), DVec4::W).transpose()
    } else if h.qform_code > 0 {
        qform_affine(h)?
    } else {
        let s = DVec3::new(h.pixdim[1].into(), h.pixdim[2].into(), h.pixdim[3].into());
        DMat4::from_scale(s.abs())
    };
    Ok(DMat4::from_scale(DVec3::splat(unit_mm)) * m)
}

/// Method 2 of the standard: `[x y z]ᵀ = R · diag(dx, dy, qfac·dz) · [i j k]ᵀ + qoffset`.
fn qform_affine(h: &NiftiHeader) -> std::result::Result<DMat4, String> {
    let (b, c, d) = (
        f64::from(h.quatern_b),
        f64::from(h.quatern_c),
        f64::from(h.quatern_d),
    );
    let a2 = 1.0 - (b * b + c * c + d * d);
    // nifti1.h: when a² is slightly negative through rounding, a = 0 and (b, c, d) is renormalised.
    let q = if a2 < 0.0 {
        if a2 < -1e-6 {
            return Err(format!(
                "qform quaternion (b, c, d) = ({b}, {c}, {d}) has norm > 1"
            ));
        }
        DQuat::from_xyzw(b, c, d, 0.0).normalize()
    } else {
        DQuat::from_xyzw(b, c, d, a2.sqrt())
    };
    let qfac = if h.pixdim[0] < 0.0 { -1.0 } else { 1.0 };
    let s = DVec3::new(
        h.pixdim[1].into(),
        h.pixdim[2].into(),
        f64::from(h.pixdim[3]) * qfac,
    );
    if s.x <= 0.0 || s.y <= 0.0 || s.z == 0.0 {
        return Err(format!(
            "qform needs positive voxel spacings, pixdim[1..3] = {:?}",
            &h.pixdim[1..4]
        ));
    }
    let lin = DMat3::from_quat(q) * DMat3::from_diagonal(s);
    let t = DVec3::new(h.quatern_x.into(), h.quatern_y.into(), h.quatern_z.into());
    Ok(DMat4::from_cols(
        lin.x_axis.extend(0.0),
        lin.y_axis.extend(0.0),
        lin.z_axis.extend(0.0),
        t.extend(1.0),
    ))
}

fn volume_from<T: Copy>(path: &Path, h: &NiftiHeader, values: Vec<T>) -> Result<Volume<T>> {
    let dims = spatial_dims(path, h)?;
    let affine = affine_from_header(h).map_err(|m| Error::format(path, m))?;
    Volume::new(dims, values, affine).map_err(|e| Error::format(path, e.to_string()))
}

/// `[nx, ny, nz]`; a 2-D image, or a 4-D one with more than one frame, is rejected.
fn spatial_dims(path: &Path, h: &NiftiHeader) -> Result<[usize; 3]> {
    let nd = h.dim[0] as usize;
    if !(1..=7).contains(&nd) {
        return Err(Error::format(path, format!("invalid dim[0] = {nd}")));
    }
    if nd < 3 {
        return Err(Error::format(
            path,
            format!("{nd}-D image: a CT or label volume needs 3 dimensions"),
        ));
    }
    if let Some(extra) = h.dim[4..=nd].iter().find(|&&n| n > 1) {
        return Err(Error::format(
            path,
            format!(
                "{nd}-D image with {extra} frames (dim = {:?}): only single 3-D volumes are supported",
                &h.dim[1..=nd]
            ),
        ));
    }
    Ok([h.dim[1] as usize, h.dim[2] as usize, h.dim[3] as usize])
}

/// Reads a NIfTI stream (gzip detected by its magic bytes, not its name) and decodes the voxels to f32.
fn read_f32(source: impl Read, path: &Path) -> Result<(NiftiHeader, Vec<f32>)> {
    let (header, raw) = read_raw(source, path)?;
    spatial_dims(path, &header)?;
    let datatype = header
        .data_type()
        .map_err(|_| Error::format(path, format!("unknown datatype code {}", header.datatype)))?;
    let vol = InMemNiftiVolume::from_raw_data(&header, raw).map_err(|e| nifti_err(path, e))?;
    let bad = |e: NiftiError| Error::format(path, format!("voxel data: {e}"));
    let mut values: Vec<f32> = match datatype {
        NiftiType::Uint8 => cast(vol.into_nifti_typed_data::<u8>().map_err(bad)?),
        NiftiType::Int8 => cast(vol.into_nifti_typed_data::<i8>().map_err(bad)?),
        NiftiType::Uint16 => cast(vol.into_nifti_typed_data::<u16>().map_err(bad)?),
        NiftiType::Int16 => cast(vol.into_nifti_typed_data::<i16>().map_err(bad)?),
        NiftiType::Uint32 => cast(vol.into_nifti_typed_data::<u32>().map_err(bad)?),
        NiftiType::Int32 => cast(vol.into_nifti_typed_data::<i32>().map_err(bad)?),
        NiftiType::Float32 => vol.into_nifti_typed_data::<f32>().map_err(bad)?,
        NiftiType::Float64 => cast(vol.into_nifti_typed_data::<f64>().map_err(bad)?),
        other => {
            return Err(Error::format(
                path,
                format!(
                    "unsupported datatype {other:?} (code {}): expected an integer or real scalar type",
                    header.datatype
                ),
            ));
        }
    };
    let (slope, inter) = (f64::from(header.scl_slope), f64::from(header.scl_inter));
    if slope != 0.0 && slope.is_finite() && inter.is_finite() && (slope, inter) != (1.0, 0.0) {
        for v in &mut values {
            *v = (f64::from(*v) * slope + inter) as f32;
        }
    }
    Ok((header, values))
}

fn cast<T: Copy + num_f64::ToF64>(v: Vec<T>) -> Vec<f32> {
    v.into_iter().map(|x| x.to_f64() as f32).collect()
}

/// Lossless-enough widening of the NIfTI scalar types (f64 is exact for every type up to 32 bits).
mod num_f64 {
    pub trait ToF64 {
        fn to_f64(self) -> f64;
    }
    macro_rules! impl_to_f64 {
        ($($t:ty),*) => {$(impl ToF64 for $t { #[inline] fn to_f64(self) -> f64 { self as f64 } })*};
    }
    impl_to_f64!(u8, i8, u16, i16, u32, i32, f64);
}

/// The checked header and exactly the voxel bytes it declares. Nothing is allocated from a declared size:
/// the framing is checked first ([`check_header`]), and the data buffer grows only with bytes actually
/// read, so a header claiming gigabytes in a short file is reported as truncated.
fn read_raw(source: impl Read, path: &Path) -> Result<(NiftiHeader, Vec<u8>)> {
    let mut source = source;
    let mut magic = [0u8; 2];
    let n = read_up_to(&mut source, &mut magic).map_err(|e| Error::io(path, e))?;
    let head = Cursor::new(magic[..n].to_vec());
    let mut stream: Box<dyn Read> = if n == 2 && magic == [0x1f, 0x8b] {
        // Every gzip member, not just the first: `cat a.gz b.gz`, pigz and bgzip write several.
        Box::new(flate2::read::MultiGzDecoder::new(head.chain(source)))
    } else {
        Box::new(head.chain(source))
    };
    let mut hdr = [0u8; HEADER_BYTES];
    let got = read_up_to(&mut stream, &mut hdr).map_err(|e| nifti_err(path, e.into()))?;
    let framing = check_header(&hdr[..got]).map_err(|m| Error::format(path, m))?;
    let header = NiftiHeader::from_reader(&hdr[..]).map_err(|e| nifti_err(path, e))?;
    // Extensions (between the header and vox_offset) carry nothing spinedrr uses: skip them.
    let gap = framing.data_offset - HEADER_BYTES as u64;
    let skipped = std::io::copy(&mut (&mut stream).take(gap), &mut std::io::sink())
        .map_err(|e| nifti_err(path, e.into()))?;
    if skipped < gap {
        return Err(Error::format(
            path,
            format!(
                "vox_offset = {}: the file ends after {} bytes, before the voxel data begins",
                framing.data_offset,
                HEADER_BYTES as u64 + skipped
            ),
        ));
    }
    let mut raw = Vec::new();
    let read = (&mut stream)
        .take(framing.data_bytes)
        .read_to_end(&mut raw)
        .map_err(|e| nifti_err(path, e.into()))?;
    if (read as u64) < framing.data_bytes {
        return Err(nifti_err(
            path,
            NiftiError::IncompatibleLength(read, framing.data_bytes as usize),
        ));
    }
    Ok((header, raw))
}

fn read_up_to(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..])? {
            0 => break,
            k => n += k,
        }
    }
    Ok(n)
}

fn nifti_err(path: &Path, e: NiftiError) -> Error {
    let msg = match &e {
        NiftiError::InvalidFormat => {
            "not a NIfTI-1 file: the magic is neither \"n+1\" nor \"ni1\"".to_string()
        }
        NiftiError::Io(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            "truncated: the file ends before the header or voxel data is complete".to_string()
        }
        NiftiError::IncompatibleLength(got, want) => {
            format!("truncated: {got} bytes of voxel data where the header declares {want}")
        }
        NiftiError::Io(io) => format!("corrupt or unreadable NIfTI data: {io}"),
        other => format!("not a readable NIfTI-1 file: {other}"),
    };
    Error::format(path, msg)
}

/// Writes through the `nifti` crate to a temporary name beside `path`, then renames it over `path`.
fn write_volume<T: Copy, E>(path: &Path, vol: &Volume<T>, data: &[E]) -> Result<()>
where
    E: nifti::DataElement + bytemuck::Pod + Clone,
{
    let array = ndarray::Array::from_shape_vec(
        ndarray::ShapeBuilder::f((vol.dims[0], vol.dims[1], vol.dims[2])),
        data.to_vec(),
    )
    .map_err(|e| Error::invalid("volume", e.to_string()))?;
    let header = header_for(vol);
    let gz = path.to_string_lossy().ends_with(".gz");
    let tmp = temp_path(path, gz);
    let result = nifti::writer::WriterOptions::new(&tmp)
        .reference_header(&header)
        .compress(gz)
        .write_nifti(&array)
        .map_err(|e| Error::format(path, format!("writing NIfTI: {e}")))
        .and_then(|()| std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e)));
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// `.NAME-tmp-PID.nii[.gz]` beside `path` (the crate's writer derives its output name from the extension).
fn temp_path(path: &Path, gz: bool) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "volume".into());
    let base = name
        .strip_suffix(".gz")
        .unwrap_or(&name)
        .trim_end_matches(".nii")
        .replace('.', "_");
    let ext = if gz { "nii.gz" } else { "nii" };
    path.with_file_name(format!(".{base}-tmp-{}.{ext}", std::process::id()))
}

/// A header carrying the affine as sform (code 1, scanner anatomical), pixdim = column lengths, in mm, and
/// spinedrr's name and version in `descrip`.
fn header_for<T: Copy>(vol: &Volume<T>) -> NiftiHeader {
    let m = vol.index_to_world;
    let row = |r: usize| {
        let v = m.row(r);
        [v.x as f32, v.y as f32, v.z as f32, v.w as f32]
    };
    let s = vol.spacing_mm();
    let mut h = NiftiHeader {
        sform_code: 1,
        qform_code: 0,
        srow_x: row(0),
        srow_y: row(1),
        srow_z: row(2),
        xyzt_units: 2,
        ..NiftiHeader::default()
    };
    h.pixdim[0] = 1.0;
    h.pixdim[1] = s.x as f32;
    h.pixdim[2] = s.y as f32;
    h.pixdim[3] = s.z as f32;
    // `descrip` names the writer: how a later run tells the file for spinedrr's own (crate::io::check_ours).
    let text = format!("{} {}", crate::io::TOOL, crate::VERSION);
    let n = text.len().min(80);
    h.descrip = vec![0; 80];
    h.descrip[..n].copy_from_slice(&text.as_bytes()[..n]);
    h
}
