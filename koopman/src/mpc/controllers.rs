//! The controllers a closed loop compares, made by kind from the models at hand: Koopman MPC
//! with each solver, LQR, random shooting (on an NNDM or the true system), bilinear MPC (plain
//! or with the offset-free correction), Koopman MPC on an EDMD model and the zero input.

use super::bilinear::{BilinearMpc, ScpOptions};
use super::config::{MpcConfig, SolverKind};
use super::controller::MpcController;
use super::lqr::Lqr;
use super::offset_free::OffsetFreeConfig;
use super::policy::{Action, ConstantPolicy, LqrPolicy, Policy, ShootingPolicy};
use super::shooting::{OneStepModel, RandomShooting};
use crate::error::{Error, Result};
use crate::model::bilinear::BilinearModel;
use crate::model::LiftedModel;
use crate::systems::System;

/// Input sequences sampled per step by the random-shooting controllers.
pub const SHOOTING_SAMPLES: usize = 1000;
/// Seed of the random-shooting controllers' samples.
pub const SHOOTING_SEED: u64 = 1;
/// Iteration limit of the LQR's Riccati iteration.
pub const LQR_MAX_ITERATIONS: usize = 20_000;
/// Relative tolerance of the LQR's Riccati iteration.
pub const LQR_TOLERANCE: f64 = 1e-10;
/// The smallest input weight the LQR uses (R = 0 leaves its gain ill-posed).
pub const LQR_MIN_R: f64 = 1e-6;

/// A controller [`build`] can make; [`ControllerKind::needs`] says which model it plans on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ControllerKind {
    /// [`MpcController`] with [`SolverKind::Dedicated`].
    Dedicated,
    /// [`MpcController`] (dedicated solver) with the offset-free correction of
    /// [`ControllerSettings::offset_free`].
    OffsetFree,
    /// [`MpcController`] with [`SolverKind::Clarabel`].
    Clarabel,
    /// [`MpcController`] with [`SolverKind::ClosedForm`].
    ClosedForm,
    /// [`LqrPolicy`]: [`Lqr`] with feed-forward, clamped to the bounds.
    Lqr,
    /// [`ShootingPolicy`] on the given one-step model (an NNDM).
    Shooting,
    /// [`ShootingPolicy`] on the controlled system itself: the oracle baseline.
    ShootingOracle,
    /// [`BilinearMpc`], re-linearised along each plan.
    Bilinear,
    /// [`BilinearMpc`] with the offset-free correction of [`ControllerSettings::offset_free`].
    BilinearOffsetFree,
    /// [`MpcController`] (dedicated solver) on the EDMD model of [`Models::edmd`].
    Edmd,
    /// [`ConstantPolicy::zero`]: the free response.
    ZeroInput,
}

/// The model a controller plans on, besides the true system.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ModelNeed {
    /// A lifted (Koopman or EDMD) model.
    Lifted,
    /// A lifted model and offset-free settings ([`ControllerSettings::offset_free`]).
    LiftedOffsetFree,
    /// An NNDM (a one-step model).
    Nndm,
    /// A bilinear Koopman model.
    Bilinear,
    /// A bilinear Koopman model and offset-free settings ([`ControllerSettings::offset_free`]).
    BilinearOffsetFree,
    /// An EDMD model next to the lifted one ([`Models::edmd`]).
    Edmd,
}

impl ControllerKind {
    /// Every kind, in the order of a comparison report.
    pub const ALL: [ControllerKind; 11] = [
        ControllerKind::BilinearOffsetFree,
        ControllerKind::Bilinear,
        ControllerKind::OffsetFree,
        ControllerKind::Dedicated,
        ControllerKind::Clarabel,
        ControllerKind::ClosedForm,
        ControllerKind::Lqr,
        ControllerKind::Edmd,
        ControllerKind::ShootingOracle,
        ControllerKind::Shooting,
        ControllerKind::ZeroInput,
    ];

