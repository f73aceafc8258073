//! The condensed MPC formulation: prediction matrices, the dense Hessian and the maps `M1`, `M2`
//! that make each step's linear term a single product `q = M1 z_0 + M2 r`.

use faer::{Mat, MatRef};

use crate::error::{Error, Result};

/// Every matrix of the condensed QP that depends on the model and the weights only.
///
/// Variables are the stacked inputs `U = [u_0; …; u_{H−1}]` (index `τ·nu + i`); predictions are
/// the stacked states `X = [x_1; …; x_H] = Φ z_0 + Γ U` (index `τ·nx + i`). The QP is
/// `min ½ UᵀHU + qᵀU` with `H = ΓᵀQ̄Γ + R̄ + δI` and `q = M1 z_0 + M2 r`, `M1 = ΓᵀQ̄Φ`,
/// `M2 = −ΓᵀQ̄` (half the MPC cost, without the constant term).
#[derive(Clone, Debug)]
pub struct Condensed {
    /// State dimension nx.
    pub nx: usize,
    /// Input dimension nu.
    pub nu: usize,
    /// Latent dimension N.
    pub latent: usize,
    /// Horizon H.
    pub horizon: usize,
    /// Hessian `H` (H·nu × H·nu), symmetric positive definite.
    pub hessian: Mat<f64>,
    /// `M1 = ΓᵀQ̄Φ` (H·nu × N).
    pub m1: Mat<f64>,
    /// `M2 = −ΓᵀQ̄` (H·nu × H·nx).
    pub m2: Mat<f64>,
    /// Free response `Φ` (H·nx × N): row block τ is `P A^{τ+1}`.
    pub phi: Mat<f64>,
    /// Forced response `Γ` (H·nx × H·nu): block (τ, j) is `P A^{τ−j} B` for `j ≤ τ`.
    pub gamma: Mat<f64>,
    /// The Tikhonov term δ that was added to the diagonal of `H`.
    pub tikhonov: f64,
    /// With a lifted terminal cost ([`Condensed::with_lifted_terminal`]): `Γ_zᵀ P` (H·nu × N),
    /// so that each step's linear term gains `−Γ_zᵀ P z_ref`.
    pub terminal_map: Option<Mat<f64>>,
}

/// Diagonal weights of the condensed cost.
#[derive(Clone, Debug)]
pub struct Weights<'a> {
    /// Diagonal of Q (nx).
    pub q: &'a [f64],
    /// Diagonal of the terminal weight (nx).
    pub terminal: &'a [f64],
    /// Diagonal of R (nu).
    pub r: &'a [f64],
    /// Relative Tikhonov factor (δ = factor · max_i (ΓᵀQ̄Γ + R̄)_ii).
    pub regularization: f64,
}

