//! The dedicated dense solver for `min ½uᵀHu + qᵀu` s.t. `lo ≤ u ≤ hi`: a dual active-set
//! method on the explicit inverse of H, whose working-set factor grows and shrinks one bound at a
//! time, warm-started from the bounds the caller's initial point sits on or from the previous
//! solve's working set ([`WarmStart`]).

use std::time::{Duration, Instant};

use faer::{Mat, MatRef};

use super::qp::{QpOutcome, QpSolver, QpStatus};
use crate::error::{Error, Result};
use crate::linalg::kernels::gemv;
use crate::linalg::SmallCholesky;

mod iterate;
mod working_set;

/// Where a variable is held: free, or on a bound of the working set.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Side {
    Free,
    Lower,
    Upper,
    /// `lo == hi`: always in the working set, its multiplier has no sign.
    Fixed,
}

const NONE: usize = usize::MAX;

/// Where a solve takes its first working set from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum WarmStart {
    /// The bounds the caller's initial point sits on (the default).
    #[default]
    Point,
    /// The final working set of the previous solve, kept with its factor (DAQP's warm start).
    /// The caller's point is used only when there is none (first solve, after
    /// [`QpSolver::reset`] or a numerical failure).
    Previous,
    /// The previous solve's working set shifted by this many variables, as a receding horizon
    /// shifts its plan by one stage (variable `i + s` → `i`, the last `s` kept); the factor is
    /// computed afresh.
    Shifted(usize),
}

/// Dual active set (Goldfarb–Idnani; the box case of DAQP, Arnström et al. 2022) for a strictly
/// convex box-constrained QP.
///
/// With the working set W (bounds held with equality, values `b_W`), the optimum of the
/// equality-constrained problem is `u = u* − H⁻¹[:, W] μ`, `u* = −H⁻¹q`, where `μ` solves
/// `K μ = u*_W − b_W` with `K = (H⁻¹)_WW`: only the Cholesky factor of K (|W| rows) is kept, and
/// adding or dropping one bound appends or deletes one of its rows in O(|W|²). The iteration keeps
/// the multipliers dual feasible (μ ≥ 0 at upper bounds, ≤ 0 at lower ones): if the new μ is not,
/// it steps towards it until a multiplier reaches zero and drops that bound; otherwise it adds the
/// most violated bound of the primal point, and stops when there is none. Once the right working
/// set is found the answer is exact to rounding. A warm start names the working set: the bounds
/// the initial point sits on ([`WarmStart::Point`], the default), or the working set the previous
/// solve ended with, as is or shifted ([`WarmStart::Previous`], [`WarmStart::Shifted`]); the
/// factor of the previous solve is reused and edited when the two sets differ in few bounds.
/// Within a solve `y = L⁻¹(u*_W − b_W)` is kept current (one dot product per added bound, the
/// factor's own rotations per dropped one), so each step costs one backward solve, one product
/// `H⁻¹[:, W] μ` and the edit. The solve is compiled for the vector extension found at run time
/// (`pulp`, AVX2 on x86-64). Nothing is allocated on the hot path once the solver is built.
pub struct BoxQp {
    n: usize,
    h: Mat<f64>,
    /// H⁻¹ (n × n, column-major, exactly symmetric).
    hinv: Vec<f64>,
    /// False after a Hessian that is not positive definite: every solve is `Numerical`.
    valid: bool,
    lo: Vec<f64>,
    hi: Vec<f64>,
    max_iterations: usize,
    time_limit: Option<Duration>,
    warm_start: WarmStart,
    /// True when `side` holds the working set a previous solve ended with.
    has_previous: bool,
    /// 1 + the largest finite bound: the scale of the primal tolerance.
    bscale: f64,
    /// Edits of the factor since it was last computed afresh (bounds rounding drift).
    edits: usize,
    /// Working set in factor order, each variable's position in it (or NONE) and its side.
    ws: Vec<usize>,
    pos: Vec<usize>,
    side: Vec<Side>,
    /// Cholesky factor of `(H⁻¹)_WW` in the order of `ws`, valid for the current H.
    chol: SmallCholesky,
    chol_valid: bool,
    // Workspace.
    want: Vec<Side>,
    ustar: Vec<f64>,
    /// `L⁻¹(u*_W − b_W)`, kept current through the edits of one solve.
    y: Vec<f64>,
    mu: Vec<f64>,
    mustar: Vec<f64>,
    row: Vec<f64>,
    u0: Vec<f64>,
    g: Vec<f64>,
    hd: Vec<f64>,
}

