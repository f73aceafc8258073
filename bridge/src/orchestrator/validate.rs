//! The whole scenario checked against its simulators' `info` right after the readiness barrier,
//! before the expensive phases: the uniform policy's bounds and the initial-state box of
//! `[collect]` or of each simulator's `[[sims]]` entry (its data region), `[train].config` and its model kinds, `[control].mpc` (for an NNDM, what random
//! shooting honours),
//! and the lengths of `control.x0`/`control.reference` (and a `reference_file` or
//! `feedforward_file` that exists already), so that a typo fails in seconds, not after
//! collection.

use koopman::mpc::{LoadedModel, MpcController, AUTONOMOUS_MPC};
use koopman::train::stand_in::{self, StandIn};
use koopman::train::TrainConfig;

use super::control_settings::{controlled_sim, mpc_config, position_loop_of};
use super::reference::{load_feedforward, load_trajectory};
use crate::error::{Error, Result};
use crate::messages::SimInfo;
use crate::scenario::{ControlSpec, Scenario};
use crate::services::koopman_trainer::train_config;
use crate::services::model_kind::ModelKind;

/// Checks every setting of `sc` that the services would only check later: the training
/// settings, and for `[control]` the MPC settings (by building a controller on a stand-in
/// linear model of the controlled simulator's dimensions) and the lengths of `x0` and
/// `reference`. `infos[j]` is the `info` of `sc.sims[j]`.
pub fn validate_scenario(sc: &Scenario, infos: &[&SimInfo]) -> Result<()> {
    // The training settings in force (after `--full`, the merge with `[full]`).
    sc.check_train()?;
    use crate::messages::CollectPolicy;
    use crate::scenario::Policy;
    let shared_box = sc.collect.x0_box()?;
    for (j, (s, info)) in sc.sims.iter().zip(infos).enumerate() {
        let region = sc.sim_region(j)?;
        // Its own adapter inputs (`collect_inputs`), else the shared policy.
        let policy = sc.sim_policy(j);
        let (low, high) = match &policy {
            Policy::Uniform { low, high }
            | Policy::Adapter {
                inputs: CollectPolicy::Uniform { low, high, .. },
                ..
            } => (low, high),
            _ => (&None, &None),
        };
        let uniform = !matches!(
            policy,
            Policy::Scripted { .. }
                | Policy::Adapter {
                    inputs: CollectPolicy::Planned { .. }
                        | CollectPolicy::Expert(_)
                        | CollectPolicy::ExpertNoise(_),
                    ..
                }
        );
        // The adapter policy's bounds default to the simulator's (then checked by it).
        let explicit =
            low.is_some() || high.is_some() || region.low.is_some() || region.high.is_some();
        if uniform && (explicit || matches!(policy, Policy::Uniform { .. })) {
            let (low, high) = (
                region.low.clone().or(low.clone()),
                region.high.clone().or(high.clone()),
            );
            crate::collect::uniform_bounds(&low, &high, info).map_err(|m| {
                let m = if region.low.is_some() || region.high.is_some() {
                    m.replace("collect.policy: `low`", "u_low")
                        .replace("collect.policy: `high`", "u_high")
                        .replace("collect.policy: ", "")
                } else {
                    m
                };
                Error::Config(format!("simulator '{}': {m}", s.id))
            })?;
        }
        if let Some(xb) = &region.x0_box {
            crate::collect::check_x0_box(xb, s.x0_keys(), &s.id, info)
                .map_err(|m| Error::Config(format!("[[sims]] '{}': {m}", s.id)))?;
        } else if let Some(xb) = &shared_box {
            crate::collect::check_x0_box(xb, sc.collect.x0_keys(), &s.id, info)
                .map_err(|m| Error::Config(format!("[collect]: {m}")))?;
        }
    }
    if let Some(t) = &sc.train {
        train_config(&t.config).map_err(|e| {
            Error::Config(format!(
                "[train].config: {e}; valid settings: {}",
                train_setting_names().join(", ")
            ))
        })?;
        for s in sc.sims.iter().filter(|s| !s.train_config.is_empty()) {
            train_config(&sc.train_config_of(&s.id)).map_err(|e| {
                Error::Config(format!(
                    "[[sims]] '{}' train_config: {e}; valid settings: {}",
                    s.id,
                    train_setting_names().join(", ")
                ))
            })?;
        }
        if sc.trained_kinds().contains(&ModelKind::Bilinear) {
            if let Some(s) = sc.sims.iter().zip(infos).find(|(_, i)| i.nu() == 0) {
                return Err(Error::Config(format!(
                    "[train].model: a bilinear model cannot be trained for simulator '{}': it has \
                     no inputs (nu = 0), and the bilinear terms Σ u_i N_i z need them (use \
                     koopman, edmd or nndm)",
                    s.0.id
                )));
            }
        }
        let ctrl =
            |id: &str| sc.train_config_of(id).get("ctrl") == Some(&serde_json::Value::Bool(true));
        if let Some(s) = sc
            .sims
            .iter()
            .zip(infos)
            .find(|(s, i)| i.nu() == 0 && ctrl(&s.id))
        {
            return Err(Error::Config(format!(
                "[train].config sets ctrl = true, but simulator '{}': {}",
                s.0.id,
                koopman::train::AUTONOMOUS_CTRL
            )));
        }
    }
    for ctrl in &sc.control {
        let j = controlled_sim(sc, ctrl);
        validate_control(ctrl, &sc.sims[j].id, infos[j])?;
        if ctrl.model.is_none() && sc.trained_kinds().contains(&ModelKind::Nndm) {
            shooting_accepts(ctrl, infos[j]).map_err(|e| {
                Error::Config(format!(
                    "[control].mpc for simulator '{}' with model kind 'nndm' ([train].model): {e}",
                    sc.sims[j].id
                ))
            })?;
        }
        if let Some(o) = &ctrl.offset_free {
            let at = |m: String| {
                Error::Config(format!(
                    "[control].offset_free for simulator '{}': {m}",
                    sc.sims[j].id
                ))
            };
            check_offset_free(o, ctrl.feedforward_file.is_some(), infos[j].nx()).map_err(at)?;
        }
        // A file that exists already is checked now; one a hook writes, when control starts.
        let existing = |f: &Option<String>| {
            let f = f.as_deref().filter(|f| !f.contains("{out}"))?;
            let p = std::path::Path::new(f);
            let p = match &sc.base_dir {
                Some(b) if p.is_relative() => b.join(p),
                _ => p.to_path_buf(),
            };
            p.is_file().then_some(p)
        };
        let at =
            |e: Error| Error::Config(format!("[control] for simulator '{}': {e}", sc.sims[j].id));
        if let Some(p) = existing(&ctrl.reference_file) {
            load_trajectory(&p, infos[j].nx()).map_err(at)?;
        }
        if let Some(p) = existing(&ctrl.feedforward_file) {
            load_feedforward(&p, infos[j].nu()).map_err(at)?;
        }
    }
    for t in &sc.tracks {
        let j = sc.tracked_index(t);
        let (id, info) = (&sc.sims[j].id, infos[j]);
        t.check_states(info.nx(), id)?;
        if info.nu() == 0 {
            return Err(Error::Config(format!(
                "[control] for simulator '{id}': no inputs to control: {AUTONOMOUS_MPC}"
            )));
        }
        mpc_config(info, &t.mpc)
            .map_err(|e| Error::Config(format!("[control] for simulator '{id}': {e}")))?;
        if let Some(o) = &t.offset_free {
            check_offset_free(o, t.error_state, info.nx()).map_err(|m| {
                Error::Config(format!("[control].offset_free for simulator '{id}': {m}"))
            })?;
        }
        // A references file that exists already is checked now; one a hook writes, when
        // control starts.
        if !t.references.contains("{out}") {
            let p = std::path::Path::new(&t.references);
            let p = match &sc.base_dir {
                Some(b) if p.is_relative() => b.join(p),
                _ => p.to_path_buf(),
            };
            if p.is_file() {
                super::reference_set::ReferenceSet::load(&p, info.nx(), info.nu())?;
            }
        }
    }
    Ok(())
}