impl Condensed {
    /// Builds the condensed matrices for `z⁺ = A z + B u`, `x = P z = z[..nx]`.
    pub fn build(
        a: MatRef<'_, f64>,
        b: MatRef<'_, f64>,
        nx: usize,
        horizon: usize,
        w: &Weights<'_>,
    ) -> Result<Self> {
        let latent = a.nrows();
        let nu = b.ncols();
        if a.ncols() != latent {
            return Err(Error::dimension("A columns", latent, a.ncols()));
        }
        if b.nrows() != latent {
            return Err(Error::dimension("B rows", latent, b.nrows()));
        }
        if nx == 0 || nx > latent {
            return Err(Error::InvalidArgument(format!(
                "state dimension {nx} must be in 1..={latent} (the latent dimension)"
            )));
        }
        if nu == 0 {
            return Err(Error::InvalidArgument(
                "MPC needs at least one input (nu = 0)".into(),
            ));
        }
        if horizon == 0 {
            return Err(Error::InvalidArgument(
                "MPC horizon must be at least 1".into(),
            ));
        }
        check_weights("Q", w.q, nx)?;
        check_weights("terminal weight", w.terminal, nx)?;
        check_weights("R", w.r, nu)?;
        if !(w.regularization.is_finite() && w.regularization >= 0.0) {
            return Err(Error::InvalidArgument(format!(
                "regularization must be finite and ≥ 0, got {}",
                w.regularization
            )));
        }
        let all_finite = (0..latent).all(|i| {
            (0..latent).all(|j| a[(i, j)].is_finite()) && (0..nu).all(|j| b[(i, j)].is_finite())
        });
        if !all_finite {
            return Err(Error::NonFinite("model matrices A, B".into()));
        }

        // C_k = P A^k (nx × N), k = 0..=H; CB_k = C_k B (nx × nu), k = 0..H−1.
        let mut c_pows: Vec<Mat<f64>> = Vec::with_capacity(horizon + 1);
        c_pows.push(identity_rows(nx, latent));
        for k in 0..horizon {
            let next = &c_pows[k] * a;
            c_pows.push(next);
        }
        let cb: Vec<Mat<f64>> = c_pows[..horizon].iter().map(|c| c * b).collect();

        let (hx, hu) = (horizon * nx, horizon * nu);
        let phi = Mat::from_fn(hx, latent, |row, col| c_pows[row / nx + 1][(row % nx, col)]);
        let gamma = Mat::from_fn(hx, hu, |row, col| {
            let (tau, i) = (row / nx, row % nx);
            let (j, k) = (col / nu, col % nu);
            if j <= tau {
                cb[tau - j][(i, k)]
            } else {
                0.0
            }
        });
        // W = Q̄ Γ (row scaling), H = Γᵀ W + R̄, M1 = Wᵀ Φ, M2 = −Wᵀ.
        let qbar = |row: usize| {
            let (tau, i) = (row / nx, row % nx);
            if tau + 1 == horizon {
                w.terminal[i]
            } else {
                w.q[i]
            }
        };
        let wq = Mat::from_fn(hx, hu, |r, c| qbar(r) * gamma[(r, c)]);
        let mut hessian = gamma.transpose() * &wq;
        for t in 0..horizon {
            for k in 0..nu {
                hessian[(t * nu + k, t * nu + k)] += w.r[k];
            }
        }
        // Symmetrise exactly (the product is symmetric up to rounding).
        for i in 0..hu {
            for j in 0..i {
                let v = 0.5 * (hessian[(i, j)] + hessian[(j, i)]);
                hessian[(i, j)] = v;
                hessian[(j, i)] = v;
            }
        }
        let max_diag = (0..hu).map(|i| hessian[(i, i)]).fold(0.0f64, f64::max);
        let mut tikhonov = w.regularization * max_diag;
        if max_diag == 0.0 {
            // The inputs do not affect the weighted states at all: keep the problem well posed.
            tikhonov = w.regularization.max(f64::MIN_POSITIVE);
        }
        for i in 0..hu {
            hessian[(i, i)] += tikhonov;
        }
        let m1 = wq.transpose() * &phi;
        let m2 = Mat::from_fn(hu, hx, |r, c| -wq[(c, r)]);
        Ok(Condensed {
            nx,
            nu,
            latent,
            horizon,
            hessian,
            m1,
            m2,
            phi,
            gamma,
            tikhonov,
            terminal_map: None,
        })
    }

