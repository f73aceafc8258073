//! What the FMI 3 and FMI 2 bindings share: the handle behind an instance pointer, logging
//! through the master's callback, calls that never unwind into the master (a panic becomes
//! `Fatal` with a logged message), and the bodies of the functions both versions export
//! (instantiate, free, step, value access, unsupported functions).

use std::ffi::{c_char, c_void, CStr, CString};
use std::panic::{catch_unwind, AssertUnwindSafe, UnwindSafe};
use std::path::{Path, PathBuf};

use crate::instance::{Failure, Instance, Status};

/// The master's logger, as each FMI version defines it.
pub trait Logger {
    /// Sends `message` (with `status` and `category`) for the instance `name`.
    fn log(&self, name: &str, status: Status, category: &str, message: &str);
}

/// What an instance pointer handed to the master points at.
pub struct Handle<L: Logger> {
    /// The instance.
    pub inst: Instance,
    /// The instance name the master gave.
    pub name: String,
    /// The master's logger.
    pub logger: L,
    /// Debug logging (info messages); warnings and errors are always logged.
    pub logging_on: bool,
}

impl<L: Logger> Handle<L> {
    /// Logs at `status` (category `logStatusError`, `logStatusWarning` or `logInfo`).
    pub fn log(&self, status: Status, message: &str) {
        if status == Status::Ok && !self.logging_on {
            return;
        }
        let category = match status {
            Status::Ok => "logInfo",
            Status::Warning => "logStatusWarning",
            _ => "logStatusError",
        };
        self.logger.log(&self.name, status, category, message);
    }

    /// `doStep`: solves the MPC for the inputs as set and holds the command over the step from
    /// `t` to `t + h`; a step that ends with a warning status logs the warning.
    pub fn do_step(&mut self, t: f64, h: f64) -> Result<Status, Failure> {
        let s = self.inst.do_step(t, h)?;
        if s == Status::Warning {
            self.log(Status::Warning, &self.inst.step_warning(h));
        }
        Ok(s)
    }
}

/// Instantiate (`what`: the FMI function's name): runs `make` without unwinding into the master
/// and hands the new instance to the master as a pointer; on failure logs `what: reason` through
/// `logger` (a panic as `Fatal`) and returns NULL.
pub fn instantiate<L: Logger>(
    what: &str,
    name: String,
    logger: L,
    logging_on: bool,
    make: impl FnOnce() -> Result<Instance, String> + UnwindSafe,
) -> *mut c_void {
    match catch_unwind(make) {
        Ok(Ok(inst)) => Box::into_raw(Box::new(Handle {
            inst,
            name,
            logger,
            logging_on,
        })) as *mut c_void,
        Ok(Err(message)) => {
            logger.log(
                &name,
                Status::Error,
                "logStatusError",
                &format!("{what}: {message}"),
            );
            std::ptr::null_mut()
        }
        Err(_) => {
            logger.log(
                &name,
                Status::Fatal,
                "logStatusError",
                &format!("{what}: internal error"),
            );
            std::ptr::null_mut()
        }
    }
}

/// The instance for the resources at `location` (a resource path or `file:` URI; `missing` is
/// the reason when the master gave none), checked against the master's `token` (GUID).
pub fn load(
    location: Option<String>,
    missing: &str,
    token: Option<String>,
) -> Result<Instance, String> {
    let location = location.ok_or(missing)?;
    let dir = resource_dir(&location)?;
    Instance::new(Path::new(&dir), token.as_deref())
}

/// FreeInstance: drops the handle behind `ptr` (NULL: nothing), never unwinding into the master.
///
/// # Safety
/// `ptr` is NULL or a pointer returned by this library's instantiate, not used afterwards.
pub unsafe fn free<L: Logger>(ptr: *mut Handle<L>) {
    if !ptr.is_null() {
        // Nothing sees the handle after the drop, so a panic in it leaves no broken state.
        let _ = catch_unwind(AssertUnwindSafe(|| drop(Box::from_raw(ptr))));
    }
}

/// A function of a capability the FMU does not declare: `Error`, logged (unless `ptr` is NULL).
///
/// # Safety
/// As [`call`].
pub unsafe fn unsupported<L: Logger>(ptr: *mut Handle<L>, what: &str) -> i32 {
    call(ptr, what, |_| {
        Err(Failure::error("not supported by this co-simulation FMU"))
    })
}

/// A getter or setter of a type (`type_name`) the FMU has no variable of: OK for an empty
/// request (`n == 0`), an error naming the type otherwise.
pub fn no_variables(n: usize, type_name: &str) -> Result<Status, Failure> {
    if n == 0 {
        Ok(Status::Ok)
    } else {
        Err(Failure::error(format!(
            "this FMU has no {type_name} variables"
        )))
    }
}

/// A string from the master (`None` for NULL or invalid UTF-8).
///
/// # Safety
/// `p` is NULL or a NUL-terminated string valid for the call.
pub unsafe fn string(p: *const c_char) -> Option<String> {
    if p.is_null() {
        return None;
    }
    CStr::from_ptr(p).to_str().ok().map(str::to_string)
}

