//! Diagnostics of lifted models: the SPEC prediction error, conditioning (κ of the latent Gram
//! matrix, κ(BᵀB)), spectra of A, control authority (the
//! model's input gains against the true system's, and the input that holds a target), and the scaling-law fit `E = A·D^(−α) + C`.

pub mod conditioning;
pub mod equilibrium;
pub mod gain;
pub mod prediction;
pub mod scaling;

pub use conditioning::{bbt_condition, eigenvalues, gram_condition, spd_condition};
pub use equilibrium::{holding_input, HoldingInput};
pub use gain::{gain_agreement, model_input_gain, system_input_gain, GainAgreement, InputGain};
pub use prediction::{prediction_error, state_rms_errors};
pub use scaling::{fit_scaling_law, ScalingFit};