/// An offset-free correction's settings against the state dimension; about a plan (the
/// error-state MPC) the `disturbance` mode only.
fn check_offset_free(
    o: &koopman::mpc::OffsetFreeConfig,
    about_plan: bool,
    nx: usize,
) -> std::result::Result<(), String> {
    if about_plan && o.mode != koopman::mpc::OffsetMode::Disturbance {
        return Err(format!(
            "the error-state MPC (a feed-forward) takes the mode \"disturbance\" only, got {:?}",
            o.mode
        ));
    }
    o.check(nx).map_err(|e| e.to_string())
}

/// The names of every `TrainConfig` field (what `[train].config` may set).
pub fn train_setting_names() -> Vec<String> {
    serde_json::to_value(TrainConfig::default())
        .ok()
        .and_then(|v| v.as_object().map(|o| o.keys().cloned().collect()))
        .unwrap_or_default()
}

/// Whether the MPC service's controller for an NNDM (random shooting, which honours the horizon,
/// `q` and the input bounds only) accepts `ctrl`'s settings: the service's own constructor
/// ([`LoadedModel::controller`]) on a stand-in NNDM of the simulator's dimensions.
fn shooting_accepts(ctrl: &ControlSpec, info: &SimInfo) -> Result<()> {
    use koopman::model::nndm::{init_params, NndmArch, NndmModel};
    let cfg = mpc_config(info, &ctrl.mpc)?;
    let arch = NndmArch::new(info.nx(), info.nu(), &[4])?;
    let params = init_params(&arch, &mut koopman::rng::Rng::new(1))?;
    let model = LoadedModel::OneStep(std::sync::Arc::new(NndmModel::from_params(arch, params)?));
    model.controller(&cfg, ctrl.offset_free.as_ref())?;
    Ok(())
}

