//! Natural cubic splines through tabulated points, the interpolation the attenuation tables are read with
//! (in log μ/ρ against log E, one spline per edge-free segment).

/// A natural cubic spline (zero second derivative at both ends) through `(x, y)` with increasing `x`;
/// two points give the straight line through them.
#[derive(Debug, Clone)]
pub(crate) struct NaturalSpline {
    x: Vec<f64>,
    y: Vec<f64>,
    /// Second derivative at each knot.
    m: Vec<f64>,
}

impl NaturalSpline {
    /// The spline through the knots; `x` strictly increasing, at least two knots (checked by the caller's
    /// table parser, asserted here).
    pub(crate) fn new(x: Vec<f64>, y: Vec<f64>) -> Self {
        let n = x.len();
        assert!(n >= 2 && y.len() == n, "a spline needs two or more knots");
        assert!(
            x.windows(2).all(|w| w[1] > w[0]),
            "spline knots must increase"
        );
        let mut m = vec![0.0; n];
        if n > 2 {
            // Tridiagonal system for the interior second derivatives (Thomas algorithm).
            let mut c = vec![0.0; n];
            let mut d = vec![0.0; n];
            for i in 1..n - 1 {
                let h0 = x[i] - x[i - 1];
                let h1 = x[i + 1] - x[i];
                let rhs = 6.0 * ((y[i + 1] - y[i]) / h1 - (y[i] - y[i - 1]) / h0);
                let diag = 2.0 * (h0 + h1) - h0 * c[i - 1];
                c[i] = h1 / diag;
                d[i] = (rhs - h0 * d[i - 1]) / diag;
            }
            for i in (1..n - 1).rev() {
                m[i] = d[i] - c[i] * m[i + 1];
            }
        }
        NaturalSpline { x, y, m }
    }

    /// The spline at `t`; outside the knots, the end intervals' cubics continued.
    pub(crate) fn eval(&self, t: f64) -> f64 {
        let n = self.x.len();
        let i = match self.x.partition_point(|&xi| xi <= t) {
            0 => 0,
            k if k >= n => n - 2,
            k => k - 1,
        };
        let (x0, x1) = (self.x[i], self.x[i + 1]);
        let h = x1 - x0;
        let a = (x1 - t) / h;
        let b = (t - x0) / h;
        a * self.y[i]
            + b * self.y[i + 1]
            + ((a * a * a - a) * self.m[i] + (b * b * b - b) * self.m[i + 1]) * h * h / 6.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reproduces_a_cubic_with_matching_end_curvature_and_passes_through_its_knots() {
        // A natural spline reproduces any straight line exactly, and interpolates its knots.
        let x: Vec<f64> = vec![0.0, 0.7, 1.5, 3.0, 4.2];
        let s = NaturalSpline::new(x.clone(), x.iter().map(|t| 2.0 - 0.5 * t).collect());
        for t in [-0.5, 0.3, 1.1, 2.2, 4.0, 5.0] {
            assert!((s.eval(t) - (2.0 - 0.5 * t)).abs() < 1e-12);
        }
        let y: Vec<f64> = x.iter().map(|t: &f64| t.sin()).collect();
        let s = NaturalSpline::new(x.clone(), y.clone());
        for (xi, yi) in x.iter().zip(&y) {
            assert!((s.eval(*xi) - yi).abs() < 1e-12);
        }
        // Between knots of a fine grid it follows a smooth function closely: sin on a 0.25 grid over
        // [0, 3], within 1e-3 away from the ends (where the natural end condition bends it).
        let x: Vec<f64> = (0..=12).map(|i| f64::from(i) * 0.25).collect();
        let s = NaturalSpline::new(x.clone(), x.iter().map(|t| t.sin()).collect());
        for t in [0.8, 1.3, 1.9, 2.2] {
            assert!((s.eval(t) - t.sin()).abs() < 1e-3, "{t}");
        }
    }
}
