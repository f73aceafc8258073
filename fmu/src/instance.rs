//! One FMU instance, independent of the FMI version: its state machine (instantiated →
//! initialisation → step → terminated, or error), its variables, and `do_step`, which plans
//! with `koopman::mpc::ModelController` (the MPC service's code path) and holds the command.

use std::path::Path;

use koopman::mpc::{LoadedModel, ModelController};

use crate::layout::{effective, status_code, Layout, Role};
use crate::settings::{ControllerFile, MAX_HORIZON};

/// An FMI status (the values of `fmi3Status` and `fmi2Status` coincide up to `Fatal`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
#[repr(i32)]
pub enum Status {
    /// All well.
    Ok = 0,
    /// Something to know, the call did its work.
    Warning = 1,
    /// The call's result is not usable (not used here).
    Discard = 2,
    /// The call failed; the instance accepts only reset, free and getters for debugging.
    Error = 3,
    /// The instance is unusable.
    Fatal = 4,
}

/// A failed call: its status and the message that is logged.
#[derive(Clone, Debug, PartialEq)]
pub struct Failure {
    /// `Error` (or `Fatal`).
    pub status: Status,
    /// What went wrong, for the log.
    pub message: String,
}

impl Failure {
    /// An `Error` with `message`.
    pub fn error(message: impl Into<String>) -> Self {
        Failure {
            status: Status::Error,
            message: message.into(),
        }
    }
}

/// Where the instance is in the FMI state machine.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// After instantiate (or reset): parameters and inputs may be set.
    Instantiated,
    /// Initialisation mode.
    Initialization,
    /// Step mode: `do_step` plans; inputs may be set, fixed parameters not.
    Step,
    /// After terminate: getters only.
    Terminated,
    /// After an error: getters, reset and free only.
    Error,
}

/// A controller FMU instance.
pub struct Instance {
    /// The variables.
    pub layout: Layout,
    file: ControllerFile,
    model: LoadedModel,
    controller: Option<ModelController>,
    mode: Mode,
    values: Vec<f64>,
    /// Communication points stepped so far.
    pub steps: u64,
    warned_step: bool,
}

impl Instance {
    /// Loads `resources/controller.json` and the model in `resources/model/`; checks that the
    /// controller file was written for `token` (when given) and fits the model.
    ///
    /// Errors: a message naming the missing or malformed file.
    pub fn new(resources: &Path, token: Option<&str>) -> Result<Self, String> {
        let file = ControllerFile::read(resources)?;
        if let Some(t) = token {
            if t != file.token {
                return Err(format!(
                    "instantiation token {t} does not match this FMU's resources ({})",
                    file.token
                ));
            }
        }
        let model_dir = ControllerFile::model_dir(resources);
        let model = LoadedModel::load(&model_dir)
            .map_err(|e| format!("cannot load the model in {}: {e}", model_dir.display()))?;
        file.check(model.nx(), model.nu())?;
        let layout = Layout::new(&file)?;
        let mut inst = Instance {
            layout,
            file,
            model,
            controller: None,
            mode: Mode::Instantiated,
            values: Vec::new(),
            steps: 0,
            warned_step: false,
        };
        inst.reset();
        Ok(inst)
    }

    /// The current mode.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// The model's sampling period (the communication step the model was trained for).
    pub fn dt(&self) -> f64 {
        self.file.dt
    }

    /// Back to the instantiated state with the start values (the model stays loaded).
    pub fn reset(&mut self) {
        self.values = self
            .layout
            .variables
            .iter()
            .map(|v| v.start.unwrap_or(0.0))
            .collect();
        self.controller = None;
        self.mode = Mode::Instantiated;
        self.steps = 0;
        self.warned_step = false;
        let lo_hi = self.bounds();
        for i in 0..self.layout.nu {
            let (lo, hi) = (lo_hi.0[i], lo_hi.1[i]);
            let vr = self.cmd_vr(i);
            self.values[vr] = 0.0f64.max(lo).min(hi);
        }
        let s = self.layout.vr("mpc_status").unwrap_or(0) as usize;
        self.values[s] = -1.0;
    }

    fn cmd_vr(&self, i: usize) -> usize {
        self.layout.vrs(|r| r == Role::Command(i))[0] as usize
    }

