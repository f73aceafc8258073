//! The FMU's variables, one table for the binary and for `modelDescription.xml`: value
//! references, names, causality, variability, start values, ranges and descriptions.
//!
//! Value references: 0 `time` (FMI 3's independent variable; absent from FMI 2), then the
//! measured state (nx inputs), the reference (nx inputs), the command (nu outputs), the solve
//! status (an integer output), and the parameters: the diagonal of Q (nx), of R (nu), the input
//! bounds (nu + nu) and the horizon (an integer).

use koopman::mpc::MpcConfig;

use crate::settings::{ControllerFile, MAX_HORIZON};

/// What a variable is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// Simulation time (FMI 3's independent variable).
    Time,
    /// Component i of the measured state (input).
    State(usize),
    /// Component i of the reference (input).
    Reference(usize),
    /// Component i of the command (output, held over the step).
    Command(usize),
    /// How the last command was obtained (integer output, [`status_code`]).
    Status,
    /// Diagonal entry i of the state weight Q (parameter).
    Q(usize),
    /// Diagonal entry i of the input weight R (parameter).
    R(usize),
    /// Lower bound of input i (parameter).
    UMin(usize),
    /// Upper bound of input i (parameter).
    UMax(usize),
    /// The horizon H (integer parameter).
    Horizon,
}

/// A variable's FMI causality.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Causality {
    /// `independent` (time).
    Independent,
    /// `input`.
    Input,
    /// `output`.
    Output,
    /// `parameter`.
    Parameter,
}

/// One variable of the FMU.
#[derive(Clone, Debug, PartialEq)]
pub struct Variable {
    /// Name in the model description.
    pub name: String,
    /// Value reference.
    pub vr: u32,
    /// What it is.
    pub role: Role,
    /// True for an integer (`Int32` / `Integer`), false for a real (`Float64` / `Real`).
    pub integer: bool,
    /// Causality.
    pub causality: Causality,
    /// Start value (`None`: calculated, no start attribute).
    pub start: Option<f64>,
    /// Smallest allowed value (`None`: none).
    pub min: Option<f64>,
    /// Largest allowed value.
    pub max: Option<f64>,
    /// Unit (declared in the model description's unit definitions).
    pub unit: Option<String>,
    /// Human-readable description.
    pub description: String,
}

/// The FMU's variables in value-reference order (`variables[vr]`).
#[derive(Clone, Debug, PartialEq)]
pub struct Layout {
    /// State dimension.
    pub nx: usize,
    /// Input dimension.
    pub nu: usize,
    /// Every variable; `variables[i].vr == i`.
    pub variables: Vec<Variable>,
}

/// The integer the `mpc_status` output takes for each plan status: 0 solved, 1 inaccurate,
/// 2 suboptimal, 3 fallback; −1 before the first step.
pub fn status_code(s: koopman::mpc::PlanStatus) -> i32 {
    use koopman::mpc::PlanStatus::*;
    match s {
        Solved => 0,
        Inaccurate => 1,
        Suboptimal => 2,
        Fallback => 3,
    }
}

/// The effective diagonal of Q, of R and the bounds of `cfg` for a model with `nx`, `nu`
/// (SPEC defaults: Q = I, R = 0, no bounds = ±∞).
pub fn effective(cfg: &MpcConfig, nx: usize, nu: usize) -> [Vec<f64>; 4] {
    [
        cfg.q.clone().unwrap_or_else(|| vec![1.0; nx]),
        cfg.r.clone().unwrap_or_else(|| vec![0.0; nu]),
        cfg.u_min
            .clone()
            .unwrap_or_else(|| vec![f64::NEG_INFINITY; nu]),
        cfg.u_max.clone().unwrap_or_else(|| vec![f64::INFINITY; nu]),
    ]
}

