//! `koopbridge.KoopmanModel` and `koopbridge.BilinearModel`: trained models from disk, with `predict`
//! (and `encode`) and their matrices as numpy arrays.

use std::path::PathBuf;
use std::sync::Arc;

use koopman::model::koopman::KoopmanModel as Inner;
use koopman::model::LiftedModel;
use numpy::PyArray2;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::convert::{array2, check_finite, faer_rows, mat, rows_f64, to_py_json, vec_n};
use crate::errors::koopman_err;

/// The `#[pymethods]` of a model class `$class` wrapping `Arc<$inner>`: what every model has
/// (``load``, ``save``, ``nx``, ``nu``, ``latent_dim``, ``metadata``, ``__repr__``) and the
/// class's own methods `$own`, in the one block pyo3 allows per class.
macro_rules! model_methods {
    ($class:ident, $inner:ty, { $($own:tt)* }) => {
        #[pymethods]
        impl $class {
            /// Loads the model saved in directory ``path``.
            #[staticmethod]
            fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
                let inner = py.detach(|| <$inner>::load(&path)).map_err(koopman_err)?;
                Ok($class {
                    inner: Arc::new(inner),
                })
            }

            /// Saves the model into directory ``path`` (``model.safetensors`` + ``config.json``).
            fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
                py.detach(|| self.inner.save(&path)).map_err(koopman_err)
            }

            /// State dimension nx.
            #[getter]
            fn nx(&self) -> usize {
                self.inner.nx()
            }

            /// Input dimension nu.
            #[getter]
            fn nu(&self) -> usize {
                self.inner.nu()
            }

            /// Latent dimension N = nx + n_enc.
            #[getter]
            fn latent_dim(&self) -> usize {
                self.inner.latent_dim()
            }

            /// The metadata saved with the model (training configuration, metrics, data), as a dict.
            #[getter]
            fn metadata(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
                to_py_json(py, &self.inner.metadata)
            }

            fn __repr__(&self) -> String {
                format!(
                    "{}(nx={}, nu={}, latent_dim={})",
                    stringify!($class),
                    self.inner.nx(),
                    self.inner.nu(),
                    self.inner.latent_dim()
                )
            }

            $($own)*
        }
    };
}

/// A neural Koopman model ``z = [x, ψ(x)]``, ``z⁺ = A z + B u``, ``x = P z`` (f64 weights).
///
/// Load a saved model with ``KoopmanModel.load(dir)`` (the directory holding
/// ``model.safetensors`` and ``config.json`` written by ``koopbridge train``). A model trained
/// with ``--normalise`` has a ``normalisation``: ``A``, ``B``, ``P`` and ``encode`` are then in
/// its z-scored coordinates, while ``predict`` takes and returns raw units (as the MPC does).
#[pyclass(module = "koopbridge._native", frozen)]
pub struct KoopmanModel {
    pub(crate) inner: Arc<Inner>,
}