    fn by_role(&self, pick: impl Fn(Role) -> bool) -> Vec<f64> {
        self.layout
            .variables
            .iter()
            .filter(|v| pick(v.role))
            .map(|v| self.values[v.vr as usize])
            .collect()
    }

    fn bounds(&self) -> (Vec<f64>, Vec<f64>) {
        (
            self.by_role(|r| matches!(r, Role::UMin(_))),
            self.by_role(|r| matches!(r, Role::UMax(_))),
        )
    }

    /// Marks the instance failed and returns the failure.
    fn fail(&mut self, message: String) -> Failure {
        self.mode = Mode::Error;
        Failure::error(message)
    }

    /// Reads variable `vr` (a real or an integer, as f64).
    pub fn get(&self, vr: u32) -> Result<f64, Failure> {
        let v = self
            .layout
            .get(vr)
            .ok_or_else(|| Failure::error(format!("no variable has value reference {vr}")))?;
        Ok(self.values[v.vr as usize])
    }

    /// True if `vr` is an integer variable (false for a real, `None` if there is none).
    pub fn is_integer(&self, vr: u32) -> Option<bool> {
        self.layout.get(vr).map(|v| v.integer)
    }

    /// Sets variable `vr`: inputs in every mode before termination, fixed parameters before
    /// the end of initialisation; values are checked against their range (a non-finite state
    /// or reference, a negative weight, a NaN bound, a horizon outside 1..=MAX are errors).
    pub fn set(&mut self, vr: u32, value: f64) -> Result<(), Failure> {
        let Some(var) = self.layout.get(vr).cloned() else {
            return Err(self.fail(format!("no variable has value reference {vr}")));
        };
        let name = &var.name;
        match (self.mode, var.role) {
            (Mode::Error, _) => {
                return Err(Failure::error(format!(
                    "cannot set '{name}': the instance failed earlier (reset or free it)"
                )))
            }
            (Mode::Terminated, _) => {
                return Err(self.fail(format!("cannot set '{name}' after terminate")));
            }
            (_, Role::Time | Role::Command(_) | Role::Status) => {
                return Err(self.fail(format!("'{name}' is not settable (it is computed)")));
            }
            (
                Mode::Step,
                Role::Q(_) | Role::R(_) | Role::UMin(_) | Role::UMax(_) | Role::Horizon,
            ) => {
                return Err(self.fail(format!(
                    "parameter '{name}' is fixed: set it before exitInitializationMode (it needs a rebuild of the controller)"
                )));
            }
            _ => {}
        }
        let bad = match var.role {
            Role::State(_) | Role::Reference(_) => (!value.is_finite())
                .then(|| format!("'{name}' = {value}: a measured state and a reference must be finite")),
            Role::Q(_) | Role::R(_) => (!(value.is_finite() && value >= 0.0))
                .then(|| format!("parameter '{name}' = {value} is out of range: a weight must be finite and >= 0")),
            Role::UMin(_) | Role::UMax(_) => value
                .is_nan()
                .then(|| format!("parameter '{name}' = NaN: a bound must be a number (or +-INF)")),
            Role::Horizon => (!(value >= 1.0 && value <= MAX_HORIZON as f64 && value.fract() == 0.0))
                .then(|| format!("parameter 'horizon' = {value} is out of range 1..={MAX_HORIZON}")),
            _ => None,
        };
        if let Some(message) = bad {
            return Err(self.fail(message));
        }
        self.values[vr as usize] = value;
        Ok(())
    }

    /// Instantiated → initialisation mode.
    pub fn enter_initialization(&mut self) -> Result<(), Failure> {
        if self.mode != Mode::Instantiated {
            let m = self.mode;
            return Err(self.fail(format!("enterInitializationMode in mode {m:?}")));
        }
        self.mode = Mode::Initialization;
        Ok(())
    }

