//! Checks the hand-written gradients of the three training losses against central finite
//! differences of an independent, naive reference implementation (per-sample loops, pinv by SVD).

// The reference implementation indexes like the formulas on purpose.
#![allow(clippy::needless_range_loop, clippy::redundant_closure)]

mod common;

use common::grad::{assert_groups_match_fd, fill, random_windows, ref_cov, rel_diff, Windows};
use faer::{Mat, Par};
use koopman::model::arch::Arch;
use koopman::model::init::init_params;
use koopman::rng::Rng;
use koopman::train::loss::{LossOptions, LossWs};

/// Reference encoder: z = [x, ψ(x)] with plain loops.
fn ref_lift(arch: &Arch, p: &[f64], x: &[f64]) -> Vec<f64> {
    let lay = arch.layout();
    let mut h = x.to_vec();
    for blk in &lay.blocks {
        let (i_w, o) = (blk.fan_in, blk.out);
        let mut y = vec![0.0; o];
        for r in 0..o {
            let mut s = p[blk.b + r];
            for c in 0..i_w {
                s += p[blk.w + r * i_w + c] * h[c];
            }
            let res = if blk.linear_residual {
                let mut q = p[blk.b + o + r];
                for c in 0..i_w {
                    q += p[blk.w + o * i_w + r * i_w + c] * h[c];
                }
                q
            } else {
                h[r]
            };
            y[r] = s.max(0.0) + res;
        }
        h = y;
    }
    let mut z = x.to_vec();
    z.extend(h);
    z
}

/// Reference total loss (SPEC formulas, as the PyTorch anchor computes them).
fn ref_loss(arch: &Arch, p: &[f64], w: &Windows, opts: &LossOptions) -> f64 {
    let lay = arch.layout();
    let (nx, nu, nn) = (arch.nx, arch.nu, arch.latent_dim());
    let b = w.x.len();
    let steps = w.u[0].len();
    let a = |i: usize, j: usize| p[lay.a + i * nn + j];
    let bmat = |i: usize, j: usize| p[lay.b + i * nu + j];
    let weights: Vec<f64> = (0..steps).map(|k| opts.gamma.powi(k as i32)).collect();
    let wsum: f64 = weights.iter().sum();
    let z: Vec<Vec<Vec<f64>>> =
        w.x.iter()
            .map(|win| win.iter().map(|s| ref_lift(arch, p, s)).collect())
            .collect();
    // Prediction.
    let mut pred = 0.0;
    for i in 0..b {
        let mut zh = z[i][0].clone();
        for k in 0..steps {
            let mut next = vec![0.0; nn];
            for r in 0..nn {
                let mut s = 0.0;
                for c in 0..nn {
                    s += a(r, c) * zh[c];
                }
                for c in 0..nu {
                    s += bmat(r, c) * w.u[i][k][c];
                }
                next[r] = s;
            }
            zh = next;
            for j in 0..nx {
                let d = zh[j] - w.x[i][k + 1][j];
                pred += weights[k] * d * d / (b * nx) as f64;
            }
        }
    }
    let mut total = pred / wsum;
    if opts.ctrl && nu > 0 {
        let bm = Mat::from_fn(nn, nu, |i, j| bmat(i, j));
        let svd = bm.thin_svd().unwrap();
        let (u_, s_, v_) = (svd.U(), svd.S(), svd.V());
        // pinv = V S⁻¹ Uᵀ (nu × N)
        let pinv = Mat::from_fn(nu, nn, |r, c| {
            (0..nu)
                .map(|k| v_[(r, k)] * u_[(c, k)] / s_[k])
                .sum::<f64>()
        });
        let mut ctrl = 0.0;
        for i in 0..b {
            for k in 0..steps {
                let mut res = vec![0.0; nn];
                for r in 0..nn {
                    let mut s = z[i][k + 1][r];
                    for c in 0..nn {
                        s -= a(r, c) * z[i][k][c];
                    }
                    res[r] = s;
                }
                for j in 0..nu {
                    let uh: f64 = (0..nn).map(|c| pinv[(j, c)] * res[c]).sum();
                    let d = uh - w.u[i][k][j];
                    ctrl += weights[k] * d * d / (b * nu) as f64;
                }
            }
        }
        total += ctrl / wsum;
    }
    if opts.cov {
        total += ref_cov(&z, nx, arch.n_enc());
    }
    total
}

/// Named parameter groups: (name, start, end).
fn groups(arch: &Arch) -> Vec<(String, usize, usize)> {
    let lay = arch.layout();
    let mut g = Vec::new();
    for (l, blk) in lay.blocks.iter().enumerate() {
        let (o, i) = (blk.out, blk.fan_in);
        g.push((format!("block{l}.W"), blk.w, blk.w + o * i));
        g.push((format!("block{l}.b"), blk.b, blk.b + o));
        if blk.linear_residual {
            g.push((format!("block{l}.R"), blk.w + o * i, blk.w + 2 * o * i));
            g.push((format!("block{l}.r"), blk.b + o, blk.b + 2 * o));
        }
    }
    g.push(("A".into(), lay.a, lay.b));
    if arch.nu > 0 {
        g.push(("B".into(), lay.b, lay.len));
    }
    g
}

