//! Checks the NNDM's hand-written BPTT gradient against central finite differences of an
//! independent, naive reference implementation (per-window loops, f64), for every layer's
//! weights and biases, with one and with several batch parts.

#![allow(clippy::needless_range_loop)]

use faer::Par;
use koopman::data::{Dataset, DatasetMeta, Pairing};
use koopman::model::nndm::{init_params, NndmArch};
use koopman::rng::Rng;
use koopman::train::nndm::NndmLossWs;

fn random_data(n: usize, steps: usize, nx: usize, nu: usize, rng: &mut Rng) -> Dataset {
    let x = (0..n * (steps + 1) * nx)
        .map(|_| rng.uniform(-2.0, 2.0))
        .collect();
    let u = (0..n * steps * nu)
        .map(|_| rng.uniform(-1.5, 1.5))
        .collect();
    Dataset {
        n,
        steps,
        nx,
        nu,
        x,
        u,
        meta: DatasetMeta {
            env: "random".into(),
            dt: 0.1,
            state_names: (0..nx).map(|i| format!("x{i}")).collect(),
            input_names: (0..nu).map(|i| format!("u{i}")).collect(),
            pairing: Pairing::Aligned,
            seed: 0,
            source: "test".into(),
            policy: "uniform".into(),
            region: None,
            window_flags: None,
        },
    }
}

/// Reference one step: x + MLP([x, u]) with plain loops.
fn ref_step(arch: &NndmArch, p: &[f64], x: &[f64], u: &[f64]) -> Vec<f64> {
    let lay = arch.layout();
    let mut h: Vec<f64> = x.iter().chain(u).copied().collect();
    for (l, ly) in lay.iter().enumerate() {
        let mut y = vec![0.0; ly.out];
        for r in 0..ly.out {
            let mut s = p[ly.b + r];
            for c in 0..ly.fan_in {
                s += p[ly.w + r * ly.fan_in + c] * h[c];
            }
            y[r] = if l + 1 < lay.len() { s.max(0.0) } else { s };
        }
        h = y;
    }
    x.iter().zip(&h).map(|(a, b)| a + b).collect()
}

/// Reference L_pred of SPEC.md on the NNDM rollout.
fn ref_loss(arch: &NndmArch, p: &[f64], d: &Dataset, gamma: f64) -> f64 {
    let weights: Vec<f64> = (0..d.steps).map(|k| gamma.powi(k as i32)).collect();
    let wsum: f64 = weights.iter().sum();
    let mut loss = 0.0;
    for k in 0..d.steps {
        let mut s = 0.0;
        for i in 0..d.n {
            let mut xh = d.state(i, 0).to_vec();
            for t in 0..=k {
                xh = ref_step(arch, p, &xh, d.input(i, t));
            }
            for j in 0..d.nx {
                s += (xh[j] - d.state(i, k + 1)[j]).powi(2);
            }
        }
        loss += weights[k] * s / (d.n * d.nx) as f64;
    }
    loss / wsum
}

fn check(nx: usize, nu: usize, hidden: &[usize], par: Par, seed: u64) {
    let arch = NndmArch::new(nx, nu, hidden).unwrap();
    let mut rng = Rng::new(seed);
    let mut p = init_params(&arch, &mut rng).unwrap();
    // Larger weights than the initialisation so that every layer matters in the rollout.
    for v in &mut p {
        *v *= 1.5;
    }
    let (b, steps, gamma) = (5, 4, 0.8);
    let data = random_data(b, steps, nx, nu, &mut rng);
    let mut ws = NndmLossWs::<f64>::new(&arch, b, steps, par);
    ws.fill(&data, &(0..b).collect::<Vec<_>>()).unwrap();
    let mut grad = vec![0.0; p.len()];
    let loss = ws.loss_and_grad(&p, &mut grad, gamma).unwrap();
    let want = ref_loss(&arch, &p, &data, gamma);
    assert!(
        (loss - want).abs() <= 1e-12 * want.abs().max(1.0),
        "{loss} vs {want}"
    );
    // Central differences, one parameter group (weight or bias of one layer) at a time.
    let h = 1e-6;
    for (l, ly) in arch.layout().iter().enumerate() {
        for (name, range) in [("weight", ly.w..ly.b), ("bias", ly.b..ly.b + ly.out)] {
            let mut fd = Vec::new();
            for k in range.clone() {
                let mut pp = p.clone();
                pp[k] += h;
                let up = ref_loss(&arch, &pp, &data, gamma);
                pp[k] -= 2.0 * h;
                let down = ref_loss(&arch, &pp, &data, gamma);
                fd.push((up - down) / (2.0 * h));
            }
            let g = &grad[range];
            let diff: f64 = g
                .iter()
                .zip(&fd)
                .map(|(a, b)| (a - b).powi(2))
                .sum::<f64>()
                .sqrt();
            let norm: f64 = fd.iter().map(|v| v * v).sum::<f64>().sqrt();
            assert!(
                norm > 1e-8,
                "layer {l} {name}: zero gradient, test is vacuous"
            );
            assert!(
                diff / norm <= 1e-6,
                "layer {l} {name}: relative error {:.3e} (‖fd‖ = {norm:.3e})",
                diff / norm
            );
        }
    }
}

#[test]
fn bptt_gradient_matches_finite_differences_for_every_layer() {
    check(2, 1, &[7, 6, 5], Par::Seq, 11);
}

#[test]
fn bptt_gradient_with_batch_parts_and_several_inputs() {
    check(3, 2, &[6, 4], Par::rayon(2), 12);
    check(2, 0, &[5], Par::rayon(3), 13);
}

#[test]
fn the_loss_workspace_refuses_bad_batches() {
    let arch = NndmArch::new(2, 1, &[4]).unwrap();
    let mut rng = Rng::new(1);
    let data = random_data(3, 4, 2, 1, &mut rng);
    let mut ws = NndmLossWs::<f64>::new(&arch, 3, 4, Par::Seq);
    assert!(ws.fill(&data, &[0, 1]).is_err());
    assert!(ws.fill(&data, &[0, 1, 3]).is_err());
    let other = random_data(3, 5, 2, 1, &mut rng);
    assert!(ws.fill(&other, &[0, 1, 2]).is_err());
    let mut g = vec![0.0; 3];
    assert!(ws.loss_and_grad(&[0.0; 3], &mut g, 0.8).is_err());
}
