//! The FMI 3.0 C API (co-simulation) over [`crate::instance::Instance`]: the FMI 3 C types and
//! every function a master may look up. Functions of interfaces the FMU does not declare
//! (model exchange, scheduled execution, event mode, clocks, FMU state, derivatives) log why and
//! return `fmi3Error`.
#![allow(non_snake_case)]

use std::ffi::{c_char, c_void};

use crate::ffi::{self, c_string, call, Handle, Logger};
use crate::instance::{Failure, Status};

/// `fmi3Instance`.
pub type Fmi3Instance = *mut c_void;
/// `fmi3Status` (an enum: OK, Warning, Discard, Error, Fatal).
pub type Fmi3Status = i32;
/// `fmi3ValueReference`.
pub type Fmi3ValueReference = u32;
/// `fmi3Boolean` (C99 `bool`).
pub type Fmi3Boolean = bool;
/// `fmi3String`.
pub type Fmi3String = *const c_char;
/// `fmi3FMUState`.
pub type Fmi3FmuState = *mut c_void;
/// `fmi3LogMessageCallback`.
pub type Fmi3LogMessage = Option<
    unsafe extern "C" fn(
        env: *mut c_void,
        status: Fmi3Status,
        category: Fmi3String,
        message: Fmi3String,
    ),
>;
/// `fmi3IntermediateUpdateCallback` (never called: no intermediate updates).
pub type Fmi3IntermediateUpdate = Option<unsafe extern "C" fn()>;

/// The FMI 3 logger of an instance.
pub struct Log3 {
    env: *mut c_void,
    cb: Fmi3LogMessage,
}

impl Logger for Log3 {
    fn log(&self, _name: &str, status: Status, category: &str, message: &str) {
        if let Some(cb) = self.cb {
            let (c, m) = (c_string(category), c_string(message));
            // SAFETY: the master's callback, with the environment it gave at instantiation.
            unsafe { cb(self.env, status as i32, c.as_ptr(), m.as_ptr()) };
        }
    }
}

type H = Handle<Log3>;

/// `fmi3GetVersion`: "3.0".
#[no_mangle]
pub extern "C" fn fmi3GetVersion() -> *const c_char {
    c"3.0".as_ptr()
}

/// `fmi3SetDebugLogging`: info messages on or off (warnings and errors are always logged).
///
/// # Safety
/// `instance` comes from `fmi3InstantiateCoSimulation`.
#[no_mangle]
pub unsafe extern "C" fn fmi3SetDebugLogging(
    instance: Fmi3Instance,
    logging_on: Fmi3Boolean,
    _n_categories: usize,
    _categories: *const Fmi3String,
) -> Fmi3Status {
    call(instance as *mut H, "fmi3SetDebugLogging", |h| {
        h.logging_on = logging_on;
        Ok(Status::Ok)
    })
}

/// `fmi3InstantiateCoSimulation`: loads `resources/controller.json` and the model from
/// `resourcePath`; NULL (with a logged message naming the missing file) on failure.
///
/// # Safety
/// The strings are NULL or NUL-terminated; `log_message` is NULL or a valid callback.
#[no_mangle]
pub unsafe extern "C" fn fmi3InstantiateCoSimulation(
    instance_name: Fmi3String,
    instantiation_token: Fmi3String,
    resource_path: Fmi3String,
    _visible: Fmi3Boolean,
    logging_on: Fmi3Boolean,
    event_mode_used: Fmi3Boolean,
    _early_return_allowed: Fmi3Boolean,
    _required_intermediate_variables: *const Fmi3ValueReference,
    _n_required_intermediate_variables: usize,
    instance_environment: *mut c_void,
    log_message: Fmi3LogMessage,
    _intermediate_update: Fmi3IntermediateUpdate,
) -> Fmi3Instance {
    let logger = Log3 {
        env: instance_environment,
        cb: log_message,
    };
    let name = ffi::string(instance_name).unwrap_or_else(|| "controller".into());
    ffi::instantiate(
        "fmi3InstantiateCoSimulation",
        name,
        logger,
        logging_on,
        || {
            if event_mode_used {
                return Err(
                    "event mode is not supported by this FMU (hasEventMode = false)".to_string(),
                );
            }
            ffi::load(
                ffi::string(resource_path),
                "no resource path: the model and controller.json travel in resources/",
                ffi::string(instantiation_token),
            )
        },
    )
}

