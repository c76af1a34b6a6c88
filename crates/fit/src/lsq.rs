//! Levenberg-Marquardt (the `levenberg-marquardt` crate) over a residual
//! function whose Jacobian is taken by finite differences: the one adapter
//! the analytic shape fits and the camera solve share. And the one
//! one-dimensional search, [`golden_section`].

use levenberg_marquardt::LeastSquaresProblem;
use nalgebra::{DMatrix, DVector, Dyn, Owned};

/// How the Jacobian's columns are differenced.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Step {
    /// `(r(u + h) - r(u)) / h`: one evaluation per parameter.
    Forward(f64),
    /// `(r(u + h) - r(u - h)) / 2h`: two, and second-order accurate.
    Central(f64),
}

/// A residual function and the point it is at.
pub struct Numeric<F: Fn(&DVector<f64>) -> DVector<f64>> {
    residuals: F,
    pub u: DVector<f64>,
    step: Step,
}

impl<F: Fn(&DVector<f64>) -> DVector<f64>> std::fmt::Debug for Numeric<F> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Numeric").field("u", &self.u).field("step", &self.step).finish_non_exhaustive()
    }
}

impl<F: Fn(&DVector<f64>) -> DVector<f64>> Numeric<F> {
    pub fn new(residuals: F, u: DVector<f64>, step: Step) -> Self {
        Self { residuals, u, step }
    }

    pub fn residuals_at(&self, u: &DVector<f64>) -> DVector<f64> {
        (self.residuals)(u)
    }
}

/// `v` with every non-finite entry replaced by `bad` (a model that cannot
/// be built at a trial point reads as a large, finite misfit, so the solver
/// steps back instead of failing).
pub fn finite_or(mut v: DVector<f64>, bad: f64) -> DVector<f64> {
    v.iter_mut().filter(|x| !x.is_finite()).for_each(|x| *x = bad);
    v
}

impl<F: Fn(&DVector<f64>) -> DVector<f64>> LeastSquaresProblem<f64, Dyn, Dyn> for Numeric<F> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, Dyn>;
    type ParameterStorage = Owned<f64, Dyn>;

    fn set_params(&mut self, u: &DVector<f64>) {
        self.u = u.clone();
    }

    fn params(&self) -> DVector<f64> {
        self.u.clone()
    }

    fn residuals(&self) -> Option<DVector<f64>> {
        Some(self.residuals_at(&self.u))
    }

    fn jacobian(&self) -> Option<DMatrix<f64>> {
        let n = self.u.len();
        let r0 = self.residuals_at(&self.u);
        let mut j = DMatrix::zeros(r0.len(), n);
        for k in 0..n {
            let mut a = self.u.clone();
            let (diff, h) = match self.step {
                Step::Forward(h) => {
                    a[k] += h;
                    (self.residuals_at(&a) - &r0, h)
                }
                Step::Central(h) => {
                    let mut b = self.u.clone();
                    a[k] += h;
                    b[k] -= h;
                    (self.residuals_at(&a) - self.residuals_at(&b), 2.0 * h)
                }
            };
            j.set_column(k, &(diff / h));
        }
        Some(j)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use levenberg_marquardt::LevenbergMarquardt;

    #[test]
    fn both_differences_solve_a_line_fit() {
        // y = 2x + 1 at five points.
        let xs = [0.0, 1.0, 2.0, 3.0, 4.0];
        for step in [Step::Forward(1e-6), Step::Central(1e-6)] {
            let f = |u: &DVector<f64>| DVector::from_iterator(5, xs.iter().map(|x| u[0] * x + u[1] - (2.0 * x + 1.0)));
            let (solved, _) = LevenbergMarquardt::new().minimize(Numeric::new(f, DVector::zeros(2), step));
            assert!((solved.u[0] - 2.0).abs() < 1e-6 && (solved.u[1] - 1.0).abs() < 1e-6, "{step:?}: {}", solved.u);
        }
        let v = finite_or(DVector::from_vec(vec![1.0, f64::NAN, f64::INFINITY]), 7.0);
        assert_eq!(v.as_slice(), &[1.0, 7.0, 7.0]);
    }
}

/// The minimum of `f` on `[lo, hi]` (`f` unimodal there) after `steps`
/// golden-section steps, each shrinking the bracket by 0.618: the middle
/// of the last bracket. In the caller's precision (`f32` or `f64`).
pub fn golden_section<T>(mut f: impl FnMut(T) -> T, lo: T, hi: T, steps: usize) -> T
where
    T: Copy
        + PartialOrd
        + From<f32>
        + std::ops::Add<Output = T>
        + std::ops::Sub<Output = T>
        + std::ops::Mul<Output = T>,
{
    let g = T::from(0.618_034);
    let (mut lo, mut hi) = (lo, hi);
    let (mut x1, mut x2) = (hi - g * (hi - lo), lo + g * (hi - lo));
    let (mut f1, mut f2) = (f(x1), f(x2));
    for _ in 0..steps {
        if f1 < f2 {
            hi = x2;
            x2 = x1;
            f2 = f1;
            x1 = hi - g * (hi - lo);
            f1 = f(x1);
        } else {
            lo = x1;
            x1 = x2;
            f1 = f2;
            x2 = lo + g * (hi - lo);
            f2 = f(x2);
        }
    }
    T::from(0.5) * (lo + hi)
}