model_methods!(KoopmanModel, Inner, {
    /// A freshly initialised (untrained) model with SPEC's initialisation, for experiments and
    /// tests: ``nx`` states, ``nu`` inputs, encoder ``hidden`` widths and ``n_mult``.
    #[staticmethod]
    #[pyo3(signature = (nx, nu, hidden=vec![256, 256, 256], n_mult=16, seed=17382))]
    fn init(nx: usize, nu: usize, hidden: Vec<usize>, n_mult: usize, seed: u64) -> PyResult<Self> {
        let arch = koopman::model::arch::Arch::new(nx, nu, &hidden, n_mult).map_err(koopman_err)?;
        let inner = Inner::init(arch, seed).map_err(koopman_err)?;
        Ok(KoopmanModel {
            inner: Arc::new(inner),
        })
    }

    /// The latent transition matrix A, shape (N, N).
    #[getter(A)]
    fn a<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        mat(py, self.inner.a_ref())
    }

    /// The latent input matrix B, shape (N, nu).
    #[getter(B)]
    fn b<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        mat(py, self.inner.b_ref())
    }

    /// The projection P = [I 0] with x = P z, shape (nx, N).
    #[getter(P)]
    fn p<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let (nx, n) = (self.inner.nx(), self.inner.latent_dim());
        let v: Vec<f64> = (0..nx * n)
            .map(|k| if k / n == k % n { 1.0 } else { 0.0 })
            .collect();
        array2(py, nx, n, &v)
    }

    /// Lifts states: ``x`` of shape (nx,) gives z of shape (N,); (n, nx) gives (n, N).
    fn encode<'py>(&self, py: Python<'py>, x: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
        let one = x
            .getattr("ndim")
            .and_then(|d| d.extract::<usize>())
            .map(|d| d == 1);
        let one =
            one.unwrap_or_else(|_| !matches!(x.get_item(0).map(|e| e.len().is_ok()), Ok(true)));
        let (rows, cols, v) = rows_f64(x, "x")?;
        check_finite(&v, "x")?;
        if cols != self.inner.nx() {
            return Err(PyValueError::new_err(format!(
                "x: states have {} values, the model has nx = {}",
                cols,
                self.inner.nx()
            )));
        }
        let inner = self.inner.clone();
        let z = py
            .detach(move || inner.lift_rows(faer_rows(rows, cols, &v).as_ref()))
            .map_err(koopman_err)?;
        let z = mat(py, z.as_ref())?;
        if one {
            Ok(z.call_method1("reshape", (-1,))?)
        } else {
            Ok(z.into_any())
        }
    }

    /// The z-scoring the model was trained with (``--normalise``), as a dict of lists
    /// ``x_mean``, ``x_std``, ``u_mean``, ``u_std``; None for a model in raw units.
    #[getter]
    fn normalisation(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        match self.inner.normalisation() {
            Some(n) => to_py_json(
                py,
                &serde_json::to_value(n).map_err(|e| PyValueError::new_err(e.to_string()))?,
            ),
            None => Ok(py.None()),
        }
    }

    /// Forecasts from ``x0`` (nx,) under the inputs ``u_seq`` (T, nu): encodes once, rolls out
    /// ``z⁺ = A z + B u`` and returns the predicted states x_1..x_T, shape (T, nx). In raw units
    /// also for a normalised model (normalised on the way in and back on the way out).
    fn predict<'py>(
        &self,
        py: Python<'py>,
        x0: &Bound<'py, PyAny>,
        u_seq: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let (nx, nu) = (self.inner.nx(), self.inner.nu());
        let (mut x0, t, mut u) = predict_inputs(x0, u_seq, nx, nu)?;
        let norm = self.inner.normalisation().cloned();
        if let Some(n) = &norm {
            n.state_in_place(&mut x0);
            if nu > 0 {
                u.chunks_exact_mut(nu).for_each(|r| n.input_in_place(r));
            }
        }
        let inner = self.inner.clone();
        let mut out = py.detach(move || {
            let (a, b) = (inner.a_ref(), inner.b_ref());
            rollout(inner.lift(&x0), t, nx, nu, &u, |z, ut, next| {
                for (i, next_i) in next.iter_mut().enumerate() {
                    let mut acc = 0.0;
                    for (j, zj) in z.iter().enumerate() {
                        acc += a[(i, j)] * zj;
                    }
                    for (j, uj) in ut.iter().enumerate() {
                        acc += b[(i, j)] * uj;
                    }
                    *next_i = acc;
                }
            })
        });
        if let Some(n) = &norm {
            out.chunks_exact_mut(nx)
                .for_each(|x| n.raw_state_in_place(x));
        }
        array2(py, t, nx, &out)
    }
});