impl BoxQp {
    /// A solver for the Hessian `h` (symmetric positive definite) and the box `[lo, hi]`, with at
    /// most `max_iterations` working-set changes per solve and an optional time limit (s).
    pub fn new(
        h: MatRef<'_, f64>,
        lo: &[f64],
        hi: &[f64],
        max_iterations: usize,
        time_limit: Option<f64>,
    ) -> Result<Self> {
        let n = h.nrows();
        if h.ncols() != n {
            return Err(Error::dimension("Hessian columns", n, h.ncols()));
        }
        if lo.len() != n || hi.len() != n {
            return Err(Error::dimension("box bounds", n, lo.len().min(hi.len())));
        }
        if let Some(i) = (0..n).find(|&i| lo[i].is_nan() || hi[i].is_nan() || lo[i] > hi[i]) {
            return Err(Error::InvalidArgument(format!(
                "box bound {i} is empty or NaN: [{}, {}]",
                lo[i], hi[i]
            )));
        }
        if max_iterations == 0 {
            return Err(Error::InvalidArgument("max_iterations must be ≥ 1".into()));
        }
        let mut chol = SmallCholesky::default();
        chol.reserve(n);
        let mut s = BoxQp {
            n,
            h: h.to_owned(),
            hinv: vec![0.0; n * n],
            valid: false,
            lo: lo.to_vec(),
            hi: hi.to_vec(),
            max_iterations,
            time_limit: time_limit.map(Duration::from_secs_f64),
            warm_start: WarmStart::Point,
            has_previous: false,
            bscale: 1.0
                + lo.iter()
                    .chain(hi)
                    .filter(|v| v.is_finite())
                    .fold(0.0f64, |m, v| m.max(v.abs())),
            edits: 0,
            ws: Vec::with_capacity(n),
            pos: vec![NONE; n],
            side: vec![Side::Free; n],
            chol,
            chol_valid: false,
            want: vec![Side::Free; n],
            ustar: vec![0.0; n],
            y: Vec::with_capacity(n),
            mu: Vec::with_capacity(n),
            mustar: vec![0.0; n],
            row: vec![0.0; n],
            u0: vec![0.0; n],
            g: vec![0.0; n],
            hd: vec![0.0; n],
        };
        if !s.invert_hessian() {
            return Err(Error::Numerical(
                "the MPC Hessian is not positive definite; increase R or the regularization".into(),
            ));
        }
        Ok(s)
    }

    /// Number of variables.
    pub fn n(&self) -> usize {
        self.n
    }

    /// Chooses where the next solves take their first working set from.
    pub fn set_warm_start(&mut self, warm_start: WarmStart) {
        self.warm_start = warm_start;
    }

