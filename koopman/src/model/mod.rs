//! Models with linear latent dynamics `z⁺ = A z + B u` and a lifting `z = Φ(x)`: the neural Koopman
//! model, EDMD with control, and the NNDM baseline; save/load.

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
    fn lift(&self, x: &[f64]) -> Vec<f64>;
}

pub mod arch;
pub mod edmd;
pub mod encoder;
pub mod init;
pub mod koopman;
pub mod scalar;
pub mod store;

use crate::{Error, Result};
use std::path::Path;

/// Loads any saved lifted model from `dir`, dispatching on `config.json`'s `"kind"`
/// (`koopman` or `edmd`).
pub fn load_lifted(dir: &Path) -> Result<Box<dyn LiftedModel>> {
    match store::read_kind(dir)?.as_str() {
        "koopman" => Ok(Box::new(koopman::KoopmanModel::load(dir)?)),
        "edmd" => Ok(Box::new(edmd::EdmdModel::load(dir)?)),
        other => Err(Error::UnknownName {
            kind: "lifted model kind",
            name: other.to_string(),
            known: "koopman, edmd".into(),
        }),
    }
}