    /// The kind's name in reports and file names (`dedicated`, `closed-form`, …).
    pub fn name(self) -> &'static str {
        match self {
            ControllerKind::Dedicated => "dedicated",
            ControllerKind::OffsetFree => "offset-free",
            ControllerKind::Clarabel => "clarabel",
            ControllerKind::ClosedForm => "closed-form",
            ControllerKind::Lqr => "lqr",
            ControllerKind::Shooting => "shooting",
            ControllerKind::ShootingOracle => "shooting-oracle",
            ControllerKind::Bilinear => "bilinear",
            ControllerKind::BilinearOffsetFree => "bilinear-offset-free",
            ControllerKind::Edmd => "edmd",
            ControllerKind::ZeroInput => "zero-input",
        }
    }

    /// The model this kind plans on; `None` for those that need only the true system.
    pub fn needs(self) -> Option<ModelNeed> {
        match self {
            ControllerKind::Dedicated
            | ControllerKind::Clarabel
            | ControllerKind::ClosedForm
            | ControllerKind::Lqr => Some(ModelNeed::Lifted),
            ControllerKind::OffsetFree => Some(ModelNeed::LiftedOffsetFree),
            ControllerKind::Shooting => Some(ModelNeed::Nndm),
            ControllerKind::Bilinear => Some(ModelNeed::Bilinear),
            ControllerKind::BilinearOffsetFree => Some(ModelNeed::BilinearOffsetFree),
            ControllerKind::Edmd => Some(ModelNeed::Edmd),
            ControllerKind::ShootingOracle | ControllerKind::ZeroInput => None,
        }
    }

    /// Every kind whose model is among `at_hand`, in report order ([`ControllerKind::ALL`]).
    pub fn available(at_hand: &[ModelNeed]) -> Vec<ControllerKind> {
        Self::ALL
            .into_iter()
            .filter(|k| k.needs().is_none_or(|n| at_hand.contains(&n)))
            .collect()
    }
}

/// The system under control and the models a controller may plan on.
#[derive(Clone, Copy)]
pub struct Models<'m> {
    /// The controlled system (the oracle's model; its dimensions are the controller's).
    pub system: &'m dyn System,
    /// A lifted model (Koopman MPC, LQR).
    pub lifted: Option<&'m dyn LiftedModel>,
    /// A one-step model (random shooting).
    pub nndm: Option<&'m dyn OneStepModel>,
    /// A bilinear model (sequential convex MPC).
    pub bilinear: Option<&'m BilinearModel>,
    /// An EDMD model (Koopman MPC, one more row beside the lifted model's).
    pub edmd: Option<&'m dyn LiftedModel>,
}

/// The settings every controller shares.
#[derive(Clone, Debug, PartialEq)]
pub struct ControllerSettings {
    /// Planning horizon H (MPC and random shooting).
    pub horizon: usize,
    /// Diagonal input weight R (the LQR uses at least [`LQR_MIN_R`]).
    pub r: f64,
    /// Diagonal state weight Q (nx values) of every planner (MPC, LQR, random shooting);
    /// `None` = identity (SPEC.md's default).
    pub q: Option<Vec<f64>>,
    /// Lower input bounds (nu).
    pub u_min: Vec<f64>,
    /// Upper input bounds (nu).
    pub u_max: Vec<f64>,
    /// The offset-free correction of [`ControllerKind::BilinearOffsetFree`] and
    /// [`ControllerKind::OffsetFree`].
    pub offset_free: Option<OffsetFreeConfig>,
}

/// A controller ready for the closed loop, and what the caller should tell the user about it.
pub struct Built<'m> {
    /// The controller.
    pub policy: Box<dyn Policy + 'm>,
    /// A warning about how it was built (e.g. a Riccati iteration that did not converge).
    pub warning: Option<String>,
}

