//! Silhouette overlap: Dice `2|A∩B| / (|A| + |B|)` and IoU `|A∩B| / |A∪B|`.

use crate::{Error, Result};

/// Dice and IoU of two binary masks of the same size. Two empty masks agree perfectly (1, 1).
pub fn dice_iou(a: &[bool], b: &[bool]) -> Result<(f64, f64)> {
    if a.len() != b.len() {
        return Err(Error::invalid(
            "masks",
            format!("sizes differ: {} vs {} pixels", a.len(), b.len()),
        ));
    }
    let (mut inter, mut na, mut nb) = (0usize, 0usize, 0usize);
    for (&x, &y) in a.iter().zip(b) {
        na += usize::from(x);
        nb += usize::from(y);
        inter += usize::from(x && y);
    }
    if na + nb == 0 {
        return Ok((1.0, 1.0));
    }
    let union = na + nb - inter;
    Ok((
        2.0 * inter as f64 / (na + nb) as f64,
        inter as f64 / union as f64,
    ))
}
