//! Checkpoint and resume: a run of 2N iterations equals, bit for bit, a run stopped after N
//! iterations and resumed from its checkpoint file for the other N; mismatched checkpoints and
//! damaged files are refused with typed errors.

mod common;

use common::data;

use koopman::data::Dataset;
use koopman::train::{train, train_resumable, Checkpoint, Precision, TrainConfig, TrainOutcome};
use koopman::Error;
use std::ops::ControlFlow;

fn cfg(precision: Precision) -> TrainConfig {
    TrainConfig {
        n_mult: 4,
        hidden: vec![32, 32],
        iterations: 240,
        batch: 16,
        validate_every: 40,
        // The learning rate decays during both halves, so the schedule must resume too.
        lr_step: 50,
        lr: 3e-3,
        precision,
        threads: 2,
        ..TrainConfig::default()
    }
}

fn scratch(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("kb-resume-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Runs `cfg` but stops right after the checkpoint of iteration `stop_at`, which it returns
/// (read back from its file).
fn interrupted(
    cfg: &TrainConfig,
    tr: &Dataset,
    va: &Dataset,
    stop_at: usize,
    file: &std::path::Path,
) -> Checkpoint {
    let mut seen = Vec::new();
    let r = train_resumable(
        cfg,
        tr,
        va,
        None,
        None,
        &mut |p| {
            // The observer runs before the checkpoint of the same iteration, so stop one later.
            if p.iteration == stop_at + 1 {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            }
        },
        &mut |ck| {
            seen.push(ck.iteration);
            ck.save(file).unwrap();
        },
    );
    assert!(matches!(r, Err(Error::Cancelled)));
    let every = cfg.validate_every;
    assert_eq!(
        seen,
        (1..=stop_at / every).map(|k| k * every).collect::<Vec<_>>()
    );
    let ck = Checkpoint::load(file).unwrap();
    assert_eq!(ck.iteration, stop_at);
    ck
}

fn same_outcome(a: &TrainOutcome, b: &TrainOutcome) {
    assert_eq!(a.model.params(), b.model.params(), "parameters differ");
    assert_eq!(a.metrics.best_iteration, b.metrics.best_iteration);
    assert_eq!(
        a.metrics.best_validation_prediction_error.to_bits(),
        b.metrics.best_validation_prediction_error.to_bits()
    );
    assert_eq!(a.metrics.final_loss, b.metrics.final_loss);
    assert_eq!(
        a.metrics.test_prediction_error.map(f64::to_bits),
        b.metrics.test_prediction_error.map(f64::to_bits)
    );
}

#[test]
fn a_resumed_run_equals_an_uninterrupted_one_bit_for_bit() {
    let (tr, va, te) = (data(96, 1), data(24, 2), data(24, 3));
    let dir = scratch("equal");
    for precision in [Precision::F32, Precision::F64] {
        let cfg = cfg(precision);
        let whole = train(
            &cfg,
            &tr,
            &va,
            Some(&te),
            &mut |_| ControlFlow::Continue(()),
        )
        .unwrap();
        let file = dir.join(format!("{precision:?}.ckpt"));
        let ck = interrupted(&cfg, &tr, &va, 120, &file);
        let mut first_seen = None;
        let resumed = train_resumable(
            &cfg,
            &tr,
            &va,
            Some(&te),
            Some(&ck),
            &mut |p| {
                first_seen.get_or_insert(p.iteration);
                ControlFlow::Continue(())
            },
            &mut |_| {},
        )
        .unwrap();
        assert_eq!(
            first_seen,
            Some(121),
            "the resumed run starts after the checkpoint"
        );
        same_outcome(&whole, &resumed);
        // The best model of the whole run is from the second half: the resume mattered.
        assert!(whole.metrics.best_iteration > 120, "{:?}", whole.metrics);
        // Resuming from the first checkpoint works as well.
        let early = interrupted(&cfg, &tr, &va, 40, &file);
        let again = train_resumable(
            &cfg,
            &tr,
            &va,
            Some(&te),
            Some(&early),
            &mut |_| ControlFlow::Continue(()),
            &mut |_| {},
        )
        .unwrap();
        same_outcome(&whole, &again);
    }
    // A checkpoint taken at the very end resumes to the finished model with no iteration left.
    let cfg = cfg(Precision::F32);
    let mut last = None;
    let whole = train_resumable(
        &cfg,
        &tr,
        &va,
        None,
        None,
        &mut |_| ControlFlow::Continue(()),
        &mut |ck| last = Some(ck.clone()),
    )
    .unwrap();
    let last = last.unwrap();
    assert_eq!(last.iteration, cfg.iterations);
    let mut steps = 0;
    let done = train_resumable(
        &cfg,
        &tr,
        &va,
        None,
        Some(&last),
        &mut |_| {
            steps += 1;
            ControlFlow::Continue(())
        },
        &mut |_| {},
    )
    .unwrap();
    assert_eq!(steps, 0);
    same_outcome(&whole, &done);
}

#[test]
fn mismatched_or_damaged_checkpoints_are_refused() {
    let (tr, va) = (data(48, 4), data(12, 5));
    let dir = scratch("refused");
    let file = dir.join("a.ckpt");
    let cfg = cfg(Precision::F32);
    let ck = interrupted(&cfg, &tr, &va, 40, &file);
    let resume = |c: &TrainConfig, t: &Dataset| {
        train_resumable(
            c,
            t,
            &va,
            None,
            Some(&ck),
            &mut |_| ControlFlow::Continue(()),
            &mut |_| {},
        )
    };
    // Another configuration, other data, another model size.
    let other_lr = TrainConfig {
        lr: 1e-3,
        ..cfg.clone()
    };
    assert!(
        matches!(resume(&other_lr, &tr), Err(Error::InvalidArgument(m)) if m.contains("configuration"))
    );
    let other_data = data(48, 6);
    assert!(
        matches!(resume(&cfg, &other_data), Err(Error::InvalidArgument(m)) if m.contains("other data"))
    );
    let bigger = TrainConfig {
        hidden: vec![32, 33],
        ..cfg.clone()
    };
    assert!(matches!(
        resume(&bigger, &tr),
        Err(Error::InvalidArgument(_))
    ));
    // Another thread count is allowed (the state is the same; only the bits of sums may differ).
    let threads = TrainConfig {
        threads: 1,
        ..cfg.clone()
    };
    assert!(resume(&threads, &tr).is_ok());
    // Damaged, foreign and missing files.
    let bytes = std::fs::read(&file).unwrap();
    let cut = dir.join("cut.ckpt");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    assert!(matches!(Checkpoint::load(&cut), Err(Error::Format { .. })));
    let foreign = dir.join("model.safetensors");
    std::fs::write(
        &foreign,
        safetensors::serialize(
            Vec::<(String, safetensors::tensor::TensorView)>::new(),
            None,
        )
        .unwrap(),
    )
    .unwrap();
    assert!(matches!(
        Checkpoint::load(&foreign),
        Err(Error::Format { .. })
    ));
    assert!(matches!(
        Checkpoint::load(&dir.join("none.ckpt")),
        Err(Error::Io { .. })
    ));
}

/// A z-scored run's checkpoint carries the fingerprint of the data as given (what a trainer
/// service checks before it resumes: it loads the raw files), and resuming it ends bit for bit
/// as the uninterrupted run. Before, the checkpoint held the z-scored data's fingerprint, so a
/// service refused every normalised checkpoint as "taken on other data".
#[test]
fn a_normalised_run_resumes_from_the_fingerprint_of_its_raw_data() {
    let (tr, va, te) = (data(96, 1), data(24, 2), data(24, 3));
    let dir = scratch("normalised");
    let cfg = TrainConfig {
        normalise: true,
        ..cfg(Precision::F32)
    };
    let whole = train(
        &cfg,
        &tr,
        &va,
        Some(&te),
        &mut |_| ControlFlow::Continue(()),
    )
    .unwrap();
    let file = dir.join("normalised.ckpt");
    let ck = interrupted(&cfg, &tr, &va, 120, &file);
    assert_eq!(
        ck.data_fingerprint,
        koopman::train::run_fingerprint(&cfg, &tr, &va)
    );
    let resumed = train_resumable(
        &cfg,
        &tr,
        &va,
        Some(&te),
        Some(&ck),
        &mut |_| ControlFlow::Continue(()),
        &mut |_| {},
    )
    .unwrap();
    same_outcome(&whole, &resumed);
    let _ = std::fs::remove_dir_all(dir);
}
