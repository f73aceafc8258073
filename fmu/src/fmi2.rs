//! The FMI 2.0 C API (co-simulation) over [`crate::instance::Instance`]: the FMI 2 C types and
//! every function of `fmi2Functions.h`. Functions of capabilities the model description does
//! not declare (model exchange, FMU state, derivatives, asynchronous steps) log why and return
//! `fmi2Error`.
#![allow(non_snake_case)]

use std::ffi::{c_char, c_int, c_void};

use crate::ffi::{self, c_string, call, Handle, Logger};
use crate::instance::Status;

/// `fmi2Component`.
pub type Fmi2Component = *mut c_void;
/// `fmi2Status` (OK, Warning, Discard, Error, Fatal, Pending).
pub type Fmi2Status = i32;
/// `fmi2ValueReference`.
pub type Fmi2ValueReference = u32;
/// `fmi2Boolean` (a C `int`).
pub type Fmi2Boolean = c_int;
/// `fmi2String`.
pub type Fmi2String = *const c_char;
/// `fmi2FMUstate`.
pub type Fmi2FmuState = *mut c_void;
/// `fmi2CallbackLogger` (variadic: the message is a printf format).
pub type Fmi2Logger = Option<
    unsafe extern "C" fn(
        env: *mut c_void,
        instance_name: Fmi2String,
        status: Fmi2Status,
        category: Fmi2String,
        message: Fmi2String,
        ...
    ),
>;

/// `fmi2CallbackFunctions`.
#[repr(C)]
pub struct Fmi2CallbackFunctions {
    /// The logger.
    pub logger: Fmi2Logger,
    /// `allocateMemory` (not used: canNotUseMemoryManagementFunctions).
    pub allocate_memory: Option<unsafe extern "C" fn(usize, usize) -> *mut c_void>,
    /// `freeMemory` (not used).
    pub free_memory: Option<unsafe extern "C" fn(*mut c_void)>,
    /// `stepFinished` (not used: steps are synchronous).
    pub step_finished: Option<unsafe extern "C" fn(*mut c_void, Fmi2Status)>,
    /// The component environment handed back to the logger.
    pub component_environment: *mut c_void,
}

/// `fmi2CoSimulation` of `fmi2Type`.
pub const FMI2_COSIMULATION: c_int = 1;

/// The FMI 2 logger of an instance.
pub struct Log2 {
    env: *mut c_void,
    cb: Fmi2Logger,
}

impl Logger for Log2 {
    fn log(&self, name: &str, status: Status, category: &str, message: &str) {
        if let Some(cb) = self.cb {
            // The message is a printf format for the master: a literal '%' is doubled.
            let (n, c, m) = (
                c_string(name),
                c_string(category),
                c_string(&message.replace('%', "%%")),
            );
            // SAFETY: the master's callback, with the environment it gave at instantiation.
            unsafe { cb(self.env, n.as_ptr(), status as i32, c.as_ptr(), m.as_ptr()) };
        }
    }
}

type H = Handle<Log2>;

/// `fmi2GetTypesPlatform`: "default".
#[no_mangle]
pub extern "C" fn fmi2GetTypesPlatform() -> *const c_char {
    c"default".as_ptr()
}

/// `fmi2GetVersion`: "2.0".
#[no_mangle]
pub extern "C" fn fmi2GetVersion() -> *const c_char {
    c"2.0".as_ptr()
}

/// `fmi2SetDebugLogging`: info messages on or off (warnings and errors are always logged).
///
/// # Safety
/// `c` comes from `fmi2Instantiate`.
#[no_mangle]
pub unsafe extern "C" fn fmi2SetDebugLogging(
    c: Fmi2Component,
    logging_on: Fmi2Boolean,
    _n_categories: usize,
    _categories: *const Fmi2String,
) -> Fmi2Status {
    call(c as *mut H, "fmi2SetDebugLogging", |h| {
        h.logging_on = logging_on != 0;
        Ok(Status::Ok)
    })
}