/// Makes the controller `kind` on `models` with `settings` (state weights `settings.q`, else 1).
///
/// Errors: the model `kind` plans on is absent from `models`, or the controller refuses the
/// model or the settings (the error of its own constructor).
pub fn build<'m>(
    kind: ControllerKind,
    models: Models<'m>,
    settings: &ControllerSettings,
) -> Result<Built<'m>> {
    let missing = |what: &str| {
        Error::InvalidArgument(format!(
            "controller {} needs {what}, none was given",
            kind.name()
        ))
    };
    let lifted = || {
        models
            .lifted
            .ok_or_else(|| missing("a lifted model (koopman or edmd)"))
    };
    let (nx, nu) = (models.system.nx(), models.system.nu());
    let (lo, hi) = (&settings.u_min, &settings.u_max);
    if let Some(q) = &settings.q {
        if q.len() != nx || q.iter().any(|w| !(w.is_finite() && *w >= 0.0)) {
            return Err(Error::InvalidArgument(format!(
                "the state weight Q needs {nx} finite values ≥ 0, got {q:?}"
            )));
        }
    }
    let q = settings.q.clone().unwrap_or_else(|| vec![1.0; nx]);
    let mpc_config = MpcConfig {
        horizon: settings.horizon,
        q: settings.q.clone(),
        r: Some(vec![settings.r; nu]),
        ..MpcConfig::with_bounds(lo.clone(), hi.clone())
    };
    let shooting = || {
        RandomShooting::new(
            SHOOTING_SAMPLES,
            settings.horizon,
            q.clone(),
            lo.clone(),
            hi.clone(),
            SHOOTING_SEED,
        )
    };
    let mut warning = None;
    let policy: Box<dyn Policy + 'm> = match kind {
        ControllerKind::Dedicated | ControllerKind::Clarabel | ControllerKind::ClosedForm => {
            let solver = match kind {
                ControllerKind::Dedicated => SolverKind::Dedicated,
                ControllerKind::Clarabel => SolverKind::Clarabel,
                _ => SolverKind::ClosedForm,
            };
            let cfg = MpcConfig {
                solver,
                ..mpc_config
            };
            Box::new(MpcController::new(lifted()?, &cfg)?)
        }
        ControllerKind::OffsetFree => {
            let mut mpc = MpcController::new(lifted()?, &mpc_config)?;
            let offset = settings
                .offset_free
                .clone()
                .ok_or_else(|| missing("offset-free settings"))?;
            mpc.set_offset_free(Some(offset))?;
            Box::new(mpc)
        }
        ControllerKind::Lqr => {
            let model = lifted()?;
            let lqr = Lqr::new(
                model,
                &q,
                &vec![settings.r.max(LQR_MIN_R); nu],
                LQR_MAX_ITERATIONS,
                LQR_TOLERANCE,
            )?;
            if !lqr.converged {
                warning = Some(format!(
                    "the Riccati iteration did not converge in {} iterations",
                    lqr.iterations
                ));
            }
            Box::new(LqrPolicy::new(lqr, model, lo.clone(), hi.clone())?)
        }
        ControllerKind::Shooting => {
            let nndm = models.nndm.ok_or_else(|| missing("an NNDM model"))?;
            Box::new(ShootingPolicy::new(shooting()?, nndm, "nndm"))
        }
        ControllerKind::ShootingOracle => Box::new(ShootingPolicy::on_system(
            shooting()?,
            models.system,
            "true-system",
        )),
        ControllerKind::Bilinear | ControllerKind::BilinearOffsetFree => {
            let model = models.bilinear.ok_or_else(|| missing("a bilinear model"))?;
            let mut mpc = BilinearMpc::new(model, &mpc_config, ScpOptions::default())?;
            if kind == ControllerKind::BilinearOffsetFree {
                let offset = settings
                    .offset_free
                    .clone()
                    .ok_or_else(|| missing("offset-free settings"))?;
                mpc.set_offset_free(Some(offset))?;
            }
            Box::new(mpc)
        }
        ControllerKind::Edmd => {
            let model = models.edmd.ok_or_else(|| missing("an EDMD model"))?;
            Box::new(Named(
                MpcController::new(model, &mpc_config)?,
                "edmd-mpc/dedicated",
            ))
        }
        ControllerKind::ZeroInput => Box::new(ConstantPolicy::zero(nu)),
    };
    Ok(Built { policy, warning })
}