/// `fmi3FreeInstance`.
///
/// # Safety
/// `instance` comes from `fmi3InstantiateCoSimulation` and is not used afterwards.
#[no_mangle]
pub unsafe extern "C" fn fmi3FreeInstance(instance: Fmi3Instance) {
    ffi::free(instance as *mut H);
}

/// `fmi3EnterInitializationMode`.
///
/// # Safety
/// `instance` comes from `fmi3InstantiateCoSimulation`.
#[no_mangle]
pub unsafe extern "C" fn fmi3EnterInitializationMode(
    instance: Fmi3Instance,
    _tolerance_defined: Fmi3Boolean,
    _tolerance: f64,
    start_time: f64,
    _stop_time_defined: Fmi3Boolean,
    _stop_time: f64,
) -> Fmi3Status {
    call(instance as *mut H, "fmi3EnterInitializationMode", |h| {
        h.inst.enter_initialization()?;
        h.inst.set_start_time(start_time);
        Ok(Status::Ok)
    })
}

/// `fmi3ExitInitializationMode`: builds the MPC with the parameters as set.
///
/// # Safety
/// `instance` comes from `fmi3InstantiateCoSimulation`.
#[no_mangle]
pub unsafe extern "C" fn fmi3ExitInitializationMode(instance: Fmi3Instance) -> Fmi3Status {
    call(instance as *mut H, "fmi3ExitInitializationMode", |h| {
        h.inst.exit_initialization().map(|_| Status::Ok)
    })
}

/// `fmi3DoStep`: solves the MPC for the inputs as set and holds the command over the step.
///
/// # Safety
/// `instance` comes from `fmi3InstantiateCoSimulation`; the out-pointers are NULL or valid.
#[no_mangle]
pub unsafe extern "C" fn fmi3DoStep(
    instance: Fmi3Instance,
    current_communication_point: f64,
    communication_step_size: f64,
    _no_set_fmu_state_prior_to_current_point: Fmi3Boolean,
    event_handling_needed: *mut Fmi3Boolean,
    terminate_simulation: *mut Fmi3Boolean,
    early_return: *mut Fmi3Boolean,
    last_successful_time: *mut f64,
) -> Fmi3Status {
    for p in [event_handling_needed, terminate_simulation, early_return] {
        if !p.is_null() {
            *p = false;
        }
    }
    if !last_successful_time.is_null() {
        *last_successful_time = current_communication_point;
    }
    call(instance as *mut H, "fmi3DoStep", |h| {
        let s = h.do_step(current_communication_point, communication_step_size)?;
        if !last_successful_time.is_null() {
            *last_successful_time = current_communication_point + communication_step_size;
        }
        Ok(s)
    })
}

/// `fmi3Terminate`.
///
/// # Safety
/// `instance` comes from `fmi3InstantiateCoSimulation`.
#[no_mangle]
pub unsafe extern "C" fn fmi3Terminate(instance: Fmi3Instance) -> Fmi3Status {
    call(instance as *mut H, "fmi3Terminate", |h| {
        h.inst.terminate().map(|_| Status::Ok)
    })
}

/// `fmi3Reset`: back to the instantiated state with the start values.
///
/// # Safety
/// `instance` comes from `fmi3InstantiateCoSimulation`.
#[no_mangle]
pub unsafe extern "C" fn fmi3Reset(instance: Fmi3Instance) -> Fmi3Status {
    call(instance as *mut H, "fmi3Reset", |h| {
        h.inst.reset();
        Ok(Status::Ok)
    })
}

