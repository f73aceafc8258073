//! Small dense linear algebra shared by training and MPC: a single-threaded Cholesky
//! factorisation with solves, inverse and one-row updates, for matrices of a few hundred rows
//! at most, where a threaded library call costs more in synchronisation than the arithmetic.

pub mod cholesky;
pub mod kernels;

pub use cholesky::{spd_inverse, SmallCholesky};