impl Layout {
    /// The variables of the controller `file` describes (its names, units, reference and MPC
    /// settings as start values).
    ///
    /// Errors: two variables with the same name, settings of the wrong length.
    pub fn new(file: &ControllerFile) -> Result<Self, String> {
        let (nx, nu) = (file.state_names.len(), file.input_names.len());
        let [q, r, lo, hi] = effective(&file.mpc, nx, nu);
        for (what, v, n) in [
            ("q", &q, nx),
            ("r", &r, nu),
            ("u_min", &lo, nu),
            ("u_max", &hi, nu),
        ] {
            if v.len() != n {
                return Err(format!(
                    "mpc.{what}: {} values, the model needs {n}",
                    v.len()
                ));
            }
        }
        let mut vars: Vec<Variable> = Vec::new();
        let mut push = |name: String,
                        role,
                        integer,
                        causality,
                        start,
                        unit: Option<String>,
                        description: String| {
            let vr = vars.len() as u32;
            vars.push(Variable {
                name,
                vr,
                role,
                integer,
                causality,
                start,
                min: None,
                max: None,
                unit,
                description,
            });
        };
        push(
            "time".into(),
            Role::Time,
            false,
            Causality::Independent,
            None,
            Some("s".into()),
            "simulation time".into(),
        );
        for (i, s) in file.state_names.iter().enumerate() {
            push(
                s.clone(),
                Role::State(i),
                false,
                Causality::Input,
                Some(0.0),
                file.state_units[i].clone(),
                format!(
                    "measured state '{s}' at the start of the communication step (must be finite)"
                ),
            );
        }
        for (i, s) in file.state_names.iter().enumerate() {
            push(
                format!("{s}_ref"),
                Role::Reference(i),
                false,
                Causality::Input,
                Some(file.reference[i]),
                file.state_units[i].clone(),
                format!("reference for '{s}' (held over the horizon)"),
            );
        }
        for (i, u) in file.input_names.iter().enumerate() {
            push(u.clone(), Role::Command(i), false, Causality::Output, None, file.input_units[i].clone(),
                format!("command '{u}': the first input of the MPC plan solved at the last doStep, held over the step"));
        }
        push("mpc_status".into(), Role::Status, true, Causality::Output, None, None,
            "how the last command was obtained: 0 solved, 1 inaccurate, 2 suboptimal, 3 fallback (shifted previous plan), -1 before the first step".into());
        for (i, s) in file.state_names.iter().enumerate() {
            push(
                format!("q_{s}"),
                Role::Q(i),
                false,
                Causality::Parameter,
                Some(q[i]),
                None,
                format!("diagonal weight of '{s}' in Q (fixed: changes the condensed Hessian)"),
            );
        }
        for (i, u) in file.input_names.iter().enumerate() {
            push(
                format!("r_{u}"),
                Role::R(i),
                false,
                Causality::Parameter,
                Some(r[i]),
                None,
                format!("diagonal weight of '{u}' in R (fixed: changes the condensed Hessian)"),
            );
        }
        for (i, u) in file.input_names.iter().enumerate() {
            push(
                format!("u_min_{u}"),
                Role::UMin(i),
                false,
                Causality::Parameter,
                Some(lo[i]),
                file.input_units[i].clone(),
                format!(
                    "lower bound of '{u}' (fixed: the box solver is built with it; may be -INF)"
                ),
            );
        }
        for (i, u) in file.input_names.iter().enumerate() {
            push(
                format!("u_max_{u}"),
                Role::UMax(i),
                false,
                Causality::Parameter,
                Some(hi[i]),
                file.input_units[i].clone(),
                format!(
                    "upper bound of '{u}' (fixed: the box solver is built with it; may be INF)"
                ),
            );
        }
        push(
            "horizon".into(),
            Role::Horizon,
            true,
            Causality::Parameter,
            Some(file.mpc.horizon as f64),
            None,
            "MPC horizon H, planned inputs (fixed: sets the size of the QP)".into(),
        );
        for v in &mut vars {
            match v.role {
                Role::Q(_) | Role::R(_) => v.min = Some(0.0),
                Role::Horizon => {
                    v.min = Some(1.0);
                    v.max = Some(MAX_HORIZON as f64);
                }
                _ => {}
            }
        }
        for (i, a) in vars.iter().enumerate() {
            if vars[..i].iter().any(|b| b.name == a.name) {
                return Err(format!(
                    "two variables are named '{}' (rename a state or an input)",
                    a.name
                ));
            }
        }
        Ok(Layout {
            nx,
            nu,
            variables: vars,
        })
    }

    /// The variable with value reference `vr`, if any.
    pub fn get(&self, vr: u32) -> Option<&Variable> {
        self.variables.get(vr as usize)
    }

    /// The value reference of the variable named `name`.
    pub fn vr(&self, name: &str) -> Option<u32> {
        self.variables.iter().find(|v| v.name == name).map(|v| v.vr)
    }

    /// Value references of the variables with `role` matching `pick`, in order.
    pub fn vrs(&self, pick: impl Fn(Role) -> bool) -> Vec<u32> {
        self.variables
            .iter()
            .filter(|v| pick(v.role))
            .map(|v| v.vr)
            .collect()
    }
}