/// `fmi3GetFloat64`.
///
/// # Safety
/// `instance` comes from `fmi3InstantiateCoSimulation`; the arrays hold `n` elements.
#[no_mangle]
pub unsafe extern "C" fn fmi3GetFloat64(
    instance: Fmi3Instance,
    vrs: *const Fmi3ValueReference,
    n_vrs: usize,
    values: *mut f64,
    n_values: usize,
) -> Fmi3Status {
    call(instance as *mut H, "fmi3GetFloat64", |h| {
        same_length(n_vrs, n_values)?;
        ffi::get_many(&h.inst, vrs, n_vrs, values, false, |v| v)
    })
}

/// `fmi3SetFloat64`: inputs at any time before terminate, parameters before the end of
/// initialisation; out-of-range values (a NaN or infinite state) are `fmi3Error`.
///
/// # Safety
/// `instance` comes from `fmi3InstantiateCoSimulation`; the arrays hold `n` elements.
#[no_mangle]
pub unsafe extern "C" fn fmi3SetFloat64(
    instance: Fmi3Instance,
    vrs: *const Fmi3ValueReference,
    n_vrs: usize,
    values: *const f64,
    n_values: usize,
) -> Fmi3Status {
    call(instance as *mut H, "fmi3SetFloat64", |h| {
        same_length(n_vrs, n_values)?;
        ffi::set_many(&mut h.inst, vrs, n_vrs, values, false, |v| v)
    })
}

/// `fmi3GetInt32` (the horizon and the solve status).
///
/// # Safety
/// `instance` comes from `fmi3InstantiateCoSimulation`; the arrays hold `n` elements.
#[no_mangle]
pub unsafe extern "C" fn fmi3GetInt32(
    instance: Fmi3Instance,
    vrs: *const Fmi3ValueReference,
    n_vrs: usize,
    values: *mut i32,
    n_values: usize,
) -> Fmi3Status {
    call(instance as *mut H, "fmi3GetInt32", |h| {
        same_length(n_vrs, n_values)?;
        ffi::get_many(&h.inst, vrs, n_vrs, values, true, |v| v as i32)
    })
}

/// `fmi3SetInt32` (the horizon).
///
/// # Safety
/// `instance` comes from `fmi3InstantiateCoSimulation`; the arrays hold `n` elements.
#[no_mangle]
pub unsafe extern "C" fn fmi3SetInt32(
    instance: Fmi3Instance,
    vrs: *const Fmi3ValueReference,
    n_vrs: usize,
    values: *const i32,
    n_values: usize,
) -> Fmi3Status {
    call(instance as *mut H, "fmi3SetInt32", |h| {
        same_length(n_vrs, n_values)?;
        ffi::set_many(&mut h.inst, vrs, n_vrs, values, true, |v| v as f64)
    })
}

fn same_length(n_vrs: usize, n_values: usize) -> Result<(), Failure> {
    if n_vrs == n_values {
        Ok(())
    } else {
        Err(Failure::error(format!(
            "{n_vrs} value references but {n_values} values (this FMU has scalar variables only)"
        )))
    }
}

/// Getters and setters of types the FMU has no variable of: OK for an empty request, an error
/// naming the type otherwise.
macro_rules! no_variables_of_type {
    ($($name:ident($values:ty, $type_name:literal);)*) => {$(
        #[doc = concat!("`", stringify!($name), "`: this FMU has no ", $type_name, " variables.")]
        ///
        /// # Safety
        /// `instance` comes from `fmi3InstantiateCoSimulation`.
        #[no_mangle]
        pub unsafe extern "C" fn $name(
            instance: Fmi3Instance,
            _vrs: *const Fmi3ValueReference,
            n_vrs: usize,
            _values: $values,
            _n_values: usize,
        ) -> Fmi3Status {
            call(instance as *mut H, stringify!($name), |_| ffi::no_variables(n_vrs, $type_name))
        }
    )*};
}

