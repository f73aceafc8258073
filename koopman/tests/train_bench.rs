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