/// `fmi2Instantiate` (co-simulation only): loads `resources/controller.json` and the model
/// from the `file:` URI `fmuResourceLocation`; NULL (with a logged message naming the missing
/// file) on failure.
///
/// # Safety
/// The strings are NULL or NUL-terminated; `functions` is NULL or valid for the call.
#[no_mangle]
pub unsafe extern "C" fn fmi2Instantiate(
    instance_name: Fmi2String,
    fmu_type: c_int,
    fmu_guid: Fmi2String,
    fmu_resource_location: Fmi2String,
    functions: *const Fmi2CallbackFunctions,
    _visible: Fmi2Boolean,
    logging_on: Fmi2Boolean,
) -> Fmi2Component {
    let logger = if functions.is_null() {
        Log2 {
            env: std::ptr::null_mut(),
            cb: None,
        }
    } else {
        Log2 {
            env: (*functions).component_environment,
            cb: (*functions).logger,
        }
    };
    let name = ffi::string(instance_name).unwrap_or_else(|| "controller".into());
    ffi::instantiate("fmi2Instantiate", name, logger, logging_on != 0, || {
        if fmu_type != FMI2_COSIMULATION {
            return Err("model exchange is not supported: this is a co-simulation FMU".to_string());
        }
        ffi::load(
            ffi::string(fmu_resource_location),
            "no resource location: the model and controller.json travel in resources/",
            ffi::string(fmu_guid),
        )
    })
}

/// `fmi2FreeInstance`.
///
/// # Safety
/// `c` comes from `fmi2Instantiate` and is not used afterwards.
#[no_mangle]
pub unsafe extern "C" fn fmi2FreeInstance(c: Fmi2Component) {
    ffi::free(c as *mut H);
}

/// `fmi2SetupExperiment`: the start time.
///
/// # Safety
/// `c` comes from `fmi2Instantiate`.
#[no_mangle]
pub unsafe extern "C" fn fmi2SetupExperiment(
    c: Fmi2Component,
    _tolerance_defined: Fmi2Boolean,
    _tolerance: f64,
    start_time: f64,
    _stop_time_defined: Fmi2Boolean,
    _stop_time: f64,
) -> Fmi2Status {
    call(c as *mut H, "fmi2SetupExperiment", |h| {
        h.inst.set_start_time(start_time);
        Ok(Status::Ok)
    })
}

/// `fmi2EnterInitializationMode`.
///
/// # Safety
/// `c` comes from `fmi2Instantiate`.
#[no_mangle]
pub unsafe extern "C" fn fmi2EnterInitializationMode(c: Fmi2Component) -> Fmi2Status {
    call(c as *mut H, "fmi2EnterInitializationMode", |h| {
        h.inst.enter_initialization().map(|_| Status::Ok)
    })
}

/// `fmi2ExitInitializationMode`: builds the MPC with the parameters as set.
///
/// # Safety
/// `c` comes from `fmi2Instantiate`.
#[no_mangle]
pub unsafe extern "C" fn fmi2ExitInitializationMode(c: Fmi2Component) -> Fmi2Status {
    call(c as *mut H, "fmi2ExitInitializationMode", |h| {
        h.inst.exit_initialization().map(|_| Status::Ok)
    })
}

/// `fmi2Terminate`.
///
/// # Safety
/// `c` comes from `fmi2Instantiate`.
#[no_mangle]
pub unsafe extern "C" fn fmi2Terminate(c: Fmi2Component) -> Fmi2Status {
    call(c as *mut H, "fmi2Terminate", |h| {
        h.inst.terminate().map(|_| Status::Ok)
    })
}

/// `fmi2Reset`.
///
/// # Safety
/// `c` comes from `fmi2Instantiate`.
#[no_mangle]
pub unsafe extern "C" fn fmi2Reset(c: Fmi2Component) -> Fmi2Status {
    call(c as *mut H, "fmi2Reset", |h| {
        h.inst.reset();
        Ok(Status::Ok)
    })
}

/// `fmi2DoStep`: solves the MPC for the inputs as set and holds the command over the step.
///
/// # Safety
/// `c` comes from `fmi2Instantiate`.
#[no_mangle]
pub unsafe extern "C" fn fmi2DoStep(
    c: Fmi2Component,
    current_communication_point: f64,
    communication_step_size: f64,
    _no_set_fmu_state_prior_to_current_point: Fmi2Boolean,
) -> Fmi2Status {
    call(c as *mut H, "fmi2DoStep", |h| {
        h.do_step(current_communication_point, communication_step_size)
    })
}

/// `fmi2GetReal`.
///
/// # Safety
/// `c` comes from `fmi2Instantiate`; the arrays hold `nvr` elements.
#[no_mangle]
pub unsafe extern "C" fn fmi2GetReal(
    c: Fmi2Component,
    vr: *const u32,
    nvr: usize,
    value: *mut f64,
) -> Fmi2Status {
    call(c as *mut H, "fmi2GetReal", |h| {
        ffi::get_many(&h.inst, vr, nvr, value, false, |v| v)
    })
}

