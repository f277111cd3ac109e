//! The OpenCV functions spinedrr uses as its independent reference — `findContours`,
//! `distanceTransform`, `projectPoints`, `solvePnP`, `calibrateCamera`, `decomposeProjectionMatrix` —
//! called through a small C++ shim (`shim/cv_shim.cpp`) against the system OpenCV.
//!
//! Why not the `opencv` crate: it generates bindings to every function of the modules it is built with
//! by parsing OpenCV's headers with libclang at build time, then compiles the generated C++ glue; for
//! these six functions that cost 50 s wall / 81 CPU-s on 2 cores (built alone, with its generator and
//! libclang crates), on a fresh build's critical path: without it the fresh build phase of `make test`
//! went from 306.8 to 263.9 s (issue #30). The shim is one translation unit (2.1 CPU-s at `-O0`); it
//! calls the same library, with the same arguments.
//!
//! Every function returns the exception OpenCV threw as `Err(message)`; none unwinds or panics.

use std::ffi::{c_char, c_int, c_void};

const ERR_LEN: usize = 1024;

unsafe extern "C" {
    fn sdcv_find_contours(
        img: *const u8,
        rows: c_int,
        cols: c_int,
        off_x: c_int,
        off_y: c_int,
        emit: extern "C" fn(*mut c_void, *const c_int, usize),
        ctx: *mut c_void,
        err: *mut c_char,
        err_len: usize,
    ) -> c_int;
    fn sdcv_distance_transform(
        img: *const u8,
        rows: c_int,
        cols: c_int,
        out: *mut f32,
        err: *mut c_char,
        err_len: usize,
    ) -> c_int;
    fn sdcv_project_points(
        obj: *const f64,
        n: usize,
        rvec: *const f64,
        tvec: *const f64,
        k: *const f64,
        out: *mut f64,
        err: *mut c_char,
        err_len: usize,
    ) -> c_int;
    fn sdcv_solve_pnp(
        obj: *const f64,
        img: *const f64,
        n: usize,
        k: *const f64,
        method: c_int,
        use_guess: c_int,
        rvec: *mut f64,
        tvec: *mut f64,
        err: *mut c_char,
        err_len: usize,
    ) -> c_int;
    fn sdcv_calibrate_camera(
        obj: *const f32,
        img: *const f32,
        counts: *const usize,
        images: usize,
        width: c_int,
        height: c_int,
        use_guess: c_int,
        max_iterations: c_int,
        eps: f64,
        k: *mut f64,
        rvecs: *mut f64,
        tvecs: *mut f64,
        rms: *mut f64,
        err: *mut c_char,
        err_len: usize,
    ) -> c_int;
    fn sdcv_decompose_projection_matrix(
        p: *const f64,
        k: *mut f64,
        r: *mut f64,
        c: *mut f64,
        err: *mut c_char,
        err_len: usize,
    ) -> c_int;
}

/// An OpenCV failure: the text of the exception it threw (or of the shim's own check).
pub type Result<T> = std::result::Result<T, String>;

/// Runs `call` with an error buffer; a negative status becomes the buffer's text.
fn checked(call: impl FnOnce(*mut c_char, usize) -> c_int) -> Result<c_int> {
    let mut err = [0 as c_char; ERR_LEN];
    let status = call(err.as_mut_ptr(), ERR_LEN);
    if status < 0 {
        let bytes: Vec<u8> = err
            .iter()
            .take_while(|&&c| c != 0)
            .map(|&c| c as u8)
            .collect();
        let text = String::from_utf8_lossy(&bytes).trim().to_string();
        return Err(if text.is_empty() {
            "OpenCV failed without a message".into()
        } else {
            text
        });
    }
    Ok(status)
}

/// Image sides as OpenCV's `int`s, refusing a buffer of another size.
fn image_sides(len: usize, rows: usize, cols: usize) -> Result<(c_int, c_int)> {
    let (Ok(r), Ok(c)) = (c_int::try_from(rows), c_int::try_from(cols)) else {
        return Err(format!("a {cols}×{rows} image is too large for OpenCV"));
    };
    if rows.checked_mul(cols) != Some(len) || rows == 0 || cols == 0 {
        return Err(format!("{len} pixels do not make a {cols}×{rows} image"));
    }
    Ok((r, c))
}

extern "C" fn push_contour(ctx: *mut c_void, xy: *const c_int, points: usize) {
    // SAFETY: `ctx` is the `Vec` that `find_contours` passed for this call, and the shim hands over
    // `points` (x, y) pairs at `xy`, valid for the duration of the call.
    let (out, xy) = unsafe {
        (
            &mut *ctx.cast::<Vec<Vec<[i32; 2]>>>(),
            std::slice::from_raw_parts(xy, 2 * points),
        )
    };
    out.push(xy.chunks_exact(2).map(|p| [p[0], p[1]]).collect());
}

