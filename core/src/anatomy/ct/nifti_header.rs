//! The NIfTI-1 framing checked before anything is allocated: `sizeof_hdr` (which also fixes the byte
//! order), the magic, `dim`, `datatype`/`bitpix` and `vox_offset`, each reported with the value the file
//! states. Offsets are those of `nifti1.h` (`sizeof_hdr` at 0, `dim` at 40, `datatype` at 70, `bitpix`
//! at 72, `vox_offset` at 108, `magic` at 344).

use nifti::NiftiType;

/// Bytes of a NIfTI-1 header.
pub const HEADER_BYTES: usize = 348;

/// Largest voxel count read (2³¹, 8 GiB as f32): a header declaring more is corrupt, not a CT.
pub const MAX_VOXELS: u64 = 1 << 31;

/// Largest `vox_offset` accepted (1 GiB of header extensions).
pub const MAX_VOX_OFFSET: u64 = 1 << 30;

/// What the framing says about the voxel data, once checked.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Framing {
    /// Byte offset of the first voxel (`vox_offset`).
    pub data_offset: u64,
    /// Bytes of voxel data the header declares (`Π dim · bitpix / 8`).
    pub data_bytes: u64,
}

/// Reads the header's raw fields in the byte order that makes `sizeof_hdr = 348`.
struct Raw<'a> {
    b: &'a [u8],
    big_endian: bool,
}

impl Raw<'_> {
    fn i16(&self, o: usize) -> i16 {
        let a = [self.b[o], self.b[o + 1]];
        if self.big_endian {
            i16::from_be_bytes(a)
        } else {
            i16::from_le_bytes(a)
        }
    }

    fn f32(&self, o: usize) -> f32 {
        let a = [self.b[o], self.b[o + 1], self.b[o + 2], self.b[o + 3]];
        if self.big_endian {
            f32::from_be_bytes(a)
        } else {
            f32::from_le_bytes(a)
        }
    }
}

/// Checks the first [`HEADER_BYTES`] of a file (`head` may be shorter when the file is) and returns where
/// the voxel data lies and how long it is. Errors are messages naming the field and its value.
pub fn check_header(head: &[u8]) -> Result<Framing, String> {
    if head.len() < 4 {
        return Err(truncated_header(head.len()));
    }
    let first = [head[0], head[1], head[2], head[3]];
    let (le, be) = (i32::from_le_bytes(first), i32::from_be_bytes(first));
    if le == 540 || be == 540 {
        return Err(
            "NIfTI-2 file: only NIfTI-1 is supported (the nifti crate reads NIfTI-1); \
                    convert with nibabel or `c3d` to NIfTI-1"
                .into(),
        );
    }
    let big_endian = match (le, be) {
        (348, _) => false,
        (_, 348) => true,
        _ if head.len() >= HEADER_BYTES && !magic_ok(head) => return Err(bad_magic()),
        _ => {
            return Err(format!(
                "sizeof_hdr = {le}: a NIfTI-1 header is 348 bytes (in either byte order)"
            ));
        }
    };
    if head.len() < HEADER_BYTES {
        return Err(truncated_header(head.len()));
    }
    if !magic_ok(head) {
        return Err(bad_magic());
    }
    if &head[344..348] == b"ni1\0" {
        return Err(
            "a header-only NIfTI-1 file (magic \"ni1\", an .hdr/.img pair): only \
                    single-file .nii or .nii.gz volumes are supported"
                .into(),
        );
    }
    let raw = Raw {
        b: head,
        big_endian,
    };
    let voxels = check_dims(&raw)?;
    let code = raw.i16(70);
    let bitpix = raw.i16(72);
    // A known but unsupported datatype (RGB, complex) is reported by the decoder, which names it.
    let size = datatype_bytes(code).ok_or_else(|| format!("unknown datatype code {code}"))?;
    if i32::from(bitpix) != 8 * size as i32 {
        return Err(format!(
            "bitpix = {bitpix} does not match datatype {code} ({} bits per voxel)",
            8 * size
        ));
    }
    let bytes_per_voxel = size as u64;
    let vox_offset = raw.f32(108);
    if !(vox_offset.is_finite() && vox_offset.fract() == 0.0 && vox_offset >= 352.0) {
        return Err(format!(
            "vox_offset = {vox_offset}: the voxel data of a .nii file starts at a whole byte \
             offset of at least 352"
        ));
    }
    if f64::from(vox_offset) > MAX_VOX_OFFSET as f64 {
        return Err(format!(
            "vox_offset = {vox_offset}: more than {MAX_VOX_OFFSET} bytes of header extensions is not \
             a NIfTI file"
        ));
    }
    Ok(Framing {
        data_offset: vox_offset as u64,
        data_bytes: voxels * bytes_per_voxel,
    })
}