fn validate_control(ctrl: &ControlSpec, sim: &str, info: &SimInfo) -> Result<()> {
    let (nx, nu) = (info.nx(), info.nu());
    let bad = |m: String| {
        Err(Error::Config(format!(
            "[control] for simulator '{sim}': {m}"
        )))
    };
    if ctrl.x0.len() != nx {
        return bad(format!(
            "x0 has {} values, the simulator has {nx} states ({})",
            ctrl.x0.len(),
            info.state_names.join(", ")
        ));
    }
    let cfg = mpc_config(info, &ctrl.mpc)?;
    let h = cfg.horizon;
    let reference = ctrl.reference.as_deref().unwrap_or_default();
    if ctrl.reference.is_some() && reference.len() != nx && reference.len() != h * nx {
        return bad(format!(
            "reference has {} values; expected {nx} (one state) or {} (horizon {h} × {nx})",
            reference.len(),
            h * nx
        ));
    }
    if let Some(v) = ctrl.x0.iter().chain(reference).find(|v| !v.is_finite()) {
        return bad(format!("x0 and reference must be finite, got {v}"));
    }
    if nu == 0 {
        return bad(format!("no inputs to control: {AUTONOMOUS_MPC}"));
    }
    if nx == 0 {
        return bad("MPC needs states (nx = 0)".into());
    }
    if let Some(pl) = &ctrl.position_loop {
        if let Err(e) = position_loop_of(pl, info, &cfg) {
            return bad(e);
        }
    }
    if let Some(i) = ctrl
        .observation_noise
        .iter()
        .flat_map(|n| &n.states)
        .find(|&&i| i >= nx)
    {
        return bad(format!(
            "observation_noise.states: {i} is not a state (the simulator has {nx})"
        ));
    }
    // The real controller is built by the MPC service from the trained model after training;
    // the same settings on a stand-in model of the same dimensions fail the same way now.
    let model = stand_in::build(StandIn::Dimensions { nx, nu })
        .map_err(Error::from)?
        .into_lifted();
    // The LQR law uses the MPC's weights and bounds: checked as the MPC's (its Riccati
    // iteration needs the trained model's (A, B), at `configure`).
    let as_mpc = koopman::mpc::MpcConfig {
        law: koopman::mpc::ControlLaw::Mpc,
        ..cfg
    };
    MpcController::new(model.as_ref(), &as_mpc)
        .map(|_| ())
        .map_err(|e| Error::Config(format!("[control].mpc: {e}")))
}
