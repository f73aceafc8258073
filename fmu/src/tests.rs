//! The FMI state machine through the C API itself (FMI 3 and FMI 2): commands against the
//! shared controller stepped by hand, bad inputs and parameters, missing resources, several
//! instances, and instantiate/free cycles without growth of the resident set.

use std::ffi::{c_char, c_void, CStr, CString};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use koopman::model::arch::Arch;
use koopman::model::koopman::KoopmanModel;
use koopman::mpc::{LoadedModel, MpcConfig};

use crate::fmi2::*;
use crate::fmi3::*;
use crate::layout::{Layout, Role};
use crate::settings::{controller_file, ControllerFile, MpcFile, CONTROLLER_FILE, MODEL_DIR};

/// Tests run one at a time (the resident-set test must not see the others' allocations).
static SERIAL: Mutex<()> = Mutex::new(());

const OK: i32 = 0;
const WARNING: i32 = 1;
const ERROR: i32 = 3;

/// A fresh folder under the system's temporary folder.
fn temp_dir(tag: &str) -> PathBuf {
    use std::sync::atomic::{AtomicUsize, Ordering};
    static N: AtomicUsize = AtomicUsize::new(0);
    let d = std::env::temp_dir().join(format!(
        "koopbridge-fmu-test {}-{}-{tag}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    ));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A pendulum-shaped model (nx 2, nu 1) with training metadata, and `resources/` for it with
/// bounds ±`bound`, Q = diag(1, q2), R = 1e-3, H = 10, reference [0.3, 0].
fn resources(tag: &str, hidden: usize, q2: f64, bound: f64) -> PathBuf {
    let root = temp_dir(tag);
    let res = root.join("resources");
    let arch = Arch::new(2, 1, &[hidden, hidden], 4).unwrap();
    let mut model = KoopmanModel::init(arch, 11).unwrap();
    model.metadata = serde_json::json!({"dataset": {
        "state_names": ["theta", "theta_dot"], "input_names": ["u"], "dt": 0.02}});
    model.save(&res.join(MODEL_DIR)).unwrap();
    let mpc = MpcFile {
        reference: Some(vec![0.3, 0.0]),
        mpc: MpcConfig {
            horizon: 10,
            q: Some(vec![1.0, q2]),
            r: Some(vec![1e-3]),
            ..MpcConfig::with_bounds(vec![-bound], vec![bound])
        },
        offset_free: None,
    };
    let units = [("theta".to_string(), "rad".to_string())];
    let file = controller_file(&res.join(MODEL_DIR), &mpc, &units, None).unwrap();
    std::fs::write(
        res.join(CONTROLLER_FILE),
        serde_json::to_vec(&file).unwrap(),
    )
    .unwrap();
    res
}

fn file_of(res: &Path) -> ControllerFile {
    ControllerFile::read(res).unwrap()
}

/// The messages an instance logged (its environment pointer points at one of these).
type Messages = Mutex<Vec<(i32, String)>>;

unsafe extern "C" fn log3(
    env: *mut c_void,
    status: i32,
    _category: *const c_char,
    message: *const c_char,
) {
    let m = &*(env as *const Messages);
    m.lock()
        .unwrap()
        .push((status, CStr::from_ptr(message).to_string_lossy().into()));
}

/// FMI 2's logger is variadic; this one reads only the fixed arguments (no format arguments
/// are ever passed by the FMU).
unsafe extern "C" fn log2(
    env: *mut c_void,
    _name: *const c_char,
    status: i32,
    _category: *const c_char,
    message: *const c_char,
) {
    log3(env, status, std::ptr::null(), message)
}

struct Fmu3 {
    inst: Fmi3Instance,
    log: Box<Messages>,
    layout: Layout,
}

impl Fmu3 {
    fn new(res: &Path) -> Result<Self, Vec<(i32, String)>> {
        let log: Box<Messages> = Box::default();
        let name = CString::new("ctrl").unwrap();
        let path = CString::new(format!("{}/", res.display())).unwrap();
        let token = CString::new(file_of_or_empty(res)).unwrap();
        let inst = unsafe {
            fmi3InstantiateCoSimulation(
                name.as_ptr(),
                token.as_ptr(),
                path.as_ptr(),
                false,
                false,
                false,
                false,
                std::ptr::null(),
                0,
                &*log as *const Messages as *mut c_void,
                Some(log3),
                None,
            )
        };
        if inst.is_null() {
            return Err(log.lock().unwrap().clone());
        }
        let layout = Layout::new(&file_of(res)).unwrap();
        Ok(Fmu3 { inst, log, layout })
    }
    fn vr(&self, name: &str) -> u32 {
        self.layout.vr(name).unwrap()
    }
    fn set(&self, names: &[&str], values: &[f64]) -> i32 {
        let vrs: Vec<u32> = names.iter().map(|n| self.vr(n)).collect();
        unsafe {
            fmi3SetFloat64(
                self.inst,
                vrs.as_ptr(),
                vrs.len(),
                values.as_ptr(),
                values.len(),
            )
        }
    }
    fn get(&self, name: &str) -> f64 {
        let (vr, mut v) = (self.vr(name), f64::NAN);
        assert_eq!(unsafe { fmi3GetFloat64(self.inst, &vr, 1, &mut v, 1) }, OK);
        v
    }
    fn init(&self) {
        unsafe {
            assert_eq!(
                fmi3EnterInitializationMode(self.inst, false, 0.0, 0.0, false, 0.0),
                OK
            );
            assert_eq!(
                fmi3ExitInitializationMode(self.inst),
                OK,
                "{:?}",
                self.messages()
            );
        }
    }
    fn step(&self, t: f64) -> i32 {
        let (mut a, mut b, mut c, mut last) = (true, true, true, 0.0);
        unsafe { fmi3DoStep(self.inst, t, 0.02, true, &mut a, &mut b, &mut c, &mut last) }
    }
    fn messages(&self) -> Vec<(i32, String)> {
        self.log.lock().unwrap().clone()
    }
}

impl Drop for Fmu3 {
    fn drop(&mut self) {
        unsafe { fmi3FreeInstance(self.inst) };
    }
}

fn file_of_or_empty(res: &Path) -> String {
    ControllerFile::read(res)
        .map(|f| f.token)
        .unwrap_or_default()
}

/// The commands of the service's code path (`LoadedModel` → `ModelController`) stepped by
/// hand through `states` towards `reference`, with the file's settings.
fn commands_by_hand(res: &Path, states: &[[f64; 2]], reference: [f64; 2]) -> Vec<f64> {
    let model = LoadedModel::load(&res.join(MODEL_DIR)).unwrap();
    let mut c = model.controller(&file_of(res).mpc, None).unwrap();
    states
        .iter()
        .map(|x| c.solve(x, &reference).unwrap().u[0])
        .collect()
}

/// A trajectory of measured states (not a closed loop: any states will do for the controller).
fn states(n: usize) -> Vec<[f64; 2]> {
    (0..n)
        .map(|k| [1.0 - 0.05 * k as f64, (0.3 * k as f64).sin()])
        .collect()
}

#[test]
fn fmi3_steps_give_the_service_controllers_commands() {
    let _g = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let res = resources("steps", 16, 0.1, 0.5);
    let f = Fmu3::new(&res).unwrap();
    // Before the first step: the input closest to zero in the bounds, status -1.
    let (status_vr, mut status) = (f.vr("mpc_status"), 7);
    assert_eq!(
        unsafe { fmi3GetInt32(f.inst, &status_vr, 1, &mut status, 1) },
        OK
    );
    assert_eq!((f.get("u"), status), (0.0, -1));
    assert_eq!(f.get("theta_ref"), 0.3);
    f.init();
    let xs = states(25);
    let want = commands_by_hand(&res, &xs, [0.3, 0.0]);
    for (k, x) in xs.iter().enumerate() {
        assert_eq!(f.set(&["theta", "theta_dot"], x), OK);
        assert_eq!(f.step(0.02 * k as f64), OK, "{:?}", f.messages());
        let u = f.get("u");
        assert_eq!(
            u.to_bits(),
            want[k].to_bits(),
            "step {k}: {u} vs {}",
            want[k]
        );
        assert!(u.abs() <= 0.5);
        assert!((f.get("time") - 0.02 * (k + 1) as f64).abs() < 1e-12);
    }
    assert!(
        want.iter().any(|u| u.abs() > 1e-3),
        "the commands are not all zero: {want:?}"
    );
    assert!(
        want.iter().any(|u| u.abs() == 0.5),
        "some command is on its bound: {want:?}"
    );
    // A moving reference reaches the plan: another reference, another command.
    assert_eq!(f.set(&["theta_ref"], &[-0.5]), OK);
    assert_eq!(f.step(1.0), OK);
    assert_ne!(f.get("u"), want[24]);
    unsafe {
        assert_eq!(fmi3Terminate(f.inst), OK);
        // After terminate: getters only.
        assert_eq!(f.set(&["theta"], &[0.0]), ERROR);
        // Reset: back to instantiated, start values, and the same run again.
        assert_eq!(fmi3Reset(f.inst), OK);
    }
    assert_eq!(f.get("theta_ref"), 0.3);
    f.init();
    assert_eq!(f.set(&["theta", "theta_dot"], &xs[0]), OK);
    assert_eq!(f.step(0.0), OK);
    assert_eq!(f.get("u").to_bits(), want[0].to_bits());
}

#[test]
fn fmi3_parameters_rebuild_the_controller_before_initialisation_ends() {
    let _g = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let res = resources("params", 16, 0.1, 2.0);
    let f = Fmu3::new(&res).unwrap();
    // Q, R, bounds and horizon set as parameters give the controller built with them.
    assert_eq!(
        f.set(
            &["q_theta_dot", "r_u", "u_min_u", "u_max_u"],
            &[0.5, 0.01, -1.0, 1.5]
        ),
        OK
    );
    let h_vr = f.vr("horizon");
    assert_eq!(unsafe { fmi3SetInt32(f.inst, &h_vr, 1, &7, 1) }, OK);
    f.init();
    let model = LoadedModel::load(&res.join(MODEL_DIR)).unwrap();
    let cfg = MpcConfig {
        horizon: 7,
        q: Some(vec![1.0, 0.5]),
        r: Some(vec![0.01]),
        ..MpcConfig::with_bounds(vec![-1.0], vec![1.5])
    };
    let mut c = model.controller(&cfg, None).unwrap();
    for (k, x) in states(5).iter().enumerate() {
        f.set(&["theta", "theta_dot"], x);
        assert_eq!(f.step(0.02 * k as f64), OK);
        assert_eq!(f.get("u"), c.solve(x, &[0.3, 0.0]).unwrap().u[0]);
    }
    // Fixed parameters cannot change in step mode.
    assert_eq!(f.set(&["q_theta"], &[2.0]), ERROR);
    let last = f.messages().last().cloned().unwrap();
    assert_eq!(last.0, ERROR);
    assert!(last.1.contains("'q_theta' is fixed"), "{last:?}");
}

#[test]
fn nan_and_infinite_states_and_bad_parameters_are_errors_with_a_logged_message() {
    let _g = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let res = resources("bad", 16, 0.1, 2.0);
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let f = Fmu3::new(&res).unwrap();
        f.init();
        assert_eq!(f.set(&["theta", "theta_dot"], &[0.1, 0.0]), OK);
        assert_eq!(f.step(0.0), OK);
        assert_eq!(f.set(&["theta_dot"], &[bad]), ERROR);
        let (status, msg) = f.messages().last().cloned().unwrap();
        assert_eq!(status, ERROR);
        assert!(
            msg.contains("fmi3SetFloat64") && msg.contains("'theta_dot'") && msg.contains("finite"),
            "{msg}"
        );
        // The instance stays failed: doStep refuses until reset; getters still answer.
        assert_eq!(f.step(0.02), ERROR);
        let _ = f.get("u");
        unsafe { assert_eq!(fmi3Reset(f.inst), OK) };
        f.init();
        assert_eq!(f.step(0.0), OK);
    }
    // Out-of-range parameters: at set time (negative weight, NaN bound, horizon 0), or at the
    // end of initialisation (u_min > u_max).
    let f = Fmu3::new(&res).unwrap();
    assert_eq!(f.set(&["q_theta"], &[-1.0]), ERROR);
    assert!(f.messages().last().unwrap().1.contains("out of range"));
    let f = Fmu3::new(&res).unwrap();
    assert_eq!(f.set(&["u_max_u"], &[f64::NAN]), ERROR);
    let f = Fmu3::new(&res).unwrap();
    let h_vr = f.vr("horizon");
    assert_eq!(unsafe { fmi3SetInt32(f.inst, &h_vr, 1, &0, 1) }, ERROR);
    assert!(f.messages().last().unwrap().1.contains("horizon"));
    let f = Fmu3::new(&res).unwrap();
    assert_eq!(f.set(&["u_min_u", "u_max_u"], &[1.0, -1.0]), OK);
    unsafe {
        assert_eq!(
            fmi3EnterInitializationMode(f.inst, false, 0.0, 0.0, false, 0.0),
            OK
        );
        assert_eq!(fmi3ExitInitializationMode(f.inst), ERROR);
    }
    assert!(
        f.messages()
            .last()
            .unwrap()
            .1
            .contains("u_min_u = 1 > u_max_u = -1"),
        "{:?}",
        f.messages()
    );
    // Type and reference errors: a real read as an integer, an unknown value reference.
    let f = Fmu3::new(&res).unwrap();
    let (vr, mut i) = (f.vr("theta"), 0);
    assert_eq!(unsafe { fmi3GetInt32(f.inst, &vr, 1, &mut i, 1) }, ERROR);
    let (vr, mut v) = (999u32, 0.0);
    assert_eq!(unsafe { fmi3GetFloat64(f.inst, &vr, 1, &mut v, 1) }, ERROR);
    // doStep before initialisation, and a step that is not the model's dt warns once.
    let f = Fmu3::new(&res).unwrap();
    assert_eq!(f.step(0.0), ERROR);
    let f = Fmu3::new(&res).unwrap();
    f.init();
    let (mut a, mut b, mut c, mut last) = (false, false, false, 0.0);
    let st = unsafe { fmi3DoStep(f.inst, 0.0, 0.05, true, &mut a, &mut b, &mut c, &mut last) };
    assert_eq!(st, WARNING);
    assert!(f
        .messages()
        .last()
        .unwrap()
        .1
        .contains("differs from the model's sampling period"));
    let st = unsafe { fmi3DoStep(f.inst, 0.05, 0.05, true, &mut a, &mut b, &mut c, &mut last) };
    assert_eq!((st, last), (OK, 0.1));
    // An unsupported function logs and errs, never crashes.
    assert_eq!(unsafe { fmi3EnterEventMode(f.inst) }, ERROR);
    assert_eq!(
        unsafe {
            fmi3DoStep(
                std::ptr::null_mut(),
                0.0,
                0.02,
                true,
                &mut a,
                &mut b,
                &mut c,
                &mut last,
            )
        },
        ERROR
    );
}

#[test]
fn missing_resources_fail_instantiate_naming_the_file() {
    let _g = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let res = resources("missing", 16, 0.1, 2.0);
    std::fs::remove_file(res.join(MODEL_DIR).join("model.safetensors")).unwrap();
    let log = Fmu3::new(&res).err().expect("instantiate fails");
    assert!(
        log.iter()
            .any(|(s, m)| *s == ERROR && m.contains("model.safetensors")),
        "{log:?}"
    );
    std::fs::remove_dir_all(res.join(MODEL_DIR)).unwrap();
    let log = Fmu3::new(&res).err().expect("instantiate fails");
    assert!(
        log.iter().any(|(_, m)| m.contains("config.json")),
        "{log:?}"
    );
    std::fs::remove_file(res.join(CONTROLLER_FILE)).unwrap();
    let log = Fmu3::new(&res).err().expect("instantiate fails");
    assert!(
        log.iter().any(|(_, m)| m.contains(CONTROLLER_FILE)),
        "{log:?}"
    );
    // A wrong instantiation token (the description of another export) is refused too.
    let res = resources("token", 16, 0.1, 2.0);
    let log: Box<Messages> = Box::default();
    let path = CString::new(res.display().to_string()).unwrap();
    let inst = unsafe {
        fmi3InstantiateCoSimulation(
            c"x".as_ptr(),
            c"{not-this-one}".as_ptr(),
            path.as_ptr(),
            false,
            false,
            false,
            false,
            std::ptr::null(),
            0,
            &*log as *const Messages as *mut c_void,
            Some(log3),
            None,
        )
    };
    assert!(inst.is_null());
    assert!(log.lock().unwrap()[0].1.contains("does not match"));
}

#[test]
fn several_instances_in_one_process_are_independent() {
    let _g = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let (ra, rb) = (resources("a", 16, 0.1, 2.0), resources("b", 16, 5.0, 0.5));
    let xs = states(12);
    let (wa, wb) = (
        commands_by_hand(&ra, &xs, [0.3, 0.0]),
        commands_by_hand(&rb, &xs, [0.3, 0.0]),
    );
    assert_ne!(wa, wb);
    let fs = [
        Fmu3::new(&ra).unwrap(),
        Fmu3::new(&rb).unwrap(),
        Fmu3::new(&ra).unwrap(),
    ];
    for f in &fs {
        f.init();
    }
    for (k, x) in xs.iter().enumerate() {
        for (f, want) in fs.iter().zip([&wa, &wb, &wa]) {
            f.set(&["theta", "theta_dot"], x);
            assert_eq!(f.step(0.02 * k as f64), OK);
            assert_eq!(f.get("u").to_bits(), want[k].to_bits());
        }
    }
}

#[test]
fn fmi2_runs_the_same_controller_from_a_file_uri() {
    let _g = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    // The folder name has a space: the URI percent-encodes it.
    let res = resources("fmi2", 16, 0.1, 2.0);
    let uri = format!("file://{}", res.display().to_string().replace(' ', "%20"));
    let log: Box<Messages> = Box::default();
    // SAFETY (test): a non-variadic function read through the variadic pointer type; the FMU
    // passes no variadic arguments.
    type Variadic =
        unsafe extern "C" fn(*mut c_void, *const c_char, i32, *const c_char, *const c_char, ...);
    let logger: Fmi2Logger =
        Some(unsafe { std::mem::transmute::<*const (), Variadic>(log2 as *const ()) });
    let functions = Fmi2CallbackFunctions {
        logger,
        allocate_memory: None,
        free_memory: None,
        step_finished: None,
        component_environment: &*log as *const Messages as *mut c_void,
    };
    let (uri, guid) = (
        CString::new(uri).unwrap(),
        CString::new(file_of(&res).token).unwrap(),
    );
    let c = unsafe {
        fmi2Instantiate(
            c"c2".as_ptr(),
            FMI2_COSIMULATION,
            guid.as_ptr(),
            uri.as_ptr(),
            &functions,
            0,
            0,
        )
    };
    assert!(!c.is_null(), "{:?}", log.lock().unwrap());
    let layout = Layout::new(&file_of(&res)).unwrap();
    let vrs = layout.vrs(|r| matches!(r, Role::State(_)));
    let u_vr = layout.vr("u").unwrap();
    let xs = states(10);
    let want = commands_by_hand(&res, &xs, [0.3, 0.0]);
    unsafe {
        assert_eq!(fmi2SetupExperiment(c, 0, 0.0, 0.0, 0, 0.0), OK);
        assert_eq!(fmi2EnterInitializationMode(c), OK);
        assert_eq!(fmi2ExitInitializationMode(c), OK);
        for (k, x) in xs.iter().enumerate() {
            assert_eq!(fmi2SetReal(c, vrs.as_ptr(), 2, x.as_ptr()), OK);
            assert_eq!(fmi2DoStep(c, 0.02 * k as f64, 0.02, 1), OK);
            let mut u = f64::NAN;
            assert_eq!(fmi2GetReal(c, &u_vr, 1, &mut u), OK);
            assert_eq!(u.to_bits(), want[k].to_bits());
        }
        let bad = [f64::NAN, 0.0];
        assert_eq!(fmi2SetReal(c, vrs.as_ptr(), 2, bad.as_ptr()), ERROR);
        assert!(log.lock().unwrap().last().unwrap().1.contains("finite"));
        assert_eq!(fmi2DoStep(c, 1.0, 0.02, 1), ERROR);
        assert_eq!(fmi2GetFMUstate(c, std::ptr::null_mut()), ERROR);
        fmi2FreeInstance(c);
    }
    // A model-exchange instantiation is refused with a message.
    let c = unsafe {
        fmi2Instantiate(
            c"me".as_ptr(),
            0,
            guid.as_ptr(),
            uri.as_ptr(),
            &functions,
            0,
            0,
        )
    };
    assert!(c.is_null());
    assert!(log
        .lock()
        .unwrap()
        .last()
        .unwrap()
        .1
        .contains("model exchange"));
}

/// The resident set size of this process in kB.
fn rss_kb() -> u64 {
    let s = std::fs::read_to_string("/proc/self/status").unwrap();
    let line = s.lines().find(|l| l.starts_with("VmRSS:")).unwrap();
    line.split_whitespace().nth(1).unwrap().parse().unwrap()
}

#[test]
fn a_thousand_instantiate_free_cycles_do_not_grow_the_resident_set() {
    let _g = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    // A model whose instance (weights + condensed QP) is ~0.5 MB: a leak of one per cycle
    // would add ~500 MB over 1000 cycles.
    let res = resources("rss", 128, 0.1, 2.0);
    let cycle = |steps: usize| {
        let f = Fmu3::new(&res).unwrap();
        f.init();
        for k in 0..steps {
            f.set(&["theta", "theta_dot"], &[0.5, 0.1 * k as f64]);
            assert_eq!(f.step(0.02 * k as f64), OK);
        }
    };
    for _ in 0..50 {
        cycle(2);
    }
    let before = rss_kb();
    for _ in 0..1000 {
        cycle(2);
    }
    let after = rss_kb();
    let grown = after.saturating_sub(before);
    eprintln!("RSS before {before} kB, after 1000 cycles {after} kB (+{grown} kB)");
    assert!(
        grown < 8 * 1024,
        "RSS grew by {grown} kB over 1000 instantiate/free cycles"
    );
}