    /// The working set of the last solve as `(variable, at upper bound)` pairs in factor order
    /// (fixed variables, `lo == hi`, report `false`).
    pub fn working_set(&self) -> impl Iterator<Item = (usize, bool)> + '_ {
        self.ws.iter().map(|&i| (i, self.side[i] == Side::Upper))
    }

    /// Replaces the Hessian (same size) for the next solves, as a time-varying QP needs; if it is
    /// not positive definite the next solves end `Numerical`.
    pub fn set_hessian(&mut self, h: MatRef<'_, f64>) -> Result<()> {
        if h.nrows() != self.n || h.ncols() != self.n {
            return Err(Error::dimension("Hessian rows", self.n, h.nrows()));
        }
        self.h.copy_from(h);
        self.invert_hessian();
        Ok(())
    }

    /// Computes H⁻¹ (symmetrised) and drops the working-set factor; false if H is not
    /// numerically positive definite.
    fn invert_hessian(&mut self) -> bool {
        let n = self.n;
        self.chol_valid = false;
        let mut c = SmallCholesky::default();
        let h = &self.h;
        let finite = (0..n).all(|j| (0..n).all(|i| h[(i, j)].is_finite()));
        self.valid = finite && c.factor(n, |i, j| h[(i, j)]);
        if self.valid {
            c.inverse_into(&mut self.hinv);
            for i in 0..n {
                for j in 0..i {
                    let v = 0.5 * (self.hinv[i * n + j] + self.hinv[j * n + i]);
                    self.hinv[i * n + j] = v;
                    self.hinv[j * n + i] = v;
                }
            }
        }
        self.valid
    }

    /// H⁻¹ (n × n, column-major and exactly symmetric) of the current Hessian; meaningless
    /// after a Hessian that is not positive definite.
    pub fn hessian_inverse(&self) -> &[f64] {
        &self.hinv
    }

    #[inline(always)]
    fn bound(&self, i: usize) -> f64 {
        match self.side[i] {
            Side::Upper => self.hi[i],
            _ => self.lo[i],
        }
    }
}

/// One solve as a [`pulp::WithSimd`] operation: everything it calls is inlined into code
/// compiled for the vector extension [`pulp::Arch`] finds at run time.
struct Run<'a> {
    qp: &'a mut BoxQp,
    /// The linear term, when `u*` is still to be formed from it.
    q: Option<&'a [f64]>,
    u: &'a mut [f64],
    start: Option<Instant>,
}

impl pulp::WithSimd for Run<'_> {
    type Output = QpOutcome;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> QpOutcome {
        let qp = self.qp;
        if let Some(q) = self.q {
            // u* = −H⁻¹ q (H⁻¹ is symmetric: its columns are its rows).
            qp.ustar.fill(0.0);
            gemv(&qp.hinv, q, &mut qp.ustar);
            for v in &mut qp.ustar {
                *v = -*v;
            }
        }
        qp.run(self.u, self.start)
    }
}

impl QpSolver for BoxQp {
    fn name(&self) -> &'static str {
        "dedicated"
    }

    fn reset(&mut self) {
        self.has_previous = false;
    }

    fn solve(&mut self, q: &[f64], _h: &[f64], u: &mut [f64]) -> QpOutcome {
        let start = self.time_limit.map(|_| Instant::now());
        let n = self.n;
        let outcome = |status, iterations, feasible_iterate| QpOutcome {
            status,
            iterations,
            feasible_iterate,
        };
        if q.len() != n || u.len() != n || !self.valid || q.iter().any(|v| !v.is_finite()) {
            return outcome(QpStatus::Numerical, 0, false);
        }
        // The whole solve is compiled for the CPU's vector extension (AVX2 where there is
        // one): wider vectors, and VEX-encoded instructions, which do not stall when other code
        // has left the upper halves of the vector registers dirty (legacy SSE code ran the
        // same solve 2.4× slower inside the bench binary, docs/decisions/0001-box-qp-solver.md).
        pulp::Arch::new().dispatch(Run {
            qp: self,
            q: Some(q),
            u,
            start,
        })
    }
}

impl BoxQp {
    /// Solves the QP whose unconstrained optimum `u* = −H⁻¹q` the caller has formed (e.g. with
    /// the linear term, in one product from the MPC's state and reference): the same answer
    /// as [`QpSolver::solve`] with that `q`, without its O(n²) product. On entry `u` holds the
    /// warm start; on exit, the solution.
    pub fn solve_unconstrained(&mut self, ustar: &[f64], u: &mut [f64]) -> QpOutcome {
        let start = self.time_limit.map(|_| Instant::now());
        let n = self.n;
        if ustar.len() != n || u.len() != n || !self.valid || ustar.iter().any(|v| !v.is_finite()) {
            return QpOutcome {
                status: QpStatus::Numerical,
                iterations: 0,
                feasible_iterate: false,
            };
        }
        self.ustar.copy_from_slice(ustar);
        // Compiled for the CPU's vector extension, as in `solve`.
        pulp::Arch::new().dispatch(Run {
            qp: self,
            q: None,
            u,
            start,
        })
    }
}
