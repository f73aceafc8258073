//! Helpers shared by the koopman integration tests: small damped-pendulum datasets and a small
//! training configuration.
#![allow(dead_code)] // each test binary uses a subset

pub mod grad;

use koopman::data::{generate, Dataset, Pairing};
use koopman::train::TrainConfig;

/// `windows` aligned damped-pendulum windows of 15 steps, generated with `seed`.
pub fn data(windows: usize, seed: u64) -> Dataset {
    let sys = koopman::systems::by_name("damped-pendulum").unwrap();
    generate(sys.as_ref(), windows, 15, seed, Pairing::Aligned).unwrap()
}

/// A small, fast configuration (n_mult 4, hidden 32×2, batch 16, validation every 50).
pub fn small_cfg(iterations: usize) -> TrainConfig {
    TrainConfig {
        n_mult: 4,
        hidden: vec![32, 32],
        iterations,
        batch: 16,
        validate_every: 50,
        lr: 3e-3,
        ..TrainConfig::default()
    }
}