/// `dim[0]` in 1..=7 and every used `dim[i] ≥ 1`; returns the voxel count, refused above [`MAX_VOXELS`].
fn check_dims(raw: &Raw) -> Result<u64, String> {
    let dim: Vec<i16> = (0..8).map(|i| raw.i16(40 + 2 * i)).collect();
    let nd = dim[0];
    if !(1..=7).contains(&nd) {
        return Err(format!(
            "invalid dim[0] = {nd}: the number of dimensions must be 1 to 7"
        ));
    }
    let used = &dim[1..=nd as usize];
    if let Some(i) = used.iter().position(|&n| n < 1) {
        return Err(format!(
            "dim[{}] = {}: every extent must be at least 1 (dim = {used:?})",
            i + 1,
            used[i]
        ));
    }
    // Seven extents of up to 32767 overflow u64: count in u128 (at most 2^105).
    let voxels: u128 = used.iter().map(|&n| n as u128).product();
    if voxels > u128::from(MAX_VOXELS) {
        return Err(format!(
            "dim = {used:?} declares {voxels} voxels, more than the {MAX_VOXELS} this reader accepts"
        ));
    }
    Ok(voxels as u64)
}

fn magic_ok(head: &[u8]) -> bool {
    matches!(&head[344..348], b"n+1\0" | b"ni1\0")
}

fn bad_magic() -> String {
    "not a NIfTI-1 file: the magic is neither \"n+1\" nor \"ni1\"".into()
}

fn truncated_header(got: usize) -> String {
    format!("truncated: the file ends after {got} bytes, before the 348-byte header is complete")
}

/// Bytes per voxel of a datatype code the `nifti` crate knows; the crate's own `data_type()` lookup
/// (on a throwaway header) is the one code table.
fn datatype_bytes(code: i16) -> Option<usize> {
    let h = nifti::NiftiHeader {
        datatype: code,
        ..nifti::NiftiHeader::default()
    };
    h.data_type().ok().map(NiftiType::size_of)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A minimal valid little-endian header: 3-D 2×3×4 int16, vox_offset 352.
    fn header() -> Vec<u8> {
        let mut h = vec![0u8; HEADER_BYTES];
        h[0..4].copy_from_slice(&348i32.to_le_bytes());
        for (i, d) in [3i16, 2, 3, 4, 1, 1, 1, 1].iter().enumerate() {
            h[40 + 2 * i..42 + 2 * i].copy_from_slice(&d.to_le_bytes());
        }
        h[70..72].copy_from_slice(&4i16.to_le_bytes());
        h[72..74].copy_from_slice(&16i16.to_le_bytes());
        h[108..112].copy_from_slice(&352f32.to_le_bytes());
        h[344..348].copy_from_slice(b"n+1\0");
        h
    }

    #[test]
    fn valid_header_frames_the_data_in_both_byte_orders() {
        let want = Framing {
            data_offset: 352,
            data_bytes: 2 * 3 * 4 * 2,
        };
        assert_eq!(check_header(&header()), Ok(want));
        let mut be = header();
        for (o, n) in [(0, 4), (70, 2), (72, 2), (108, 4)] {
            be[o..o + n].reverse();
        }
        for i in 0..8 {
            be[40 + 2 * i..42 + 2 * i].reverse();
        }
        assert_eq!(check_header(&be), Ok(want));
    }

    #[test]
    fn each_bad_field_is_named_with_its_stated_value() {
        let patch = |o: usize, b: &[u8]| {
            let mut h = header();
            h[o..o + b.len()].copy_from_slice(b);
            check_header(&h).unwrap_err()
        };
        let e = patch(40, &9i16.to_le_bytes());
        assert!(e.contains("dim[0] = 9"), "{e}");
        let e = patch(42, &(-5i16).to_le_bytes());
        assert!(e.contains("dim[1] = -5"), "{e}");
        let e = patch(0, &1000i32.to_le_bytes());
        assert!(e.contains("sizeof_hdr = 1000"), "{e}");
        for v in [1e30f32, -1.0, 100.0, f32::NAN, 352.5] {
            let e = patch(108, &v.to_le_bytes());
            assert!(e.contains(&format!("vox_offset = {v}")), "{e}");
        }
        let e = patch(72, &8i16.to_le_bytes());
        assert!(e.contains("bitpix = 8"), "{e}");
        let e = patch(70, &9999i16.to_le_bytes());
        assert!(e.contains("datatype code 9999"), "{e}");
        let mut big = header();
        for i in 1..=3 {
            big[40 + 2 * i..42 + 2 * i].copy_from_slice(&30000i16.to_le_bytes());
        }
        assert!(check_header(&big).unwrap_err().contains("voxels"));
        // Found by fuzzing: seven extents of 32767 overflowed the u64 voxel count.
        let mut seven = header();
        for i in 0..8 {
            let d = if i == 0 { 7i16 } else { i16::MAX };
            seven[40 + 2 * i..42 + 2 * i].copy_from_slice(&d.to_le_bytes());
        }
        assert!(check_header(&seven).unwrap_err().contains("voxels"));
        assert!(
            check_header(&header()[..100])
                .unwrap_err()
                .contains("truncated")
        );
    }
}