no_variables_of_type! {
    fmi3GetFloat32(*mut f32, "Float32");
    fmi3GetInt8(*mut i8, "Int8");
    fmi3GetUInt8(*mut u8, "UInt8");
    fmi3GetInt16(*mut i16, "Int16");
    fmi3GetUInt16(*mut u16, "UInt16");
    fmi3GetUInt32(*mut u32, "UInt32");
    fmi3GetInt64(*mut i64, "Int64");
    fmi3GetUInt64(*mut u64, "UInt64");
    fmi3GetBoolean(*mut bool, "Boolean");
    fmi3GetString(*mut Fmi3String, "String");
    fmi3SetFloat32(*const f32, "Float32");
    fmi3SetInt8(*const i8, "Int8");
    fmi3SetUInt8(*const u8, "UInt8");
    fmi3SetInt16(*const i16, "Int16");
    fmi3SetUInt16(*const u16, "UInt16");
    fmi3SetUInt32(*const u32, "UInt32");
    fmi3SetInt64(*const i64, "Int64");
    fmi3SetUInt64(*const u64, "UInt64");
    fmi3SetBoolean(*const bool, "Boolean");
    fmi3SetString(*const Fmi3String, "String");
}

/// Functions of interfaces this FMU does not declare: each logs that it is not supported and
/// returns `fmi3Error`. Signatures as in `fmi3FunctionTypes.h`.
macro_rules! unsupported {
    ($($name:ident($($arg:ident: $ty:ty),*);)*) => {$(
        #[doc = concat!("`", stringify!($name), "`: not supported by this FMU (logs why, returns `fmi3Error`).")]
        ///
        /// # Safety
        /// `instance` is NULL or comes from `fmi3InstantiateCoSimulation`.
        #[no_mangle]
        pub unsafe extern "C" fn $name(instance: Fmi3Instance, $($arg: $ty),*) -> Fmi3Status {
            $(let _ = $arg;)*
            ffi::unsupported(instance as *mut H, stringify!($name))
        }
    )*};
}

unsupported! {
    fmi3EnterEventMode();
    fmi3EnterStepMode();
    fmi3EnterConfigurationMode();
    fmi3ExitConfigurationMode();
    fmi3EnterContinuousTimeMode();
    fmi3EvaluateDiscreteStates();
    fmi3GetBinary(vrs: *const u32, n: usize, sizes: *mut usize, values: *mut *const u8, nv: usize);
    fmi3SetBinary(vrs: *const u32, n: usize, sizes: *const usize, values: *const *const u8, nv: usize);
    fmi3GetClock(vrs: *const u32, n: usize, values: *mut bool);
    fmi3SetClock(vrs: *const u32, n: usize, values: *const bool);
    fmi3GetNumberOfVariableDependencies(vr: u32, n: *mut usize);
    fmi3GetVariableDependencies(dependent: u32, element_indices: *mut usize, independents: *mut u32, element_indices_of_independents: *mut usize, kinds: *mut i32, n: usize);
    fmi3GetFMUState(state: *mut Fmi3FmuState);
    fmi3SetFMUState(state: Fmi3FmuState);
    fmi3FreeFMUState(state: *mut Fmi3FmuState);
    fmi3SerializedFMUStateSize(state: Fmi3FmuState, size: *mut usize);
    fmi3SerializeFMUState(state: Fmi3FmuState, bytes: *mut u8, size: usize);
    fmi3DeserializeFMUState(bytes: *const u8, size: usize, state: *mut Fmi3FmuState);
    fmi3GetDirectionalDerivative(unknowns: *const u32, nu: usize, knowns: *const u32, nk: usize, seed: *const f64, ns: usize, sensitivity: *mut f64, nsens: usize);
    fmi3GetAdjointDerivative(unknowns: *const u32, nu: usize, knowns: *const u32, nk: usize, seed: *const f64, ns: usize, sensitivity: *mut f64, nsens: usize);
    fmi3GetIntervalDecimal(vrs: *const u32, n: usize, intervals: *mut f64, qualifiers: *mut i32);
    fmi3GetIntervalFraction(vrs: *const u32, n: usize, counters: *mut u64, resolutions: *mut u64, qualifiers: *mut i32);
    fmi3GetShiftDecimal(vrs: *const u32, n: usize, shifts: *mut f64);
    fmi3GetShiftFraction(vrs: *const u32, n: usize, counters: *mut u64, resolutions: *mut u64);
    fmi3SetIntervalDecimal(vrs: *const u32, n: usize, intervals: *const f64);
    fmi3SetIntervalFraction(vrs: *const u32, n: usize, counters: *const u64, resolutions: *const u64);
    fmi3SetShiftDecimal(vrs: *const u32, n: usize, shifts: *const f64);
    fmi3SetShiftFraction(vrs: *const u32, n: usize, counters: *const u64, resolutions: *const u64);
    fmi3UpdateDiscreteStates(a: *mut bool, b: *mut bool, c: *mut bool, d: *mut bool, e: *mut bool, t: *mut f64);
    fmi3CompletedIntegratorStep(no_set: bool, enter_event_mode: *mut bool, terminate: *mut bool);
    fmi3SetTime(time: f64);
    fmi3SetContinuousStates(x: *const f64, n: usize);
    fmi3GetContinuousStateDerivatives(dx: *mut f64, n: usize);
    fmi3GetEventIndicators(indicators: *mut f64, n: usize);
    fmi3GetContinuousStates(x: *mut f64, n: usize);
    fmi3GetNominalsOfContinuousStates(nominals: *mut f64, n: usize);
    fmi3GetNumberOfEventIndicators(n: *mut usize);
    fmi3GetNumberOfContinuousStates(n: *mut usize);
    fmi3GetOutputDerivatives(vrs: *const u32, n: usize, orders: *const i32, values: *mut f64, nv: usize);
    fmi3ActivateModelPartition(clock: u32, activation_time: f64);
}

