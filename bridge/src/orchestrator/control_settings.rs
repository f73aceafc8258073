//! A `[control]` entry resolved against its simulator's `info` — the simulator it drives, its MPC
//! settings and its position loop — as both the validation before collection and the control
//! phase need it.

use koopman::mpc::MpcConfig;

use super::position_loop::PositionLoop;
use crate::error::{Error, Result};
use crate::messages::SimInfo;
use crate::scenario::{ControlSpec, PositionLoopSpec, Scenario};

/// The MPC settings of a scenario's `[control].mpc` for a simulator: SPEC defaults with the
/// simulator's input bounds, overlaid with the scenario's fields (unknown fields are an error),
/// then the input bounds intersected with the simulator's (it cannot take more).
pub fn mpc_config(
    info: &SimInfo,
    overrides: &serde_json::Map<String, serde_json::Value>,
) -> Result<MpcConfig> {
    let mut v =
        serde_json::to_value(MpcConfig::default()).map_err(|e| Error::Config(e.to_string()))?;
    if let Some(o) = v.as_object_mut() {
        for (k, val) in overrides {
            o.insert(k.clone(), val.clone());
        }
    }
    let mut cfg: MpcConfig =
        serde_json::from_value(v).map_err(|e| Error::Config(format!("[control].mpc: {e}")))?;
    crate::services::mpc::clamp_bounds_to_sim(&mut cfg, info)
        .map_err(|e| Error::Config(format!("[control].mpc: {e}")))?;
    Ok(cfg)
}

/// The index in `sc.sims` of the simulator a control entry drives (`sim`, else the first).
pub fn controlled_sim(sc: &Scenario, ctrl: &ControlSpec) -> usize {
    sc.controlled_index(ctrl)
}

/// The position loop of a control entry, its inputs clipped to the MPC's bounds (the scenario's
/// intersected with the simulator's); the error says what does not fit.
pub fn position_loop_of(
    spec: &PositionLoopSpec,
    info: &SimInfo,
    mpc: &MpcConfig,
) -> std::result::Result<PositionLoop, String> {
    PositionLoop::new(
        spec,
        info.nx(),
        info.nu(),
        mpc.u_min.as_deref(),
        mpc.u_max.as_deref(),
    )
}
