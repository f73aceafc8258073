//! A bench (ignored by default) of the neural Koopman trainer, as `koopbridge bench train` times
//! it but with the koopman crate alone: 50 warm-up iterations, then `KOOPMAN_BENCH_ITERS`
//! (default 300) timed ones with the default recipe (hidden 256×3, n_mult 16, batch 64, ctrl +
//! cov, f32) and `KOOPMAN_BENCH_THREADS` (default 2) threads; prints wall it/s and process CPU ms
//! per iteration for the damped pendulum (N = 34) and, when `KOOPMAN_BENCH_DATA` names a directory
//! with `train.npz` and `val.npz` (e.g. the Go2 expert data, N = 595), for that data:
//! `KOOPMAN_BENCH_DATA=/work/runs/data/go2-expert cargo test --release -p koopman --test
//! train_bench -- --ignored --nocapture`. `KOOPMAN_BENCH_CURVES=DIR` writes each timed run's
//! per-iteration total loss there as JSON (to compare the arithmetic of two builds).

mod common;

use koopman::data::Dataset;
use koopman::train::{train, Precision, TrainConfig};
use std::ops::ControlFlow;
use std::path::Path;

/// User + system CPU seconds of this process (`/proc/self/stat`, 10 ms resolution).
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap();
    let f: Vec<&str> = stat
        .rsplit(')')
        .next()
        .unwrap()
        .split_whitespace()
        .collect();
    (f[11].parse::<f64>().unwrap() + f[12].parse::<f64>().unwrap()) / 100.0
}