/// `fmi3InstantiateModelExchange`: not supported (a co-simulation FMU); logs and returns NULL.
///
/// # Safety
/// `log_message` is NULL or a valid callback.
#[no_mangle]
pub unsafe extern "C" fn fmi3InstantiateModelExchange(
    instance_name: Fmi3String,
    _instantiation_token: Fmi3String,
    _resource_path: Fmi3String,
    _visible: Fmi3Boolean,
    _logging_on: Fmi3Boolean,
    instance_environment: *mut c_void,
    log_message: Fmi3LogMessage,
) -> Fmi3Instance {
    refuse(
        instance_name,
        instance_environment,
        log_message,
        "model exchange is not supported: this is a co-simulation FMU",
    )
}

/// `fmi3InstantiateScheduledExecution`: not supported; logs and returns NULL.
///
/// # Safety
/// `log_message` is NULL or a valid callback.
#[no_mangle]
pub unsafe extern "C" fn fmi3InstantiateScheduledExecution(
    instance_name: Fmi3String,
    _instantiation_token: Fmi3String,
    _resource_path: Fmi3String,
    _visible: Fmi3Boolean,
    _logging_on: Fmi3Boolean,
    instance_environment: *mut c_void,
    log_message: Fmi3LogMessage,
    _clock_update: Option<unsafe extern "C" fn()>,
    _lock_preemption: Option<unsafe extern "C" fn()>,
    _unlock_preemption: Option<unsafe extern "C" fn()>,
) -> Fmi3Instance {
    refuse(
        instance_name,
        instance_environment,
        log_message,
        "scheduled execution is not supported: this is a co-simulation FMU",
    )
}

/// An instantiate function of an interface this FMU does not declare: logs `message` as an
/// error through `log_message` and returns NULL.
///
/// # Safety
/// `instance_name` is NULL or NUL-terminated; `log_message` is NULL or a valid callback.
unsafe fn refuse(
    instance_name: Fmi3String,
    instance_environment: *mut c_void,
    log_message: Fmi3LogMessage,
    message: &str,
) -> Fmi3Instance {
    let name = ffi::string(instance_name).unwrap_or_default();
    let log = Log3 {
        env: instance_environment,
        cb: log_message,
    };
    log.log(&name, Status::Error, "logStatusError", message);
    std::ptr::null_mut()
}
