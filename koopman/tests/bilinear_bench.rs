//! A small bench (ignored by default) of one sequential convex MPC step on the bilinear model at
//! N = 34 (the damped pendulum, n_mult 16) and N = 289 (the Franka's size, nx 17, nu 7):
//! `cargo test --release -p koopman --test bilinear_bench -- --ignored --nocapture`.

use std::time::Instant;

use koopman::model::arch::Arch;
use koopman::model::bilinear::BilinearModel;
use koopman::model::koopman::KoopmanModel;
use koopman::mpc::{BilinearMpc, MpcConfig, OneStepModel, ScpOptions};
use koopman::rng::Rng;

fn bench(nx: usize, nu: usize, horizon: usize, steps: usize) {
    let arch = Arch::new(nx, nu, &[256, 256, 256], 16).unwrap();
    let nn = arch.latent_dim();
    let lin = KoopmanModel::init(arch, 17382).unwrap();
    let mut rng = Rng::new(1);
    let scale = 0.05 / (nn as f64).sqrt();
    let n = (0..nu * nn * nn).map(|_| scale * rng.normal()).collect();
    let model = BilinearModel::from_parts(lin, n).unwrap();
    let cfg = MpcConfig {
        horizon,
        r: Some(vec![1e-3; nu]),
        ..MpcConfig::with_bounds(vec![-1.0; nu], vec![1.0; nu])
    };
    let mut mpc = BilinearMpc::new(&model, &cfg, ScpOptions::default()).unwrap();
    let mut x: Vec<f64> = (0..nx).map(|_| rng.uniform(-1.0, 1.0)).collect();
    let reference = vec![0.0; nx];
    let (mut times, mut lins, mut not_conv) = (Vec::new(), 0, 0);
    for _ in 0..steps {
        let t0 = Instant::now();
        let s = mpc.solve(&x, &reference).unwrap();
        times.push(t0.elapsed().as_secs_f64() * 1e3);
        lins += s.linearisations;
        not_conv += usize::from(s.status != koopman::mpc::ScpStatus::Converged);
        let mut next = vec![0.0; nx];
        model.predict(&x, &s.u[..nu], &mut next);
        x = next;
    }
    times.sort_by(f64::total_cmp);
    println!(
        "N = {nn}, nx = {nx}, nu = {nu}, H = {horizon}: median {:.3} ms, p90 {:.3} ms per step \
         over {steps} closed-loop steps; {:.2} linearisations per step; {not_conv} not converged",
        times[steps / 2],
        times[steps * 9 / 10],
        lins as f64 / steps as f64
    );
}

#[test]
#[ignore = "timing bench; run with --ignored --nocapture"]
fn bilinear_mpc_step_cost() {
    bench(2, 1, 15, 100);
    bench(17, 7, 15, 40);
}