fn env_usize(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn bench(label: &str, tr: &Dataset, va: &Dataset, precision: Precision) {
    let iters = env_usize("KOOPMAN_BENCH_ITERS", 300);
    let mut cfg = TrainConfig {
        iterations: 50,
        validate_every: 50,
        threads: env_usize("KOOPMAN_BENCH_THREADS", 2),
        precision,
        ..TrainConfig::default()
    };
    let quiet = &mut |_: &koopman::train::Progress| ControlFlow::Continue(());
    train(&cfg, tr, va, None, quiet).unwrap();
    cfg.iterations = iters;
    cfg.validate_every = iters;
    let mut curve = Vec::with_capacity(iters);
    let cpu0 = cpu_seconds();
    let out = train(&cfg, tr, va, None, &mut |p| {
        curve.push(p.loss.total);
        ControlFlow::Continue(())
    })
    .unwrap();
    let cpu_ms = 1000.0 * (cpu_seconds() - cpu0) / iters as f64;
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!(
        "{label} (nx {}, nu {}, N {}) {precision:?}, {} threads, {iters} iterations: {:.2} it/s \
         wall, {cpu_ms:.1} ms CPU per iteration; loadavg {}",
        tr.nx,
        tr.nu,
        tr.nx * 17,
        cfg.threads,
        out.metrics.iterations_per_second,
        load.split_whitespace().next().unwrap_or("?"),
    );
    if let Ok(dir) = std::env::var("KOOPMAN_BENCH_CURVES") {
        let name = if label.contains("pendulum") {
            "pendulum"
        } else {
            "data"
        };
        let path = Path::new(&dir).join(format!("{name}-{precision:?}.json"));
        std::fs::write(path, serde_json::to_string(&curve).unwrap()).unwrap();
    }
}

#[test]
#[ignore = "a bench: run with --ignored --nocapture"]
fn train_speed() {
    let precision = if std::env::var("KOOPMAN_BENCH_F64").is_ok() {
        Precision::F64
    } else {
        Precision::F32
    };
    if let Ok(dir) = std::env::var("KOOPMAN_BENCH_DATA") {
        let dir = Path::new(&dir);
        let tr = Dataset::load_npz(&dir.join("train.npz")).unwrap();
        let va = Dataset::load_npz(&dir.join("val.npz")).unwrap();
        let (tr, va) = (
            tr.head(4096.min(tr.n)).unwrap(),
            va.head(256.min(va.n)).unwrap(),
        );
        bench(&dir.display().to_string(), &tr, &va, precision);
    }
    let tr = common::data(4096, 42);
    let va = tr.head(256).unwrap();
    bench("damped pendulum", &tr, &va, precision);
}

/// CPU time of the calling thread in seconds (`/proc/thread-self/schedstat`, ns resolution).
fn thread_cpu() -> f64 {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").unwrap();
    s.split_whitespace().next().unwrap().parse::<f64>().unwrap() * 1e-9
}

/// Thread CPU ms per call of `f` (repeated for at least 0.3 s of CPU after one warm-up call).
fn per_call_ms(mut f: impl FnMut()) -> f64 {
    f();
    let (t0, mut n) = (thread_cpu(), 0);
    while thread_cpu() - t0 < 0.3 || n < 3 {
        f();
        n += 1;
    }
    1e3 * (thread_cpu() - t0) / n as f64
}

/// Where one iteration's time goes at the Go2's size (nx 35, nu 12, N 595, hidden 256×3,
/// batch 64, T 15, f32), each part on one thread (CPU time of that thread, so other processes'
/// load does not count): the encoder passes, the loss with each regulariser on or off (their
/// differences are the regularisers' cost), the rollout's products alone, and Adam.
#[test]
#[ignore = "a bench: run with --ignored --nocapture"]
fn train_parts_go2() {
    use faer::linalg::matmul::matmul;
    use faer::{Accum, Mat, MatRef, Par};
    use koopman::model::arch::Arch;
    use koopman::model::encoder::EncoderWs;
    use koopman::train::adam::{clip_grad_norm, Adam};
    use koopman::train::loss::{LossOptions, LossWs};

    let (nx, nu, b, steps) = (35, 12, 64, 15);
    let arch = Arch::new(nx, nu, &[256, 256, 256], 16).unwrap();
    let nn = arch.latent_dim();
    let params64 =
        koopman::model::init::init_params(&arch, &mut koopman::rng::Rng::new(1)).unwrap();
    let params: Vec<f32> = params64.iter().map(|&v| v as f32).collect();
    let mut grad = vec![0.0f32; params.len()];
    let rows = (steps + 1) * b;
    let gf = |flop: f64, ms: f64| flop / (ms * 1e6);
    // Encoder over all 1,024 states (one part, as each thread runs its half).
    let mut enc = EncoderWs::<f32>::new(&arch, rows, Par::Seq);
    let mut rng = koopman::rng::Rng::new(2);
    for v in enc.input_mut(rows) {
        *v = rng.normal() as f32;
    }
    let macs_row: usize = arch
        .layout()
        .blocks
        .iter()
        .map(|blk| blk.rows() * blk.fan_in)
        .sum();
    let fwd_flop = 2.0 * (rows * macs_row) as f64;
    let first = arch.layout().blocks[0];
    let bwd_flop = 2.0 * fwd_flop - 2.0 * (rows * first.rows() * first.fan_in) as f64;
    let t_fwd = per_call_ms(|| enc.forward(&params));
    let t_bwd = per_call_ms(|| {
        enc.forward(&params);
        for v in enc
            .output_grad_mut()
            .col_iter_mut()
            .flat_map(|c| c.iter_mut())
        {
            *v = 1e-3;
        }
        enc.backward(&params, &mut grad);
    }) - t_fwd;
    println!(
        "encoder forward: {t_fwd:.2} ms, {:.1} GFLOP",
        fwd_flop * 1e-9
    );
    println!("  -> {:.1} GFLOP/s", gf(fwd_flop, t_fwd));
    println!(
        "encoder backward: {t_bwd:.2} ms, {:.1} GFLOP -> {:.1} GFLOP/s",
        bwd_flop * 1e-9,
        gf(bwd_flop, t_bwd)
    );
    // The rollout's products alone: 15 steps forward, 15 adjoint, dA = gᵀ Ẑ (one thread).
    let a = Mat::<f32>::from_fn(nn, nn, |i, j| ((i * 7 + j) % 13) as f32 * 1e-3);
    let zh = Mat::<f32>::from_fn(rows, nn, |i, j| ((i + j) % 5) as f32 * 0.1);
    let mut dst = Mat::<f32>::zeros(rows, nn);
    let t_roll = per_call_ms(|| {
        for k in 0..steps {
            matmul(
                dst.as_mut().subrows_mut(k * b, b),
                Accum::Replace,
                zh.as_ref().subrows(k * b, b),
                a.transpose(),
                1.0,
                Par::Seq,
            );
        }
    });
    let step_flop = 2.0 * (b * nn * nn) as f64 * steps as f64;
    println!(
        "rollout forward (15 × 64×595×595): {t_roll:.2} ms -> {:.1} GFLOP/s",
        gf(step_flop, t_roll)
    );
    let t_half = per_call_ms(|| {
        for k in 0..steps {
            matmul(
                dst.as_mut().subrows_mut(k * b, b / 2),
                Accum::Replace,
                zh.as_ref().subrows(k * b, b / 2),
                a.transpose(),
                1.0,
                Par::Seq,
            );
        }
    });
    println!(
        "  one thread's half (15 × 32×595×595): {t_half:.2} ms -> {:.1} GFLOP/s",
        gf(step_flop / 2.0, t_half)
    );
    let mut ga = Mat::<f32>::zeros(nn, nn);
    let tb = steps * b;
    let t_ga = per_call_ms(|| {
        matmul(
            ga.as_mut(),
            Accum::Add,
            zh.as_ref().subrows(0, tb).transpose(),
            zh.as_ref().subrows(b, tb),
            1.0,
            Par::Seq,
        )
    });
    println!(
        "dA = gᵀ Ẑ (595×960×595): {t_ga:.2} ms -> {:.1} GFLOP/s",
        gf(2.0 * (tb * nn * nn) as f64, t_ga)
    );
    // The whole loss on one thread, regularisers on and off.
    let mut ws = LossWs::<f32>::new(&arch, b, steps, Par::Seq);
    for v in ws.states_mut() {
        *v = rng.normal() as f32;
    }
    for v in ws.inputs_mut() {
        *v = rng.normal() as f32;
    }
    let mut loss_ms = |ctrl: bool, cov: bool| {
        let opts = LossOptions {
            gamma: 0.8,
            ctrl,
            cov,
        };
        per_call_ms(|| {
            ws.loss_and_grad(&params, &mut grad, &opts).unwrap();
        })
    };
    let (t_pred, t_ctrl, t_cov, t_both) = (
        loss_ms(false, false),
        loss_ms(true, false),
        loss_ms(false, true),
        loss_ms(true, true),
    );
    println!("loss_and_grad, one thread: pred only {t_pred:.2} ms, +ctrl {t_ctrl:.2}, +cov {t_cov:.2}, both {t_both:.2}");
    println!(
        "  rollout + copies (pred only − encoder): {:.2} ms",
        t_pred - t_fwd - t_bwd
    );
    let mut adam = Adam::<f32>::new(params.len());
    let mut p2 = params.clone();
    let t_adam = per_call_ms(|| {
        clip_grad_norm(&mut grad, 0.1);
        adam.step(&mut p2, &grad, 1e-3);
    });
    println!(
        "clip + Adam over {} parameters: {t_adam:.2} ms",
        params.len()
    );
    let _ = MatRef::<f32>::from_column_major_slice(&[], 0, 0);
}

/// `acc[i] = acc[i]·m + c` on 12 independent 8-lane f32 vectors, `n` times (AVX2 + FMA).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn fma_chains(n: usize) -> f32 {
    use std::arch::x86_64::*;
    let (m, c) = (
        _mm256_set1_ps(std::hint::black_box(0.999_999)),
        _mm256_set1_ps(std::hint::black_box(1e-7)),
    );
    let mut acc = [_mm256_set1_ps(std::hint::black_box(1.0)); 12];
    for _ in 0..std::hint::black_box(n) {
        for a in acc.iter_mut() {
            *a = _mm256_fmadd_ps(*a, m, c);
        }
    }
    let mut out = [0.0f32; 8];
    let mut s = acc[0];
    for a in &acc[1..] {
        s = _mm256_add_ps(s, *a);
    }
    // SAFETY: `out` holds 8 f32, what one unaligned 256-bit store writes.
    unsafe { _mm256_storeu_ps(out.as_mut_ptr(), s) };
    out.iter().sum()
}

/// The machine's f32 FMA peak on one core (12 independent 256-bit FMA chains; Zen 4 issues two
/// 256-bit FMAs per cycle, and its 512-bit ones as two halves, so AVX-512 has the same peak).
#[test]
#[ignore = "a bench: run with --ignored --nocapture"]
#[cfg(target_arch = "x86_64")]
fn fma_peak() {
    if !(is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")) {
        return;
    }
    let n = 20_000_000;
    let mut sink = 0.0;
    let ms = per_call_ms(|| {
        // SAFETY: the features were detected above.
        sink += unsafe { fma_chains(n) };
    });
    let flop = 2.0 * 8.0 * 12.0 * n as f64;
    println!(
        "f32 FMA peak, one core: {:.1} GFLOP/s ({sink:.1})",
        flop / (ms * 1e6)
    );
}