    /// Adds the lifted terminal cost `(z_H − z_ref)ᵀ P (z_H − z_ref)` (`P`: N × N, symmetric
    /// positive semidefinite) to a condensed QP built for the same `A`, `B`: with
    /// `z_H = A^H z_0 + Γ_z U`, `Γ_z = [A^{H−1}B … AB B]`, the Hessian gains `Γ_zᵀ P Γ_z`, `M1`
    /// gains `Γ_zᵀ P A^H`, and [`Condensed::terminal_map`] keeps `Γ_zᵀ P` for the `z_ref` part.
    pub fn with_lifted_terminal(
        mut self,
        a: MatRef<'_, f64>,
        b: MatRef<'_, f64>,
        p: MatRef<'_, f64>,
    ) -> Result<Self> {
        let (n, nu, h) = (self.latent, self.nu, self.horizon);
        if p.nrows() != n || p.ncols() != n {
            return Err(Error::dimension("terminal cost P (N × N)", n, p.nrows()));
        }
        // A^k B for k = 0..H−1, and A^H.
        let mut akb: Vec<Mat<f64>> = Vec::with_capacity(h);
        akb.push(b.to_owned());
        for k in 1..h {
            let next = a * &akb[k - 1];
            akb.push(next);
        }
        let mut ah = Mat::<f64>::identity(n, n);
        for _ in 0..h {
            ah = a * &ah;
        }
        let gz = Mat::from_fn(n, h * nu, |i, col| {
            let (j, k) = (col / nu, col % nu);
            akb[h - 1 - j][(i, k)]
        });
        let tm = gz.transpose() * p; // H·nu × N
        let extra = &tm * &gz;
        for i in 0..h * nu {
            for j in 0..h * nu {
                self.hessian[(i, j)] += 0.5 * (extra[(i, j)] + extra[(j, i)]);
            }
        }
        self.m1 = &self.m1 + &tm * &ah;
        self.terminal_map = Some(tm);
        Ok(self)
    }

    /// Number of QP variables H·nu.
    pub fn n_vars(&self) -> usize {
        self.horizon * self.nu
    }

    /// The step's linear term `q = M1 z_0 + M2 r` (r: stacked reference, H·nx values).
    pub fn linear_term(&self, z0: &[f64], r: &[f64], q: &mut [f64]) {
        q.fill(0.0);
        gemv_acc(self.m1.as_ref(), z0, q);
        gemv_acc(self.m2.as_ref(), r, q);
    }

    /// Predicted states `X = Φ z_0 + Γ U` (H·nx values).
    pub fn predict(&self, z0: &[f64], u: &[f64]) -> Vec<f64> {
        let mut x = vec![0.0; self.horizon * self.nx];
        gemv_acc(self.phi.as_ref(), z0, &mut x);
        gemv_acc(self.gamma.as_ref(), u, &mut x);
        x
    }

    /// The MPC cost `Σ (x_{τ+1} − r_τ)ᵀQ_τ(…) + u_τᵀRu_τ` of a plan, for tests and reports
    /// (computed from the predictions, independently of `H` and `q`).
    pub fn cost(&self, z0: &[f64], u: &[f64], r: &[f64], w: &Weights<'_>) -> f64 {
        let x = self.predict(z0, u);
        let mut c = 0.0;
        for (row, (&xi, &ri)) in x.iter().zip(r).enumerate() {
            let (tau, i) = (row / self.nx, row % self.nx);
            let qi = if tau + 1 == self.horizon {
                w.terminal[i]
            } else {
                w.q[i]
            };
            c += qi * (xi - ri) * (xi - ri);
        }
        for (k, &uk) in u.iter().enumerate() {
            c += w.r[k % self.nu] * uk * uk;
        }
        c
    }
}

/// `y += M x` for a column-major matrix, column by column (vectorises well).
pub(crate) fn gemv_acc(m: MatRef<'_, f64>, x: &[f64], y: &mut [f64]) {
    debug_assert_eq!(m.ncols(), x.len());
    debug_assert_eq!(m.nrows(), y.len());
    for (j, &xj) in x.iter().enumerate() {
        if xj == 0.0 {
            continue;
        }
        let col = m.col(j);
        match col.try_as_col_major() {
            Some(c) => {
                for (yi, &mij) in y.iter_mut().zip(c.as_slice()) {
                    *yi += mij * xj;
                }
            }
            None => {
                for (i, yi) in y.iter_mut().enumerate() {
                    *yi += col[i] * xj;
                }
            }
        }
    }
}

fn identity_rows(nx: usize, latent: usize) -> Mat<f64> {
    Mat::from_fn(nx, latent, |i, j| if i == j { 1.0 } else { 0.0 })
}

fn check_weights(what: &str, w: &[f64], n: usize) -> Result<()> {
    if w.len() != n {
        return Err(Error::dimension(what, n, w.len()));
    }
    if w.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
        return Err(Error::InvalidArgument(format!(
            "{what} must be finite and ≥ 0"
        )));
    }
    Ok(())
}
