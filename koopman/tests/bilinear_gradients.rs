//! Checks the bilinear model's hand-written loss gradients (`z⁺ = A z + B u + Σ u_i N_i z`,
//! inverse control through each sample's `pinv(B(z))`) against central finite differences of a
//! naive reference (per-sample loops, pinv by SVD), and that the model at initialisation is
//! SPEC's linear model.

// The reference implementation indexes like the formulas on purpose.
#![allow(clippy::needless_range_loop)]

mod common;

use common::grad::{assert_groups_match_fd, fill, random_windows, ref_cov, rel_diff, Windows};
use faer::{Mat, Par};
use koopman::model::arch::Arch;
use koopman::model::bilinear::BilinearModel;
use koopman::model::init::init_params;
use koopman::model::koopman::KoopmanModel;
use koopman::model::LiftedModel;
use koopman::rng::Rng;
use koopman::train::bilinear::bilinear_len;
use koopman::train::loss::{LossOptions, LossWs};

/// Reference total loss of the bilinear model with plain loops; the lifting is the inference
/// model's (f64 forward pass), everything after it is written out here.
fn ref_loss(arch: &Arch, p: &[f64], w: &Windows, opts: &LossOptions) -> f64 {
    let lay = arch.layout();
    let (nx, nu, nn) = (arch.nx, arch.nu, arch.latent_dim());
    let lin = KoopmanModel::from_params(arch.clone(), p[..lay.len].to_vec()).unwrap();
    let a = |i: usize, j: usize| p[lay.a + i * nn + j];
    let bmat = |i: usize, j: usize| p[lay.b + i * nu + j];
    let nmat = |k: usize, i: usize, j: usize| p[lay.len + k * nn * nn + i * nn + j];
    let b = w.x.len();
    let steps = w.u[0].len();
    let weights: Vec<f64> = (0..steps).map(|k| opts.gamma.powi(k as i32)).collect();
    let wsum: f64 = weights.iter().sum();
    let z: Vec<Vec<Vec<f64>>> =
        w.x.iter()
            .map(|win| win.iter().map(|s| lin.lift(s)).collect())
            .collect();
    let step = |zc: &[f64], u: &[f64]| -> Vec<f64> {
        (0..nn)
            .map(|r| {
                let mut s = 0.0;
                for c in 0..nn {
                    let mut arc = a(r, c);
                    for k in 0..nu {
                        arc += u[k] * nmat(k, r, c);
                    }
                    s += arc * zc[c];
                }
                for k in 0..nu {
                    s += bmat(r, k) * u[k];
                }
                s
            })
            .collect()
    };
    let mut pred = 0.0;
    for i in 0..b {
        let mut zh = z[i][0].clone();
        for k in 0..steps {
            zh = step(&zh, &w.u[i][k]);
            for j in 0..nx {
                let d = zh[j] - w.x[i][k + 1][j];
                pred += weights[k] * d * d / (b * nx) as f64;
            }
        }
    }
    let mut total = pred / wsum;
    if opts.ctrl {
        let mut ctrl = 0.0;
        for i in 0..b {
            for k in 0..steps {
                let zc = &z[i][k];
                let bz = Mat::from_fn(nn, nu, |r, c| {
                    bmat(r, c) + (0..nn).map(|j| nmat(c, r, j) * zc[j]).sum::<f64>()
                });
                let svd = bz.thin_svd().unwrap();
                let (u_, s_, v_) = (svd.U(), svd.S(), svd.V());
                let res: Vec<f64> = (0..nn)
                    .map(|r| z[i][k + 1][r] - (0..nn).map(|c| a(r, c) * zc[c]).sum::<f64>())
                    .collect();
                for j in 0..nu {
                    let uh: f64 = (0..nn)
                        .map(|c| {
                            (0..nu)
                                .map(|q| v_[(j, q)] * u_[(c, q)] / s_[q])
                                .sum::<f64>()
                                * res[c]
                        })
                        .sum();
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
        g.push((format!("block{l}.weights"), blk.w, blk.b));
        g.push((format!("block{l}.biases"), blk.b, blk.b + blk.rows()));
    }
    g.push(("A".into(), lay.a, lay.b));
    g.push(("B".into(), lay.b, lay.len));
    let nn = arch.latent_dim();
    for i in 0..arch.nu {
        let s = lay.len + i * nn * nn;
        g.push((format!("N{}", i + 1), s, s + nn * nn));
    }
    g
}

fn arch(nu: usize) -> Arch {
    Arch {
        nx: 2,
        nu,
        widths: vec![2, 6, 6, 5],
    }
}

/// Generic parameters: SPEC's initialisation moved by noise, with non-zero N_i.
fn generic_params(arch: &Arch, rng: &mut Rng) -> Vec<f64> {
    let mut p = init_params(arch, rng).unwrap();
    for v in p.iter_mut() {
        *v += 0.05 * rng.normal();
    }
    p.extend((0..bilinear_len(arch)).map(|_| 0.1 * rng.normal()));
    p
}

fn check_case(nu: usize, ctrl: bool, cov: bool, seed: u64) {
    let arch = arch(nu);
    let mut rng = Rng::new(seed);
    let p = generic_params(&arch, &mut rng);
    let (b, steps) = (5, 3);
    let w = random_windows(b, steps, arch.nx, nu, &mut rng);
    let opts = LossOptions {
        gamma: 0.8,
        ctrl,
        cov,
    };
    let mut ws = LossWs::<f64>::with_dynamics(&arch, b, steps, Par::Seq, true);
    fill(&mut ws, &w, arch.nx, nu);
    let mut grad = vec![0.0; p.len()];
    let parts = ws.loss_and_grad(&p, &mut grad, &opts).unwrap();
    let want = ref_loss(&arch, &p, &w, &opts);
    assert!(
        (parts.total - want).abs() <= 1e-11 * want.abs().max(1.0),
        "loss value: fast {} vs reference {want}",
        parts.total
    );
    if ctrl {
        assert!(parts.ctrl > 0.0);
    } else {
        assert_eq!(parts.ctrl, 0.0);
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
fn bilinear_gradients_match_finite_differences_with_and_without_inverse_control() {
    check_case(1, false, true, 21);
    check_case(1, true, false, 22);
    check_case(1, true, true, 23);
}

#[test]
fn bilinear_gradients_with_two_inputs_match_finite_differences() {
    check_case(2, true, true, 24);
    check_case(2, false, false, 25);
}

#[test]
fn bilinear_model_at_initialisation_is_the_linear_model() {
    let arch = Arch::new(2, 1, &[16, 16], 4).unwrap();
    let seed = 17382;
    let bil = BilinearModel::init(arch.clone(), seed).unwrap();
    let lin = KoopmanModel::init(arch.clone(), seed).unwrap();
    assert_eq!(bil.linear(), &lin);
    assert!(bil.n_flat().iter().all(|v| *v == 0.0));
    // Same latent prediction, exactly.
    let x = [0.7, -1.3];
    let z = bil.lift(&x);
    assert_eq!(z, lin.lift(&x));
    let mut next = vec![0.0; z.len()];
    bil.step(&z, &[2.5], &mut next);
    let (a, b) = (lin.a(), lin.b());
    for r in 0..z.len() {
        let want: f64 = (0..z.len()).map(|c| a[(r, c)] * z[c]).sum::<f64>() + b[(r, 0)] * 2.5;
        assert!((next[r] - want).abs() <= 1e-14 * (1.0 + want.abs()));
    }
    // Same losses and the same gradient of the shared parameters.
    let mut rng = Rng::new(3);
    let (nb, steps) = (8, 4);
    let w = random_windows(nb, steps, 2, 1, &mut rng);
    let opts = LossOptions {
        gamma: 0.8,
        ctrl: true,
        cov: true,
    };
    let mut wl = LossWs::<f64>::new(&arch, nb, steps, Par::Seq);
    let mut wb = LossWs::<f64>::with_dynamics(&arch, nb, steps, Par::Seq, true);
    fill(&mut wl, &w, 2, 1);
    fill(&mut wb, &w, 2, 1);
    let pl = lin.params().to_vec();
    let pb = bil.params();
    let mut gl = vec![0.0; pl.len()];
    let mut gb = vec![0.0; pb.len()];
    let ll = wl.loss_and_grad(&pl, &mut gl, &opts).unwrap();
    let lb = wb.loss_and_grad(&pb, &mut gb, &opts).unwrap();
    assert_eq!(ll.pred, lb.pred);
    assert_eq!(ll.cov, lb.cov);
    assert!(
        (ll.ctrl - lb.ctrl).abs() <= 1e-12 * ll.ctrl,
        "{ll:?} vs {lb:?}"
    );
    assert!(rel_diff(&gl, &gb) < 1e-10, "shared gradient differs");
    // The N gradient is not zero at N = 0: training moves away from the linear model.
    assert!(gb[pl.len()..].iter().any(|g| *g != 0.0));
}

#[test]
fn bilinear_f32_gradient_agrees_with_f64_and_row_parts_agree() {
    let arch = Arch::new(2, 1, &[32, 32], 4).unwrap();
    let mut rng = Rng::new(5);
    let p = generic_params(&arch, &mut rng);
    let (b, steps) = (16, 5);
    let w = random_windows(b, steps, 2, 1, &mut rng);
    let opts = LossOptions {
        gamma: 0.8,
        ctrl: true,
        cov: true,
    };
    let mut w64 = LossWs::<f64>::with_dynamics(&arch, b, steps, Par::Seq, true);
    fill(&mut w64, &w, 2, 1);
    let mut g64 = vec![0.0; p.len()];
    let l64 = w64.loss_and_grad(&p, &mut g64, &opts).unwrap();
    let mut wpar = LossWs::<f64>::with_dynamics(&arch, b, steps, Par::rayon(3), true);
    fill(&mut wpar, &w, 2, 1);
    let mut gpar = vec![0.0; p.len()];
    let lpar = wpar.loss_and_grad(&p, &mut gpar, &opts).unwrap();
    assert!((lpar.total - l64.total).abs() <= 1e-13 * l64.total);
    for (a, c) in g64.iter().zip(&gpar) {
        assert!((a - c).abs() <= 1e-11 * (1.0 + a.abs()), "{a} vs {c}");
    }
    let p32: Vec<f32> = p.iter().map(|&v| v as f32).collect();
    let mut w32 = LossWs::<f32>::with_dynamics(&arch, b, steps, Par::rayon(2), true);
    fill(&mut w32, &w, 2, 1);
    let mut g32 = vec![0.0f32; p.len()];
    let l32 = w32.loss_and_grad(&p32, &mut g32, &opts).unwrap();
    assert!((l32.total - l64.total).abs() < 1e-4 * l64.total);
    let rel = rel_diff(&g64, &g32);
    assert!(rel < 1e-3, "f32 vs f64 {rel}");
}

#[test]
fn wrong_parameter_length_is_a_typed_error() {
    let arch = arch(1);
    let mut ws = LossWs::<f64>::with_dynamics(&arch, 3, 2, Par::Seq, true);
    let p = vec![0.0; arch.num_params()];
    let mut g = p.clone();
    let opts = LossOptions {
        gamma: 0.8,
        ctrl: false,
        cov: false,
    };
    assert!(matches!(
        ws.loss_and_grad(&p, &mut g, &opts),
        Err(koopman::Error::Dimension { .. })
    ));
}
