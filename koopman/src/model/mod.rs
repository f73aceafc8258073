//! Models with linear latent dynamics `z⁺ = A z + B u` and a lifting `z = Φ(x)`: the neural Koopman
//! model, EDMD with control, and the NNDM baseline; the bilinear Koopman model
//! (`+ Σ u_i N_i z`, [`bilinear`]); the explicit-matrix stand-in model ([`matrix`]); save/load.

use faer::Mat;

/// A model whose latent dynamics are linear: what the MPC needs to know about it.
pub trait LiftedModel: Send + Sync {
    /// State dimension nx.
    fn nx(&self) -> usize;
    /// Input dimension nu.
    fn nu(&self) -> usize;
    /// Latent dimension N (the first `nx` latent coordinates are x itself: `x = P z`).
    fn latent_dim(&self) -> usize;
    /// The latent transition matrix A (N × N), in f64.
    fn a(&self) -> Mat<f64>;
    /// The latent input matrix B (N × nu), in f64.
    fn b(&self) -> Mat<f64>;
    /// Lifts a state: `z = Φ(x)`, `N` values.
    ///
    /// Precondition: `x.len() == self.nx()` (implementations panic otherwise, like slice
    /// indexing). Use [`LiftedModel::try_lift`] for states that come from outside the program.
    fn lift(&self, x: &[f64]) -> Vec<f64>;

    /// Checked [`LiftedModel::lift`]: a typed error for a state of the wrong length or with a
    /// non-finite value, instead of a panic or a NaN latent state.
    fn try_lift(&self, x: &[f64]) -> crate::Result<Vec<f64>> {
        if x.len() != self.nx() {
            return Err(crate::Error::dimension("state", self.nx(), x.len()));
        }
        crate::error::ensure_finite("state", x)?;
        Ok(self.lift(x))
    }
}

pub mod arch;
pub mod bilinear;
pub mod edmd;
pub mod encoder;
pub mod init;
pub mod koopman;
pub mod matrix;
pub mod nndm;
pub mod normalised;
pub mod scalar;
pub mod store;

use crate::{Error, Result};
use std::path::Path;

/// Loads any saved lifted model from `dir`, dispatching on `config.json`'s `"kind"`
/// (`koopman` or `edmd`). A model trained on z-scored data comes back in raw units
/// ([`normalised::RawUnits`]).
pub fn load_lifted(dir: &Path) -> Result<Box<dyn LiftedModel>> {
    match store::read_kind(dir)?.as_str() {
        "koopman" => {
            let model = koopman::KoopmanModel::load(dir)?;
            match model.normalisation().cloned() {
                Some(norm) => Ok(Box::new(normalised::RawUnits::new(Box::new(model), norm)?)),
                None => Ok(Box::new(model)),
            }
        }
        "edmd" => Ok(Box::new(edmd::EdmdModel::load(dir)?)),
        other => Err(Error::UnknownName {
            kind: "lifted model kind",
            name: other.to_string(),
            known: "koopman, edmd".into(),
        }),
    }
}

/// Loads a saved one-step model `x⁺ = f(x, u)` (for random-shooting MPC) from `dir`,
/// dispatching on `config.json`'s `"kind"` (`nndm`).
pub fn load_one_step(dir: &Path) -> Result<Box<dyn crate::mpc::OneStepModel>> {
    match store::read_kind(dir)?.as_str() {
        "nndm" => Ok(Box::new(nndm::NndmModel::load(dir)?)),
        other => Err(Error::UnknownName {
            kind: "one-step model kind",
            name: other.to_string(),
            known: "nndm".into(),
        }),
    }
}
