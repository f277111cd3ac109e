//! The geometry of a landmark overlay: the landmarks' positions, the arrow magnification, and the
//! detector window a view shows (every arrow inside, at the plot's aspect; resized so that views of one
//! figure share one scale).

/// Candidate magnifications of the displacement arrows, largest first.
const GAINS: [f64; 6] = [50.0, 20.0, 10.0, 5.0, 2.0, 1.0];

/// One landmark in an overlay: its key number, level (a segment's `L3/center` → `L3`), reference,
/// measured and predicted positions (px).
pub(super) struct Point {
    pub key: usize,
    pub level: Option<String>,
    pub reference: (f64, f64),
    pub measured: (f64, f64),
    pub predicted: (f64, f64),
}

/// A detector window: (u0, u1), (v0, v1) in px.
pub(super) type Window = ((f64, f64), (f64, f64));

/// The arrow magnification: the largest of [`GAINS`] that keeps the longest arrow within a fifth of
/// the landmarks' spread (1 when the shifts are already that large).
pub(super) fn gain(pts: &[Point]) -> f64 {
    let (mut spread, mut longest) = (0.0f64, 0.0f64);
    for p in pts {
        for q in pts {
            spread =
                spread.max((p.reference.0 - q.reference.0).hypot(p.reference.1 - q.reference.1));
        }
        for y in [p.measured, p.predicted] {
            longest = longest.max((y.0 - p.reference.0).hypot(y.1 - p.reference.1));
        }
    }
    let limit = 0.2 * spread.max(50.0);
    GAINS
        .into_iter()
        .find(|g| g * longest <= limit)
        .unwrap_or(1.0)
}

/// `x + g · (y − x)`.
pub(super) fn tip(x: (f64, f64), y: (f64, f64), g: f64) -> (f64, f64) {
    (x.0 + g * (y.0 - x.0), x.1 + g * (y.1 - x.1))
}

/// The detector window shown: every point and arrow tip with a margin, widened to the plot's aspect
/// ratio `aspect` (width / height) so DRR pixels stay square.
pub(super) fn window(pts: &[Point], g: f64, aspect: f64) -> Window {
    let (mut u0, mut u1, mut v0, mut v1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in pts {
        let tips = [
            tip(p.reference, p.measured, g),
            tip(p.reference, p.predicted, g),
        ];
        for (u, v) in [p.reference, p.measured, tips[0], tips[1]] {
            (u0, u1, v0, v1) = (u0.min(u), u1.max(u), v0.min(v), v1.max(v));
        }
    }
    if u0 > u1 {
        (u0, u1, v0, v1) = (0.0, 1.0, 0.0, 1.0);
    }
    let m = 0.25 * (u1 - u0).max(v1 - v0).max(40.0);
    let (mut w, mut h) = (u1 - u0 + 2.0 * m, v1 - v0 + 2.0 * m);
    if w / h < aspect {
        w = h * aspect;
    } else {
        h = w / aspect;
    }
    let (cu, cv) = ((u0 + u1) / 2.0, (v0 + v1) / 2.0);
    ((cu - w / 2.0, cu + w / 2.0), (cv - h / 2.0, cv + h / 2.0))
}

/// `window` re-centred at its own centre with size `w × h` (detector px): the views of one figure
/// share the largest window's size, so they are drawn at one scale.
pub(super) fn resized(window: Window, w: f64, h: f64) -> Window {
    let ((u0, u1), (v0, v1)) = window;
    let (cu, cv) = ((u0 + u1) / 2.0, (v0 + v1) / 2.0);
    ((cu - w / 2.0, cu + w / 2.0), (cv - h / 2.0, cv + h / 2.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(u: f64, shift: f64) -> Point {
        Point {
            key: 1,
            level: None,
            reference: (u, 100.0),
            measured: (u + shift, 100.0),
            predicted: (u + shift, 100.0),
        }
    }

    #[test]
    fn arrows_are_magnified_to_a_fifth_of_the_spread_at_most() {
        // Spread 400 px → arrows up to 80 px: a 3-px shift gets ×20 (60 px), a 30-px shift ×2 (60 px),
        // a 100-px shift is drawn at its size.
        for (shift, g) in [(3.0, 20.0), (30.0, 2.0), (100.0, 1.0)] {
            assert_eq!(
                gain(&[point(0.0, shift), point(400.0, 0.0)]),
                g,
                "shift {shift}"
            );
        }
    }

    #[test]
    fn the_window_holds_every_arrow_at_the_plot_aspect() {
        let pts = [point(100.0, 10.0), point(300.0, -5.0)];
        let ((u0, u1), (v0, v1)) = window(&pts, 5.0, 1.5);
        assert!(((u1 - u0) / (v1 - v0) - 1.5).abs() < 1e-12);
        for p in &pts {
            let t = tip(p.reference, p.measured, 5.0);
            assert!(u0 < t.0 && t.0 < u1 && u0 < p.reference.0 && v0 < 100.0 && 100.0 < v1);
        }
    }
}