/// `findContours(RETR_LIST, CHAIN_APPROX_NONE)` of the 8-bit image `img` (`rows × cols`, row-major,
/// nonzero = object), every point offset by `offset`: each boundary as its closed chain of pixels.
pub fn find_contours(
    img: &[u8],
    rows: usize,
    cols: usize,
    offset: [i32; 2],
) -> Result<Vec<Vec<[i32; 2]>>> {
    let (r, c) = image_sides(img.len(), rows, cols)?;
    let mut found: Vec<Vec<[i32; 2]>> = Vec::new();
    let ctx = (&mut found as *mut Vec<Vec<[i32; 2]>>).cast::<c_void>();
    // SAFETY: `img` holds rows·cols bytes (checked above); `ctx` outlives the call.
    checked(|err, len| unsafe {
        sdcv_find_contours(
            img.as_ptr(),
            r,
            c,
            offset[0],
            offset[1],
            push_contour,
            ctx,
            err,
            len,
        )
    })?;
    Ok(found)
}

/// `distanceTransform(DIST_L2, DIST_MASK_PRECISE)` of the 8-bit image `img` (`rows × cols`,
/// row-major): each pixel's Euclidean distance to the nearest zero pixel, as `f32`.
pub fn distance_transform(img: &[u8], rows: usize, cols: usize) -> Result<Vec<f32>> {
    let (r, c) = image_sides(img.len(), rows, cols)?;
    let mut out = vec![0f32; img.len()];
    // SAFETY: `img` and `out` hold rows·cols elements (checked above).
    checked(|err, len| unsafe {
        sdcv_distance_transform(img.as_ptr(), r, c, out.as_mut_ptr(), err, len)
    })?;
    Ok(out)
}

/// `projectPoints` of `points` through the pose `(rvec, tvec)` and the camera matrix `k` (row-major),
/// without distortion.
pub fn project_points(
    points: &[[f64; 3]],
    rvec: [f64; 3],
    tvec: [f64; 3],
    k: [[f64; 3]; 3],
) -> Result<Vec<[f64; 2]>> {
    let mut out = vec![[0.0; 2]; points.len()];
    // SAFETY: `points` and `out` hold `len` triples and pairs; the others are fixed-size arrays.
    checked(|err, len| unsafe {
        sdcv_project_points(
            points.as_ptr().cast(),
            points.len(),
            rvec.as_ptr(),
            tvec.as_ptr(),
            k.as_ptr().cast(),
            out.as_mut_ptr().cast(),
            err,
            len,
        )
    })?;
    Ok(out)
}

/// Which `solvePnP` solver to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PnpMethod {
    /// `SOLVEPNP_ITERATIVE`.
    Iterative,
    /// `SOLVEPNP_SQPNP`.
    Sqpnp,
}

/// `solvePnP` of the model points `obj` seen at `img` through `k` (no distortion). With `guess`, that
/// pose `(rvec, tvec)` starts the solver (`useExtrinsicGuess`). `Ok(None)` when OpenCV reports no
/// solution.
pub fn solve_pnp(
    obj: &[[f64; 3]],
    img: &[[f64; 2]],
    k: [[f64; 3]; 3],
    method: PnpMethod,
    guess: Option<([f64; 3], [f64; 3])>,
) -> Result<Option<([f64; 3], [f64; 3])>> {
    if obj.len() != img.len() {
        return Err(format!(
            "{} model points but {} image points",
            obj.len(),
            img.len()
        ));
    }
    let (mut rvec, mut tvec) = guess.unwrap_or(([0.0; 3], [0.0; 3]));
    let m = match method {
        PnpMethod::Iterative => 0,
        PnpMethod::Sqpnp => 1,
    };
    // SAFETY: `obj` and `img` hold `len` triples and pairs (checked above); the rest are fixed-size.
    let status = checked(|err, len| unsafe {
        sdcv_solve_pnp(
            obj.as_ptr().cast(),
            img.as_ptr().cast(),
            obj.len(),
            k.as_ptr().cast(),
            m,
            c_int::from(guess.is_some()),
            rvec.as_mut_ptr(),
            tvec.as_mut_ptr(),
            err,
            len,
        )
    })?;
    Ok((status == 0).then_some((rvec, tvec)))
}

/// The result of [`calibrate_camera`].
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    /// The camera matrix, row-major.
    pub k: [[f64; 3]; 3],
    /// Each image's pose `(rvec, tvec)`.
    pub poses: Vec<([f64; 3], [f64; 3])>,
    /// OpenCV's RMS reprojection error (px).
    pub rms: f64,
}