fn check_case(nu: usize, ctrl: bool, cov: bool, seed: u64) {
    let arch = Arch {
        nx: 2,
        nu,
        widths: vec![2, 6, 6, 5],
    };
    let mut rng = Rng::new(seed);
    let mut p = init_params(&arch, &mut rng).unwrap();
    // Move away from the initialisation's structure so every term is generic.
    for v in p.iter_mut() {
        *v += 0.05 * rng.normal();
    }
    let (b, steps) = (5, 3);
    let w = random_windows(b, steps, arch.nx, nu, &mut rng);
    let opts = LossOptions {
        gamma: 0.8,
        ctrl,
        cov,
    };
    let mut ws = LossWs::<f64>::new(&arch, b, steps, Par::Seq);
    fill(&mut ws, &w, arch.nx, nu);
    let mut grad = vec![0.0; p.len()];
    let parts = ws.loss_and_grad(&p, &mut grad, &opts).unwrap();
    let want = ref_loss(&arch, &p, &w, &opts);
    assert!(
        (parts.total - want).abs() <= 1e-12 * want.abs().max(1.0),
        "loss value: fast {} vs reference {want}",
        parts.total
    );
    if !ctrl || nu == 0 {
        assert_eq!(parts.ctrl, 0.0);
    }
    if !cov {
        assert_eq!(parts.cov, 0.0);
    } else {
        assert!(parts.cov > 0.0);
    }
    assert_groups_match_fd(
        &groups(&arch),
        &p,
        &grad,
        |pp| ref_loss(&arch, pp, &w, &opts),
        &format!("nu={nu} ctrl={ctrl} cov={cov}"),
    );
}

#[test]
fn gradients_match_finite_differences_with_each_regulariser_on_and_off() {
    for (ctrl, cov) in [(false, false), (true, false), (false, true), (true, true)] {
        check_case(1, ctrl, cov, 11);
    }
}

#[test]
fn pinv_gradient_with_two_inputs_matches_finite_differences() {
    check_case(2, true, false, 12);
    check_case(2, true, true, 13);
}

#[test]
fn autonomous_system_without_inputs_has_correct_gradients() {
    check_case(0, true, true, 14);
}

#[test]
fn f32_gradient_agrees_with_f64() {
    let arch = Arch::new(2, 1, &[32, 32], 4).unwrap();
    let mut rng = Rng::new(5);
    let p = init_params(&arch, &mut rng).unwrap();
    let (b, steps) = (16, 5);
    let w = random_windows(b, steps, 2, 1, &mut rng);
    let opts = LossOptions {
        gamma: 0.8,
        ctrl: true,
        cov: true,
    };
    let mut w64 = LossWs::<f64>::new(&arch, b, steps, Par::Seq);
    fill(&mut w64, &w, 2, 1);
    let mut g64 = vec![0.0; p.len()];
    let l64 = w64.loss_and_grad(&p, &mut g64, &opts).unwrap();
    let p32: Vec<f32> = p.iter().map(|&v| v as f32).collect();
    let mut w32 = LossWs::<f32>::new(&arch, b, steps, Par::rayon(2));
    fill(&mut w32, &w, 2, 1);
    let mut g32 = vec![0.0f32; p.len()];
    let l32 = w32.loss_and_grad(&p32, &mut g32, &opts).unwrap();
    assert!((l32.total - l64.total).abs() < 1e-4 * l64.total);
    let rel = rel_diff(&g64, &g32);
    assert!(rel < 1e-4, "f32 vs f64 gradient relative error {rel}");
}

#[test]
fn row_parallel_evaluation_equals_the_sequential_one() {
    let arch = Arch::new(2, 1, &[16, 16], 4).unwrap();
    let mut rng = Rng::new(8);
    let p = init_params(&arch, &mut rng).unwrap();
    let (b, steps) = (7, 4);
    let w = random_windows(b, steps, 2, 1, &mut rng);
    let opts = LossOptions {
        gamma: 0.8,
        ctrl: true,
        cov: true,
    };
    let mut seq = LossWs::<f64>::new(&arch, b, steps, Par::Seq);
    fill(&mut seq, &w, 2, 1);
    let mut gs = vec![0.0; p.len()];
    let ls = seq.loss_and_grad(&p, &mut gs, &opts).unwrap();
    for parts in [2, 3] {
        let mut par = LossWs::<f64>::new(&arch, b, steps, Par::rayon(parts));
        fill(&mut par, &w, 2, 1);
        let mut gp = vec![0.0; p.len()];
        let lp = par.loss_and_grad(&p, &mut gp, &opts).unwrap();
        assert!((lp.total - ls.total).abs() <= 1e-13 * ls.total);
        for (a, c) in gs.iter().zip(&gp) {
            assert!((a - c).abs() <= 1e-12 * (1.0 + a.abs()), "{a} vs {c}");
        }
    }
}
