//! Which program an external command line of a scenario runs: `{python}` resolved to a Python
//! that imports koopbridge, a relative path taken from the scenario's folder.

use std::path::{Path, PathBuf};

/// The program of an external adapter command run in folder `base`: `{python}` is the first of
/// `base/.venv/bin/python` (the venv of the scenario's repository), `$KOOPBRIDGE_PYTHON`, the
/// `.venv/bin/python` of a folder above this `koopbridge` binary (the repository it was built
/// in), `python3` from `PATH` if it imports koopbridge, else `python3` anyway (a path that does
/// not exist is passed over); the choice is printed once on standard error. A relative path with
/// a `/` is taken relative to `base`; a bare name is looked up in `PATH`.
pub fn external_program(first: &str, base: &Path) -> PathBuf {
    if first == "{python}" {
        static SAID: std::sync::Mutex<Vec<PathBuf>> = std::sync::Mutex::new(Vec::new());
        let imports = |py: &Path| {
            std::process::Command::new(py)
                .args(["-c", "import koopbridge"])
                .stdin(std::process::Stdio::null())
                .stdout(std::process::Stdio::null())
                .stderr(std::process::Stdio::null())
                .status()
                .is_ok_and(|s| s.success())
        };
        let env = std::env::var_os("KOOPBRIDGE_PYTHON");
        let exe = std::env::current_exe().ok();
        let (python, why) = python_for(base, env.as_deref(), exe.as_deref(), &imports);
        if let Ok(mut said) = SAID.lock() {
            if !said.contains(&python) {
                eprintln!("koopbridge: {{python}} is {} ({why})", python.display());
                said.push(python.clone());
            }
        }
        return python;
    }
    let p = Path::new(first);
    if p.is_relative() && first.contains('/') {
        return base.join(p);
    }
    p.to_path_buf()
}

/// The choice of [`external_program`] for `{python}` and why, given `$KOOPBRIDGE_PYTHON` (`env`),
/// the running binary (`exe`) and whether a Python imports koopbridge (`imports`).
fn python_for(
    base: &Path,
    env: Option<&std::ffi::OsStr>,
    exe: Option<&Path>,
    imports: &dyn Fn(&Path) -> bool,
) -> (PathBuf, String) {
    let venv = base.join(".venv/bin/python");
    if venv.is_file() {
        return (
            venv,
            format!("the venv of the scenario's repository {}", base.display()),
        );
    }
    let mut passed = String::new();
    if let Some(v) = env.filter(|v| !v.is_empty()) {
        let p = PathBuf::from(v);
        let found = if p.components().count() > 1 {
            p.is_file().then_some(p.clone())
        } else {
            std::env::var_os("PATH").and_then(|path| {
                std::env::split_paths(&path)
                    .map(|d| d.join(&p))
                    .find(|c| c.is_file())
            })
        };
        match found {
            Some(py) => return (py, "KOOPBRIDGE_PYTHON".into()),
            None => passed = format!("; KOOPBRIDGE_PYTHON={} does not exist", p.display()),
        }
    }
    if let Some(repo) = exe.and_then(|e| {
        e.ancestors()
            .skip(1)
            .find(|d| d.join(".venv/bin/python").is_file())
    }) {
        let why = format!(
            "the venv of {}, where this koopbridge was built{passed}",
            repo.display()
        );
        return (repo.join(".venv/bin/python"), why);
    }
    let python3 = PathBuf::from("python3");
    let why = if imports(&python3) {
        format!("python3 from PATH, which imports koopbridge{passed}")
    } else {
        format!("python3 from PATH, which does NOT import koopbridge: set KOOPBRIDGE_PYTHON to a Python that does{passed}")
    };
    (python3, why)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(p: &Path) -> PathBuf {
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, "").unwrap();
        p.to_path_buf()
    }

    #[test]
    fn python_is_the_scenario_venv_then_koopbridge_python_then_the_build_venv_then_python3() {
        let t = std::env::temp_dir().join(format!("kb-python-for-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&t);
        let (base, other) = (t.join("scenarios"), t.join("my-python"));
        let chosen = file(&t.join("envpy/bin/python"));
        let exe = t.join("build/target/release/koopbridge");
        let yes = |_: &Path| true;
        let no = |_: &Path| false;
        let env = Some(chosen.as_os_str());
        // Nothing found: python3, said to lack koopbridge unless it imports it.
        let (py, why) = python_for(&base, None, Some(&exe), &no);
        assert_eq!(py, PathBuf::from("python3"));
        assert!(why.contains("does NOT import koopbridge"), "{why}");
        assert!(python_for(&base, None, None, &yes)
            .1
            .contains("which imports koopbridge"));
        // KOOPBRIDGE_PYTHON is honoured; a missing one falls through (and is named).
        assert_eq!(
            python_for(&base, env, Some(&exe), &no),
            (chosen.clone(), "KOOPBRIDGE_PYTHON".into())
        );
        let missing = other.join("bin/python");
        let (py, why) = python_for(&base, Some(missing.as_os_str()), Some(&exe), &yes);
        assert_eq!(py, PathBuf::from("python3"));
        assert!(
            why.contains(&format!(
                "KOOPBRIDGE_PYTHON={} does not exist",
                missing.display()
            )),
            "{why}"
        );
        // The venv above the binary comes after KOOPBRIDGE_PYTHON, before python3.
        let build_venv = file(&t.join("build/.venv/bin/python"));
        assert_eq!(python_for(&base, env, Some(&exe), &no).0, chosen);
        let (py, why) = python_for(&base, Some(missing.as_os_str()), Some(&exe), &yes);
        assert_eq!(py, build_venv);
        assert!(
            why.contains("where this koopbridge was built") && why.contains("does not exist"),
            "{why}"
        );
        // The scenario repository's own venv comes first.
        let own = file(&base.join(".venv/bin/python"));
        assert_eq!(python_for(&base, env, Some(&exe), &no).0, own);
        assert_eq!(external_program("{python}", &base), own);
        std::fs::remove_dir_all(&t).unwrap();
    }
}