/// A policy under another name in reports (the EDMD row beside the Koopman model's).
struct Named<P>(P, &'static str);

impl<P: Policy> Policy for Named<P> {
    fn name(&self) -> String {
        self.1.into()
    }
    fn horizon(&self) -> usize {
        self.0.horizon()
    }
    fn act(&mut self, x: &[f64], current: &[f64], future: &[f64]) -> Result<Action> {
        self.0.act(x, current, future)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::matrix::MatrixModel;
    use crate::systems::by_name;

    /// The pendulum (nx = 2, nu = 1) with `lifted` as its only model.
    fn models<'m>(system: &'m dyn System, lifted: Option<&'m dyn LiftedModel>) -> Models<'m> {
        Models {
            system,
            lifted,
            nndm: None,
            bilinear: None,
            edmd: None,
        }
    }

    /// Horizon `h`, input weight `r`, and the bounds `[lo, hi]` on the one input.
    fn settings(h: usize, r: f64, lo: f64, hi: f64) -> ControllerSettings {
        ControllerSettings {
            horizon: h,
            r,
            q: None,
            u_min: vec![lo],
            u_max: vec![hi],
            offset_free: None,
        }
    }

    #[test]
    fn available_follows_the_models_at_hand_in_report_order() {
        use ControllerKind::*;
        assert_eq!(
            ControllerKind::available(&[]),
            vec![ShootingOracle, ZeroInput]
        );
        assert_eq!(
            ControllerKind::available(&[ModelNeed::Nndm, ModelNeed::Lifted]),
            vec![
                Dedicated,
                Clarabel,
                ClosedForm,
                Lqr,
                ShootingOracle,
                Shooting,
                ZeroInput
            ]
        );
        assert_eq!(
            ControllerKind::available(&[ModelNeed::Bilinear])[0],
            Bilinear
        );
    }

    #[test]
    fn each_kind_builds_on_its_model_and_is_refused_without_it() {
        let system = by_name("damped-pendulum").unwrap();
        let model = MatrixModel::random_stable(2, 6, 1, 0.9, 3).unwrap();
        let settings = settings(5, 0.0, -2.0, 2.0);
        let bare = models(system.as_ref(), None);
        let with_lifted = models(system.as_ref(), Some(&model));
        let x = [0.3, -0.1];
        let future = vec![0.0; 2 * settings.horizon];
        for kind in ControllerKind::available(&[ModelNeed::Lifted]) {
            let mut built = build(kind, with_lifted, &settings).unwrap();
            let action = built.policy.act(&x, &[0.0, 0.0], &future).unwrap();
            assert_eq!(action.u.len(), 1, "{kind:?}");
            assert!((-2.0..=2.0).contains(&action.u[0]), "{kind:?}: {action:?}");
            if kind == ControllerKind::ZeroInput {
                assert_eq!(action.u, vec![0.0]);
            }
        }
        for kind in ControllerKind::ALL {
            let Some(need) = kind.needs() else { continue };
            let err = build(kind, bare, &settings).err().expect("refused");
            assert!(
                matches!(err, Error::InvalidArgument(_)),
                "{kind:?} {need:?}: {err}"
            );
        }
    }

    #[test]
    fn the_offset_free_row_is_the_dedicated_mpc_with_the_correction() {
        let system = by_name("damped-pendulum").unwrap();
        let model = MatrixModel::random_stable(2, 6, 1, 0.9, 3).unwrap();
        let on_model = models(system.as_ref(), Some(&model));
        assert_eq!(
            ControllerKind::available(&[ModelNeed::Lifted, ModelNeed::LiftedOffsetFree])[..2],
            [ControllerKind::OffsetFree, ControllerKind::Dedicated]
        );
        let plain = settings(5, 0.0, -2.0, 2.0);
        let err = build(ControllerKind::OffsetFree, on_model, &plain)
            .err()
            .expect("no settings");
        assert!(err.to_string().contains("offset-free settings"), "{err}");
        let with = ControllerSettings {
            offset_free: Some(OffsetFreeConfig::defaults(
                super::super::OffsetMode::Disturbance,
                2,
                vec![0],
            )),
            ..plain.clone()
        };
        let mut built = build(ControllerKind::OffsetFree, on_model, &with).unwrap();
        assert_eq!(built.policy.name(), "koopman-mpc/dedicated+disturbance");
        // The first decision (no prediction error seen yet) is the plain MPC's.
        let mut dedicated = build(ControllerKind::Dedicated, on_model, &plain).unwrap();
        let (x, future) = ([0.1, 0.0], vec![0.0; 10]);
        assert_eq!(
            built.policy.act(&x, &[0.0, 0.0], &future).unwrap().u,
            dedicated.policy.act(&x, &[0.0, 0.0], &future).unwrap().u
        );
    }

    #[test]
    fn the_dedicated_controller_is_the_mpc_controller_with_those_settings() {
        // The factory adds nothing of its own: its first input is the hand-built controller's.
        let system = by_name("damped-pendulum").unwrap();
        let model = MatrixModel::random_stable(2, 8, 1, 0.95, 4).unwrap();
        let on_model = models(system.as_ref(), Some(&model));
        let x = [1.0, 0.2];
        let future: Vec<f64> = (0..2 * 7).map(|i| 0.05 * i as f64).collect();
        let mut built = build(
            ControllerKind::Dedicated,
            on_model,
            &settings(7, 0.01, -1.0, 1.5),
        )
        .unwrap();
        let got = built.policy.act(&x, &[0.0, 0.0], &future).unwrap().u;
        let cfg = MpcConfig {
            horizon: 7,
            r: Some(vec![0.01]),
            solver: SolverKind::Dedicated,
            ..MpcConfig::with_bounds(vec![-1.0], vec![1.5])
        };
        let mut direct = MpcController::new(&model, &cfg).unwrap();
        let want = direct.solve(&x, &future).unwrap();
        assert_eq!(got, want.first(1).to_vec());
    }

    #[test]
    fn the_state_weight_reaches_every_planner_and_bad_weights_are_refused() {
        let system = by_name("damped-pendulum").unwrap();
        let model = MatrixModel::random_stable(2, 8, 1, 0.95, 4).unwrap();
        let on_model = models(system.as_ref(), Some(&model));
        let x = [1.0, 0.2];
        let future: Vec<f64> = (0..2 * 7).map(|i| 0.05 * i as f64).collect();
        let weighted = ControllerSettings {
            q: Some(vec![1.0, 0.01]),
            ..settings(7, 0.01, -3.0, 3.0)
        };
        let first = |kind, s: &ControllerSettings| {
            let mut built = build(kind, on_model, s).unwrap();
            built.policy.act(&x, &[0.0, 0.0], &future).unwrap().u
        };
        let got = first(ControllerKind::Dedicated, &weighted);
        let cfg = MpcConfig {
            horizon: 7,
            q: Some(vec![1.0, 0.01]),
            r: Some(vec![0.01]),
            solver: SolverKind::Dedicated,
            ..MpcConfig::with_bounds(vec![-3.0], vec![3.0])
        };
        let mut direct = MpcController::new(&model, &cfg).unwrap();
        assert_eq!(got, direct.solve(&x, &future).unwrap().first(1).to_vec());
        // Q changes the plans of the MPC, the LQR and random shooting (an ignored Q would not).
        let plain = settings(7, 0.01, -3.0, 3.0);
        for kind in [
            ControllerKind::Dedicated,
            ControllerKind::Lqr,
            ControllerKind::ShootingOracle,
        ] {
            let (a, b) = (first(kind, &weighted), first(kind, &plain));
            assert!((a[0] - b[0]).abs() > 1e-6, "{kind:?}: {a:?} vs {b:?}");
        }
        for bad in [vec![1.0], vec![1.0, -0.1], vec![1.0, f64::NAN]] {
            let s = ControllerSettings {
                q: Some(bad),
                ..plain.clone()
            };
            assert!(build(ControllerKind::Dedicated, on_model, &s).is_err());
        }
    }

    #[test]
    fn the_edmd_row_is_the_dedicated_mpc_on_the_edmd_model_under_its_own_name() {
        let system = by_name("damped-pendulum").unwrap();
        let model = MatrixModel::random_stable(2, 8, 1, 0.95, 5).unwrap();
        let set = settings(6, 0.0, -1.0, 1.0);
        let x = [0.7, -0.3];
        let future = vec![0.0; 2 * set.horizon];
        let mut on_edmd = models(system.as_ref(), None);
        on_edmd.edmd = Some(&model);
        let mut edmd = build(ControllerKind::Edmd, on_edmd, &set).unwrap();
        let mut dedicated = build(
            ControllerKind::Dedicated,
            models(system.as_ref(), Some(&model)),
            &set,
        )
        .unwrap();
        assert_eq!(edmd.policy.name(), "edmd-mpc/dedicated");
        assert_ne!(dedicated.policy.name(), edmd.policy.name());
        assert_eq!(
            edmd.policy.act(&x, &[0.0, 0.0], &future).unwrap().u,
            dedicated.policy.act(&x, &[0.0, 0.0], &future).unwrap().u
        );
        // Offset-free bilinear MPC without its settings (and without a model) is refused.
        let err = build(ControllerKind::BilinearOffsetFree, on_edmd, &set)
            .err()
            .expect("refused");
        assert!(matches!(err, Error::InvalidArgument(_)), "{err}");
    }
}