/// The checked arguments of ``predict``: ``x0`` as `nx` finite values, ``u_seq`` as `T` rows of
/// `nu` finite inputs; returns (x0, T, row-major inputs).
fn predict_inputs(
    x0: &Bound<'_, PyAny>,
    u_seq: &Bound<'_, PyAny>,
    nx: usize,
    nu: usize,
) -> PyResult<(Vec<f64>, usize, Vec<f64>)> {
    let x0 = vec_n(x0, nx, "x0")?;
    let (t, cols, u) = rows_f64(u_seq, "u_seq")?;
    if cols != nu {
        return Err(PyValueError::new_err(format!(
            "u_seq: inputs have {cols} values, the model has nu = {nu}"
        )));
    }
    check_finite(&u, "u_seq")?;
    Ok((x0, t, u))
}

/// Rolls the latent state `z0` forward with `step(z, u_t, z⁺)` for the `t` rows of `nu` inputs
/// in the row-major `u` and returns the states x_1..x_T: the first `nx` latent coordinates after
/// each step, row-major.
fn rollout(
    z0: Vec<f64>,
    t: usize,
    nx: usize,
    nu: usize,
    u: &[f64],
    step: impl Fn(&[f64], &[f64], &mut [f64]),
) -> Vec<f64> {
    let mut z = z0;
    let mut next = vec![0.0; z.len()];
    let mut out = Vec::with_capacity(t * nx);
    for s in 0..t {
        step(&z, &u[s * nu..(s + 1) * nu], &mut next);
        std::mem::swap(&mut z, &mut next);
        out.extend_from_slice(&z[..nx]);
    }
    out
}

/// A bilinear Koopman model ``z = [x, ψ(x)]``, ``z⁺ = A z + B u + Σ_i u_i N_i z`` (f64 weights).
///
/// Load one written by ``koopbridge train --model bilinear`` with ``BilinearModel.load(dir)``
/// (``config.json`` kind ``bilinear``).
#[pyclass(module = "koopbridge._native", frozen)]
pub struct BilinearModel {
    inner: Arc<koopman::model::bilinear::BilinearModel>,
}

model_methods!(BilinearModel, koopman::model::bilinear::BilinearModel, {
    /// A freshly initialised model: SPEC's initialisation (the encoder, A and B of
    /// ``KoopmanModel.init`` with the same arguments) and every N_i = 0.
    #[staticmethod]
    #[pyo3(signature = (nx, nu, hidden=vec![256, 256, 256], n_mult=16, seed=17382))]
    fn init(nx: usize, nu: usize, hidden: Vec<usize>, n_mult: usize, seed: u64) -> PyResult<Self> {
        let arch = koopman::model::arch::Arch::new(nx, nu, &hidden, n_mult).map_err(koopman_err)?;
        let inner =
            koopman::model::bilinear::BilinearModel::init(arch, seed).map_err(koopman_err)?;
        Ok(BilinearModel {
            inner: Arc::new(inner),
        })
    }

    /// The latent transition matrix A, shape (N, N).
    #[getter(A)]
    fn a<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        mat(py, self.inner.linear().a_ref())
    }

    /// The constant part B of the input matrix, shape (N, nu).
    #[getter(B)]
    fn b<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        mat(py, self.inner.linear().b_ref())
    }

    /// The bilinear matrices [N_1, …, N_nu], each of shape (N, N).
    #[getter(N)]
    fn n<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyArray2<f64>>>> {
        (0..self.inner.nu())
            .map(|i| mat(py, self.inner.n_mat(i)))
            .collect()
    }

    /// Forecasts from ``x0`` (nx,) under ``u_seq`` (T, nu): encodes once, rolls out the bilinear
    /// latent dynamics and returns the predicted states x_1..x_T, shape (T, nx).
    fn predict<'py>(
        &self,
        py: Python<'py>,
        x0: &Bound<'py, PyAny>,
        u_seq: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let (nx, nu) = (self.inner.nx(), self.inner.nu());
        let (x0, t, u) = predict_inputs(x0, u_seq, nx, nu)?;
        let inner = self.inner.clone();
        let out = py.detach(move || {
            rollout(inner.lift(&x0), t, nx, nu, &u, |z, ut, next| {
                inner.step(z, ut, next)
            })
        });
        array2(py, t, nx, &out)
    }
});