/// A C string for the logger (interior NULs replaced).
pub fn c_string(s: &str) -> CString {
    CString::new(s.replace('\0', " ")).unwrap_or_default()
}

/// The folder a resource location names: a plain path (FMI 3's `resourcePath`) or a `file:`
/// URI (FMI 2's `fmuResourceLocation`), percent-decoded.
pub fn resource_dir(location: &str) -> Result<PathBuf, String> {
    let path = if let Some(rest) = location.strip_prefix("file:") {
        let rest = if let Some(r) = rest.strip_prefix("//") {
            // file://host/path: only an empty host or localhost is a local file.
            let (host, path) = r.split_at(r.find('/').unwrap_or(r.len()));
            if !(host.is_empty() || host == "localhost") {
                return Err(format!(
                    "resource location {location}: not a local file URI"
                ));
            }
            path
        } else {
            rest
        };
        percent_decode(rest)?
    } else {
        location.to_string()
    };
    if path.is_empty() {
        return Err("empty resource location".into());
    }
    Ok(PathBuf::from(path))
}

fn percent_decode(s: &str) -> Result<String, String> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' {
            let hex = s
                .get(i + 1..i + 3)
                .and_then(|h| u8::from_str_radix(h, 16).ok())
                .ok_or_else(|| format!("bad percent escape in the resource URI {s}"))?;
            out.push(hex);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8(out).map_err(|_| format!("resource URI {s} is not UTF-8"))
}

/// Runs `f` on the instance behind `ptr`: a NULL pointer is `Error`, a failure is logged and
/// returned as its status, a panic is logged and returned as `Fatal`. Returns the status as the
/// FMI integer.
///
/// # Safety
/// `ptr` is NULL or a pointer returned by this library's instantiate and not yet freed.
pub unsafe fn call<L: Logger>(
    ptr: *mut Handle<L>,
    what: &str,
    f: impl FnOnce(&mut Handle<L>) -> Result<Status, Failure>,
) -> i32 {
    if ptr.is_null() {
        return Status::Error as i32;
    }
    let h = &mut *ptr;
    let result = catch_unwind(AssertUnwindSafe(|| f(h)));
    let h = &mut *ptr;
    match result {
        Ok(Ok(s)) => s as i32,
        Ok(Err(fail)) => {
            h.log(fail.status, &format!("{what}: {}", fail.message));
            fail.status as i32
        }
        Err(panic) => {
            let msg = panic
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "unknown panic".into());
            h.log(Status::Fatal, &format!("{what}: internal error: {msg}"));
            Status::Fatal as i32
        }
    }
}

/// Reads `n` values through `get` for the value references `vrs` into `out`.
///
/// # Safety
/// `vrs` and `out` hold `n` elements (or are NULL with `n == 0`).
pub unsafe fn get_many<T>(
    inst: &Instance,
    vrs: *const u32,
    n: usize,
    out: *mut T,
    integer: bool,
    conv: impl Fn(f64) -> T,
) -> Result<Status, Failure> {
    if n == 0 {
        return Ok(Status::Ok);
    }
    if vrs.is_null() || out.is_null() {
        return Err(Failure::error("NULL value reference or value array"));
    }
    let vrs = std::slice::from_raw_parts(vrs, n);
    let out = std::slice::from_raw_parts_mut(out, n);
    for (vr, o) in vrs.iter().zip(out) {
        check_type(inst, *vr, integer)?;
        *o = conv(inst.get(*vr)?);
    }
    Ok(Status::Ok)
}

/// Sets `n` values for the value references `vrs`.
///
/// # Safety
/// `vrs` and `values` hold `n` elements (or are NULL with `n == 0`).
pub unsafe fn set_many<T: Copy>(
    inst: &mut Instance,
    vrs: *const u32,
    n: usize,
    values: *const T,
    integer: bool,
    conv: impl Fn(T) -> f64,
) -> Result<Status, Failure> {
    if n == 0 {
        return Ok(Status::Ok);
    }
    if vrs.is_null() || values.is_null() {
        return Err(Failure::error("NULL value reference or value array"));
    }
    let vrs = std::slice::from_raw_parts(vrs, n);
    let values = std::slice::from_raw_parts(values, n);
    for (vr, v) in vrs.iter().zip(values) {
        check_type(inst, *vr, integer)?;
        inst.set(*vr, conv(*v))?;
    }
    Ok(Status::Ok)
}

fn check_type(inst: &Instance, vr: u32, integer: bool) -> Result<(), Failure> {
    match inst.is_integer(vr) {
        None => Err(Failure::error(format!(
            "no variable has value reference {vr}"
        ))),
        Some(i) if i != integer => Err(Failure::error(format!(
            "value reference {vr} is {}, not {}",
            if i { "an integer" } else { "a real" },
            if integer { "an integer" } else { "a real" }
        ))),
        _ => Ok(()),
    }
}
