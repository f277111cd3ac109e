//! Greedy placement of text labels that do not overlap: each label in turn takes the first candidate
//! position around its anchor (eight directions at growing distances) whose box stays inside the plot,
//! touches no label placed before it and covers no obstacle (the markers). When every candidate
//! collides, the one with the least overlap wins.

/// An axis-aligned box in pixels, `x0 ≤ x1`, `y0 ≤ y1`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelBox {
    pub x0: f64,
    pub y0: f64,
    pub x1: f64,
    pub y1: f64,
}

impl PixelBox {
    /// A `w × h` box centred on `(x, y)`.
    pub fn around((x, y): (f64, f64), w: f64, h: f64) -> PixelBox {
        PixelBox {
            x0: x - w / 2.0,
            y0: y - h / 2.0,
            x1: x + w / 2.0,
            y1: y + h / 2.0,
        }
    }

    /// Area of the intersection with `o` (0 when they only touch or are apart).
    pub fn overlap(&self, o: &PixelBox) -> f64 {
        let w = self.x1.min(o.x1) - self.x0.max(o.x0);
        let h = self.y1.min(o.y1) - self.y0.max(o.y0);
        if w > 0.0 && h > 0.0 { w * h } else { 0.0 }
    }

    fn inside(&self, b: &PixelBox) -> bool {
        self.x0 >= b.x0 && self.y0 >= b.y0 && self.x1 <= b.x1 && self.y1 <= b.y1
    }
}

/// Distances (px) from the anchor at which candidates are tried, nearest first.
const RADII: [f64; 8] = [6.0, 14.0, 24.0, 38.0, 55.0, 75.0, 100.0, 130.0];

/// The candidate boxes of a `w × h` label around `anchor` at distance `r`: right, left, below, above,
/// then the four diagonals.
fn candidates((x, y): (f64, f64), (w, h): (f64, f64), r: f64) -> [PixelBox; 8] {
    let b = |x0: f64, y0: f64| PixelBox {
        x0,
        y0,
        x1: x0 + w,
        y1: y0 + h,
    };
    let d = r * std::f64::consts::FRAC_1_SQRT_2;
    [
        b(x + r, y - h / 2.0),
        b(x - r - w, y - h / 2.0),
        b(x - w / 2.0, y + r),
        b(x - w / 2.0, y - r - h),
        b(x + d, y + d),
        b(x - d - w, y + d),
        b(x + d, y - d - h),
        b(x - d - w, y - d - h),
    ]
}

/// Boxes for labels of `sizes` (w, h) at `anchors`, in order, avoiding each other, `obstacles` and
/// the outside of `bounds`.
pub fn place_labels(
    anchors: &[(f64, f64)],
    sizes: &[(f64, f64)],
    obstacles: &[PixelBox],
    bounds: PixelBox,
) -> Vec<PixelBox> {
    let mut placed: Vec<PixelBox> = Vec::new();
    for (&a, &size) in anchors.iter().zip(sizes) {
        let cost = |c: &PixelBox| -> f64 {
            let out = if c.inside(&bounds) { 0.0 } else { 1e9 };
            out + placed
                .iter()
                .chain(obstacles)
                .map(|o| c.overlap(o))
                .sum::<f64>()
        };
        let mut best: Option<(f64, PixelBox)> = None;
        'search: for r in RADII {
            for c in candidates(a, size, r) {
                let k = cost(&c);
                if k == 0.0 {
                    best = Some((0.0, c));
                    break 'search;
                }
                if best.is_none_or(|(b, _)| k < b) {
                    best = Some((k, c));
                }
            }
        }
        if let Some((_, c)) = best {
            placed.push(c);
        }
    }
    placed
}

#[cfg(test)]
mod tests {
    use super::*;

    const BOUNDS: PixelBox = PixelBox {
        x0: 0.0,
        y0: 0.0,
        x1: 800.0,
        y1: 600.0,
    };

    #[test]
    fn a_lone_label_sits_just_right_of_its_anchor() {
        let b = place_labels(&[(100.0, 100.0)], &[(50.0, 12.0)], &[], BOUNDS);
        assert_eq!(
            b,
            vec![PixelBox {
                x0: 106.0,
                y0: 94.0,
                x1: 156.0,
                y1: 106.0
            }]
        );
    }

    #[test]
    fn crowded_labels_do_not_overlap_each_other_or_the_markers() {
        // Twelve landmarks within 40 px of each other, long names, markers as obstacles: the case that
        // made today's overlays unreadable.
        let anchors: Vec<(f64, f64)> = (0..12)
            .map(|i| {
                (
                    400.0 + 10.0 * f64::from(i % 4),
                    300.0 + 12.0 * f64::from(i / 4),
                )
            })
            .collect();
        let sizes = vec![(150.0, 14.0); anchors.len()];
        let markers: Vec<PixelBox> = anchors
            .iter()
            .map(|&a| PixelBox::around(a, 8.0, 8.0))
            .collect();
        let boxes = place_labels(&anchors, &sizes, &markers, BOUNDS);
        assert_eq!(boxes.len(), anchors.len());
        for (i, a) in boxes.iter().enumerate() {
            assert!(a.inside(&BOUNDS), "{a:?}");
            assert!((a.x1 - a.x0 - 150.0).abs() < 1e-9 && (a.y1 - a.y0 - 14.0).abs() < 1e-9);
            for m in &markers {
                assert_eq!(a.overlap(m), 0.0, "label {i} covers a marker");
            }
            for b in &boxes[i + 1..] {
                assert_eq!(a.overlap(b), 0.0, "{a:?} overlaps {b:?}");
            }
        }
    }

    #[test]
    fn overlap_is_the_intersection_area() {
        let a = PixelBox::around((0.0, 0.0), 4.0, 2.0);
        let b = PixelBox::around((3.0, 0.0), 4.0, 2.0);
        assert_eq!(a.overlap(&b), 2.0);
        assert_eq!(a.overlap(&PixelBox::around((4.0, 0.0), 4.0, 2.0)), 0.0);
    }
}