/// `fmi2SetReal`: inputs at any time before terminate, parameters before the end of
/// initialisation; out-of-range values (a NaN or infinite state) are `fmi2Error`.
///
/// # Safety
/// `c` comes from `fmi2Instantiate`; the arrays hold `nvr` elements.
#[no_mangle]
pub unsafe extern "C" fn fmi2SetReal(
    c: Fmi2Component,
    vr: *const u32,
    nvr: usize,
    value: *const f64,
) -> Fmi2Status {
    call(c as *mut H, "fmi2SetReal", |h| {
        ffi::set_many(&mut h.inst, vr, nvr, value, false, |v| v)
    })
}

/// `fmi2GetInteger` (the horizon and the solve status).
///
/// # Safety
/// `c` comes from `fmi2Instantiate`; the arrays hold `nvr` elements.
#[no_mangle]
pub unsafe extern "C" fn fmi2GetInteger(
    c: Fmi2Component,
    vr: *const u32,
    nvr: usize,
    value: *mut c_int,
) -> Fmi2Status {
    call(c as *mut H, "fmi2GetInteger", |h| {
        ffi::get_many(&h.inst, vr, nvr, value, true, |v| v as c_int)
    })
}

/// `fmi2SetInteger` (the horizon).
///
/// # Safety
/// `c` comes from `fmi2Instantiate`; the arrays hold `nvr` elements.
#[no_mangle]
pub unsafe extern "C" fn fmi2SetInteger(
    c: Fmi2Component,
    vr: *const u32,
    nvr: usize,
    value: *const c_int,
) -> Fmi2Status {
    call(c as *mut H, "fmi2SetInteger", |h| {
        ffi::set_many(&mut h.inst, vr, nvr, value, true, |v| v as f64)
    })
}

/// Getters and setters of types the FMU has no variable of: OK for an empty request.
macro_rules! no_variables_of_type {
    ($($name:ident($values:ty, $type_name:literal);)*) => {$(
        #[doc = concat!("`", stringify!($name), "`: this FMU has no ", $type_name, " variables.")]
        ///
        /// # Safety
        /// `c` comes from `fmi2Instantiate`.
        #[no_mangle]
        pub unsafe extern "C" fn $name(c: Fmi2Component, _vr: *const u32, nvr: usize, _value: $values) -> Fmi2Status {
            call(c as *mut H, stringify!($name), |_| ffi::no_variables(nvr, $type_name))
        }
    )*};
}

no_variables_of_type! {
    fmi2GetBoolean(*mut Fmi2Boolean, "Boolean");
    fmi2GetString(*mut Fmi2String, "String");
    fmi2SetBoolean(*const Fmi2Boolean, "Boolean");
    fmi2SetString(*const Fmi2String, "String");
}

/// Functions of capabilities this FMU does not declare: log and return `fmi2Error`.
macro_rules! unsupported {
    ($($name:ident($($arg:ident: $ty:ty),*);)*) => {$(
        #[doc = concat!("`", stringify!($name), "`: not supported by this FMU (logs why, returns `fmi2Error`).")]
        ///
        /// # Safety
        /// `c` is NULL or comes from `fmi2Instantiate`.
        #[no_mangle]
        pub unsafe extern "C" fn $name(c: Fmi2Component, $($arg: $ty),*) -> Fmi2Status {
            $(let _ = $arg;)*
            ffi::unsupported(c as *mut H, stringify!($name))
        }
    )*};
}

unsupported! {
    fmi2GetFMUstate(state: *mut Fmi2FmuState);
    fmi2SetFMUstate(state: Fmi2FmuState);
    fmi2FreeFMUstate(state: *mut Fmi2FmuState);
    fmi2SerializedFMUstateSize(state: Fmi2FmuState, size: *mut usize);
    fmi2SerializeFMUstate(state: Fmi2FmuState, bytes: *mut c_char, size: usize);
    fmi2DeSerializeFMUstate(bytes: *const c_char, size: usize, state: *mut Fmi2FmuState);
    fmi2GetDirectionalDerivative(unknown: *const u32, n_unknown: usize, known: *const u32, n_known: usize, dv_known: *const f64, dv_unknown: *mut f64);
    fmi2SetRealInputDerivatives(vr: *const u32, nvr: usize, order: *const c_int, value: *const f64);
    fmi2GetRealOutputDerivatives(vr: *const u32, nvr: usize, order: *const c_int, value: *mut f64);
    fmi2CancelStep();
    fmi2GetStatus(kind: c_int, value: *mut Fmi2Status);
    fmi2GetRealStatus(kind: c_int, value: *mut f64);
    fmi2GetIntegerStatus(kind: c_int, value: *mut c_int);
    fmi2GetBooleanStatus(kind: c_int, value: *mut Fmi2Boolean);
    fmi2GetStringStatus(kind: c_int, value: *mut Fmi2String);
}