/// `calibrateCamera` of the images' point correspondences (`(object, image)` pairs per image) for a
/// `width × height` detector, lens distortion fixed at zero (`CALIB_FIX_K1..K6`,
/// `CALIB_ZERO_TANGENT_DIST`). With `guess` (row-major K) it starts from it
/// (`CALIB_USE_INTRINSIC_GUESS`); without, OpenCV's closed form does (planar object points). The LM stops
/// after `max_iterations` or a relative step below `eps`.
pub fn calibrate_camera(
    images: &[Vec<([f32; 3], [f32; 2])>],
    width: u32,
    height: u32,
    guess: Option<[[f64; 3]; 3]>,
    max_iterations: u32,
    eps: f64,
) -> Result<Calibration> {
    let (Ok(w), Ok(h), Ok(iters)) = (
        c_int::try_from(width),
        c_int::try_from(height),
        c_int::try_from(max_iterations),
    ) else {
        return Err(format!(
            "a {width}×{height} detector or {max_iterations} iterations are out of OpenCV's range"
        ));
    };
    let counts: Vec<usize> = images.iter().map(Vec::len).collect();
    let obj: Vec<[f32; 3]> = images.iter().flatten().map(|p| p.0).collect();
    let img: Vec<[f32; 2]> = images.iter().flatten().map(|p| p.1).collect();
    let mut k = guess.unwrap_or([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]);
    let mut rvecs = vec![[0.0f64; 3]; images.len()];
    let mut tvecs = vec![[0.0f64; 3]; images.len()];
    let mut rms = f64::NAN;
    // SAFETY: `obj` and `img` hold Σ counts points; `rvecs`, `tvecs` one triple per image; `k` 3×3.
    checked(|err, len| unsafe {
        sdcv_calibrate_camera(
            obj.as_ptr().cast(),
            img.as_ptr().cast(),
            counts.as_ptr(),
            images.len(),
            w,
            h,
            c_int::from(guess.is_some()),
            iters,
            eps,
            k.as_mut_ptr().cast(),
            rvecs.as_mut_ptr().cast(),
            tvecs.as_mut_ptr().cast(),
            &mut rms,
            err,
            len,
        )
    })?;
    Ok(Calibration {
        k,
        poses: rvecs.into_iter().zip(tvecs).collect(),
        rms,
    })
}

/// K (row-major, as OpenCV returns it: not normalised), R (row-major) and the homogeneous camera centre.
pub type Decomposition = ([[f64; 3]; 3], [[f64; 3]; 3], [f64; 4]);

/// `decomposeProjectionMatrix` of `p` (3×4, row-major).
pub fn decompose_projection_matrix(p: &[[f64; 4]; 3]) -> Result<Decomposition> {
    let (mut k, mut r, mut c) = ([[0.0; 3]; 3], [[0.0; 3]; 3], [0.0; 4]);
    // SAFETY: every buffer is a fixed-size array of the size the shim writes.
    checked(|err, len| unsafe {
        sdcv_decompose_projection_matrix(
            p.as_ptr().cast(),
            k.as_mut_ptr().cast(),
            r.as_mut_ptr().cast(),
            c.as_mut_ptr(),
            err,
            len,
        )
    })?;
    Ok((k, r, c))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn contours_and_distances_of_a_square() {
        // A 3×3 square of ones in a 7×7 image: its boundary is the eight pixels around its centre, and
        // the distance from the centre pixel to the nearest zero (the edge ring's pixels) is 1 px.
        let mut img = vec![0u8; 49];
        for v in 2..5 {
            for u in 2..5 {
                img[v * 7 + u] = 1;
            }
        }
        let found = find_contours(&img, 7, 7, [10, 20]).unwrap();
        assert_eq!(found.len(), 1);
        let mut pts = found[0].clone();
        pts.sort();
        let mut expect: Vec<[i32; 2]> = (2..5)
            .flat_map(|v| (2..5).map(move |u| [u + 10, v + 20]))
            .filter(|&p| p != [13, 23])
            .collect();
        expect.sort();
        assert_eq!(pts, expect);
        let d = distance_transform(
            &img.iter().map(|&x| 255 * (1 - x)).collect::<Vec<_>>(),
            7,
            7,
        )
        .unwrap();
        assert_eq!(d[3 * 7 + 3], 0.0);
        let zero = img.iter().map(|&x| x * 255).collect::<Vec<_>>();
        let d = distance_transform(&zero, 7, 7).unwrap();
        assert!((d[3 * 7 + 3] - 2.0).abs() < 1e-3, "{}", d[3 * 7 + 3]);
    }

    #[test]
    fn bad_sizes_and_opencv_exceptions_are_errors() {
        assert!(find_contours(&[0u8; 10], 3, 3, [0, 0]).is_err());
        assert!(distance_transform(&[], 0, 0).is_err());
        // solvePnP needs at least 3 (SQPnP) or 4 (iterative) points: OpenCV throws, we return it.
        let k = [[1000.0, 0.0, 500.0], [0.0, 1000.0, 500.0], [0.0, 0.0, 1.0]];
        let e = solve_pnp(
            &[[0.0; 3]; 2],
            &[[0.0; 2]; 2],
            k,
            PnpMethod::Iterative,
            None,
        )
        .unwrap_err();
        assert!(!e.is_empty());
        assert!(solve_pnp(&[[0.0; 3]; 2], &[[0.0; 2]; 3], k, PnpMethod::Sqpnp, None).is_err());
    }
}