    /// Initialisation → step mode: builds the controller with the parameters as set (the
    /// MPC file's settings where they were left at their start values).
    pub fn exit_initialization(&mut self) -> Result<(), Failure> {
        if self.mode != Mode::Initialization {
            let m = self.mode;
            return Err(self.fail(format!("exitInitializationMode in mode {m:?}")));
        }
        let cfg = self.config();
        let (lo, hi) = self.bounds();
        if let Some(i) = (0..lo.len()).find(|&i| lo[i] > hi[i]) {
            let u = &self.file.input_names[i];
            return Err(self.fail(format!(
                "parameters u_min_{u} = {} > u_max_{u} = {}: the bounds are out of range",
                lo[i], hi[i]
            )));
        }
        match self.model.controller(&cfg, self.file.offset_free.as_ref()) {
            Ok(c) => self.controller = Some(c),
            Err(e) => return Err(self.fail(format!("the MPC cannot be built: {e}"))),
        }
        self.mode = Mode::Step;
        Ok(())
    }

    /// The MPC settings of the file with the parameters' current values; a parameter still at
    /// the file's effective value leaves the file's setting untouched (so an unchanged FMU
    /// builds exactly the service's controller).
    pub fn config(&self) -> koopman::mpc::MpcConfig {
        let (nx, nu) = (self.layout.nx, self.layout.nu);
        let mut cfg = self.file.mpc.clone();
        let [q0, r0, lo0, hi0] = effective(&cfg, nx, nu);
        let pick = |now: Vec<f64>, was: Vec<f64>, field: &Option<Vec<f64>>| {
            if now == was {
                field.clone()
            } else {
                Some(now)
            }
        };
        cfg.q = pick(self.by_role(|r| matches!(r, Role::Q(_))), q0, &cfg.q);
        cfg.r = pick(self.by_role(|r| matches!(r, Role::R(_))), r0, &cfg.r);
        let (lo, hi) = self.bounds();
        cfg.u_min = pick(lo, lo0, &cfg.u_min);
        cfg.u_max = pick(hi, hi0, &cfg.u_max);
        cfg.horizon = self.by_role(|r| r == Role::Horizon)[0] as usize;
        cfg
    }

    /// Solves the MPC for the measured state and reference as set, and holds the plan's first
    /// input as the command over `[t, t + h)`. Returns `Warning` (once) when `h` is not the
    /// model's sampling period.
    pub fn do_step(&mut self, t: f64, h: f64) -> Result<Status, Failure> {
        if self.mode != Mode::Step {
            let m = self.mode;
            return Err(self.fail(format!("doStep in mode {m:?} (exit initialisation first)")));
        }
        if !(h > 0.0 && h.is_finite() && t.is_finite()) {
            return Err(self.fail(format!(
                "doStep: communication step size {h} at t = {t}: must be > 0 and finite"
            )));
        }
        let x = self.by_role(|r| matches!(r, Role::State(_)));
        let reference = self.by_role(|r| matches!(r, Role::Reference(_)));
        let plan = match self.controller.as_mut().map(|c| c.solve(&x, &reference)) {
            Some(Ok(p)) => p,
            Some(Err(e)) => {
                return Err(self.fail(format!("doStep at t = {t}: the MPC failed: {e}")))
            }
            None => return Err(self.fail("doStep: no controller".into())),
        };
        for i in 0..self.layout.nu {
            let vr = self.cmd_vr(i);
            self.values[vr] = plan.u[i];
        }
        let s = self.layout.vr("mpc_status").unwrap_or(0) as usize;
        self.values[s] = status_code(plan.status) as f64;
        self.values[0] = t + h;
        self.steps += 1;
        let dt = self.file.dt;
        if !self.warned_step && (h - dt).abs() > 1e-9 * dt.max(1.0) {
            self.warned_step = true;
            return Ok(Status::Warning);
        }
        Ok(Status::Ok)
    }

    /// The message of the warning `do_step` returned.
    pub fn step_warning(&self, h: f64) -> String {
        format!(
            "doStep: communication step {h} s differs from the model's sampling period {} s; the MPC predicts with the model's step (warned once)",
            self.file.dt
        )
    }

    /// Step or initialisation mode → terminated.
    pub fn terminate(&mut self) -> Result<(), Failure> {
        match self.mode {
            Mode::Step | Mode::Initialization => {
                self.mode = Mode::Terminated;
                Ok(())
            }
            m => Err(self.fail(format!("terminate in mode {m:?}"))),
        }
    }

    /// Sets the time at the start of initialisation.
    pub fn set_start_time(&mut self, t: f64) {
        self.values[0] = t;
    }
}
