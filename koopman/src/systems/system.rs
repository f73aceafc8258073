//! The `System` trait: a discrete-time controlled system with its sampling distributions.

/// A discrete-time controlled system `x_{k+1} = f(x_k, u_k)` with its sampling distributions.
///
/// Implementations are cheap to clone and thread-safe so that data generation can use every core.
pub trait System: Send + Sync {
    /// The canonical environment name (e.g. `damped-pendulum`).
    fn name(&self) -> &str;
    /// State dimension nx.
    fn nx(&self) -> usize;
    /// Input dimension nu (0 for autonomous systems).
    fn nu(&self) -> usize;
    /// Sampling period in seconds (the step of one transition).
    fn dt(&self) -> f64;
    /// Human-readable names of the state components, `nx` of them.
    fn state_names(&self) -> Vec<String>;
    /// Human-readable names of the input components, `nu` of them.
    fn input_names(&self) -> Vec<String>;
    /// Lower and upper input bounds (the data-collection range of SPEC.md), `nu` each.
    fn input_bounds(&self) -> (Vec<f64>, Vec<f64>);
    /// Indices of state components that are angles (wrapped to (−π, π] when measuring errors).
    fn angle_indices(&self) -> Vec<usize>;
    /// Number of transitions T in one training window (15, or 1 for the polynomial system).
    fn window_steps(&self) -> usize;
    /// Draws an initial state from the distribution of SPEC.md.
    fn sample_initial_state(&self, rng: &mut crate::rng::Rng) -> Vec<f64>;
    /// Draws one input from the data-collection distribution (uniform within the bounds).
    fn sample_input(&self, rng: &mut crate::rng::Rng) -> Vec<f64> {
        let (lo, hi) = self.input_bounds();
        lo.iter()
            .zip(&hi)
            .map(|(&l, &h)| rng.uniform(l, h))
            .collect()
    }
    /// Parameters that distinguish this instance from the default one (e.g. `n_poly=10`), or an
    /// empty string; recorded in dataset metadata.
    fn parameters(&self) -> String {
        String::new()
    }
    /// Advances the state by one step `dt` with `u` held constant; writes `x_next`.
    fn step(&self, x: &[f64], u: &[f64], x_next: &mut [f64]);
}
