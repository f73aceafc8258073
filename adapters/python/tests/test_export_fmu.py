"""`koopbridge export-fmu` checked by masters that are not ours: fmpy validates both FMUs (FMI 3
and FMI 2) and runs the closed loop with the project's damped-pendulum FMU, libcosim (through
libcosimpy) runs it too, and the commands are compared with the MPC service's closed loop from
the same x0 (real services over Zenoh, real FMUs, a model trained here)."""

from __future__ import annotations

import shutil
import subprocess
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

import koopbridge
from conftest import Child, free_endpoint, koopbridge_binary_or_skip

DT, STEPS, X0 = 0.02, 200, (-1.0, 0.1)
MPC_TOML = """\
reference = [0.0, 0.0]

[mpc]
horizon = 30
r = [1e-4]
u_min = [-8.0]
u_max = [8.0]
"""
MPC_SETTINGS = {"horizon": 30, "r": [1e-4], "u_min": [-8.0], "u_max": [8.0]}
# The bilinear MPC with the offset-free correction: stateful across solves (each measured state
# updates the correction), so the FMU and the service must see the same sequence of states.
OFFSET_FREE = {"mode": "trajectory", "radius": 1.0, "gain": [0.5, 0.5]}
OFFSET_FREE_TOML = '\n[offset_free]\nmode = "trajectory"\nradius = 1.0\ngain = [0.5, 0.5]\n'


def run(cmd: list, **kw) -> subprocess.CompletedProcess:
    r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, **kw)
    assert r.returncode == 0, f"{' '.join(map(str, cmd))}\n{r.stdout}\n{r.stderr}"
    return r


@pytest.fixture(scope="module")
def models(tmp_path_factory) -> dict[str, Path]:
    """A Koopman model and a bilinear model of the damped pendulum (SPEC's system, data where
    cos θ keeps its sign), trained briefly here, and the MPC file."""
    exe = koopbridge_binary_or_skip()
    d = tmp_path_factory.mktemp("export")
    run([exe, "data", "gen", "--env", "damped-pendulum", "--windows", "2800", "--train", "2000", "--val", "400",
         "--test", "400", "--x0-low=-1.5,-3", "--x0-high=1.5,3", "--u-bound", "8", "--out", d / "data"])
    common = ["--data", d / "data", "--iterations", "400", "--hidden", "64,64", "--n-mult", "4",
              "--validate-every", "200", "--threads", "1"]
    run([exe, "train", *common, "--out", d / "koopman"])
    run([exe, "train", "--model", "bilinear", *common, "--out", d / "bilinear"])
    (d / "mpc.toml").write_text(MPC_TOML)
    (d / "mpc-offset-free.toml").write_text(MPC_TOML + OFFSET_FREE_TOML)
    return {"exe": exe, "dir": d, "koopman": d / "koopman", "bilinear": d / "bilinear", "mpc": d / "mpc.toml"}


def export(models, kind: str, fmi: str, name: str, offset_free: bool = False) -> Path:
    out = models["dir"] / name
    flag = "--bilinear" if kind == "bilinear" else "--model"
    mpc = models["dir"] / "mpc-offset-free.toml" if offset_free else models["mpc"]
    run([models["exe"], "export-fmu", flag, models[kind], "--mpc", mpc, "--fmi", fmi, "--out", out,
         "--unit", "theta=rad", "--unit", "theta_dot=rad/s", "--unit", "u=N.m"])
    return out


class Slave:
    """A co-simulation FMU stepped by fmpy (FMI 2 or 3), addressed by variable names."""

    def __init__(self, path: Path, name: str) -> None:
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave
        from fmpy.fmi3 import FMU3Slave

        self.md = read_model_description(str(path))
        self.v3 = self.md.fmiVersion.startswith("3")
        self.dir = extract(str(path))
        cls = FMU3Slave if self.v3 else FMU2Slave
        self.fmu = cls(guid=self.md.guid, unzipDirectory=self.dir,
                       modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=name)
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.fmu.instantiate()

    def init(self, **params: float) -> None:
        if self.v3:
            self.fmu.enterInitializationMode(startTime=0.0)
        else:
            self.fmu.setupExperiment(startTime=0.0)
            self.fmu.enterInitializationMode()
        if params:
            self.set(list(params), list(params.values()))
        self.fmu.exitInitializationMode()

    def set(self, names, values) -> None:
        vrs = [self.vr[n] for n in names]
        (self.fmu.setFloat64 if self.v3 else self.fmu.setReal)(vrs, [float(v) for v in values])

    def get(self, names) -> list[float]:
        vrs = [self.vr[n] for n in names]
        return list((self.fmu.getFloat64 if self.v3 else self.fmu.getReal)(vrs))

    def step(self, t: float) -> None:
        self.fmu.doStep(t, DT)

    def close(self) -> None:
        self.fmu.terminate()
        self.fmu.freeInstance()
        shutil.rmtree(self.dir, ignore_errors=True)


def plant(damped_fmu: Path, name: str) -> Slave:
    p = Slave(damped_fmu, name)
    p.init(theta0=X0[0], omega0=X0[1])
    return p


def fmpy_closed_loop(controller: Path, damped_fmu: Path) -> tuple[np.ndarray, np.ndarray]:
    """The small fmpy master: each communication point reads the pendulum's state, hands it to the
    controller FMU, steps the controller (its command for this step), hands the command to the
    pendulum and steps it (Gauss-Seidel order: no shift)."""
    pend, ctrl = plant(damped_fmu, "pendulum"), Slave(controller, "controller")
    ctrl.init()
    xs, us = [], []
    for k in range(STEPS):
        t = k * DT
        x = pend.get(["theta", "omega"])
        ctrl.set(["theta", "theta_dot"], x)
        ctrl.step(t)
        (u,) = ctrl.get(["u"])
        pend.set(["u"], [u])
        pend.step(t)
        xs.append(x)
        us.append(u)
    pend.close()
    ctrl.close()
    return np.array(xs), np.array(us)


class Service:
    """`koopbridge serve mpc` with the model in its store, configured with the MPC file's
    settings, and a Client."""

    def __init__(self, models, kind: str, tmp: Path, session: str, offset_free: bool = False) -> None:
        store = tmp / "store"
        shutil.copytree(models[kind], store / "pend")
        self.ep = free_endpoint()
        cmd = [str(models["exe"]), "serve", "mpc", "--session", session, "--id", "s0", "--store", str(store),
               "--state-dir", str(tmp / "state"), "--listen", self.ep]
        self.child = Child(cmd, tmp / "serve.log")
        self.client = koopbridge.Client(session=session, connect=[self.ep])
        t_end = time.monotonic() + 30
        while True:
            try:
                extra = {"offset_free": OFFSET_FREE} if offset_free else {}
                self.client.configure_mpc("s0", "pend", **MPC_SETTINGS, **extra)
                break
            except koopbridge.BridgeTimeout:
                assert time.monotonic() < t_end, self.child.output()

    def solve(self, x) -> float:
        return float(self.client.solve("s0", list(x), [0.0, 0.0], model="pend", nu=1)["u"][0, 0])

    def close(self) -> None:
        self.client.close()
        self.child.__exit__()


def service_closed_loop(service: Service, damped_fmu: Path, delay: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The MPC service's closed loop on the same pendulum FMU from the same x0. With `delay` = 1
    the command solved from x_k is applied over the next step (the first step gets 0), as a
    Jacobi-type master does. Returns the states and the commands solved from them."""
    pend = plant(damped_fmu, "pendulum")
    xs, us, held = [], [], 0.0
    for k in range(STEPS):
        x = pend.get(["theta", "omega"])
        u = service.solve(x)
        pend.set(["u"], [held if delay else u])
        pend.step(k * DT)
        held = u
        xs.append(x)
        us.append(u)
    pend.close()
    return np.array(xs), np.array(us)


def test_export_writes_both_fmi_versions_and_fmpy_validates_them(models):
    from fmpy.validation import validate_fmu

    for fmi, platform in (("3", "x86_64-linux"), ("2", "linux64")):
        out = export(models, "koopman", fmi, f"controller{fmi}.fmu")
        problems = validate_fmu(str(out))
        assert problems == [], problems
        names = zipfile.ZipFile(out).namelist()
        assert f"binaries/{platform}/koopbridge_mpc.so" in names
        assert {"modelDescription.xml", "resources/controller.json", "resources/mpc.toml",
                "resources/model/config.json", "resources/model/model.safetensors"} <= set(names)
        from fmpy import read_model_description

        md = read_model_description(str(out))
        v = {x.name: x for x in md.modelVariables}
        assert (v["theta"].causality, v["theta"].unit) == ("input", "rad")
        assert (v["theta_dot_ref"].causality, float(v["theta_dot_ref"].start)) == ("input", 0.0)
        assert (v["u"].causality, v["u"].unit) == ("output", "N.m")
        assert (v["u_max_u"].causality, v["u_max_u"].variability, float(v["u_max_u"].start)) == ("parameter", "fixed", 8.0)
        assert int(v["horizon"].start) == 30 and float(v["r_u"].start) == 1e-4
        assert md.defaultExperiment.stepSize == str(DT) or float(md.defaultExperiment.stepSize) == DT
    # No partial file is left next to the output, and a bad MPC file writes nothing.
    bad = models["dir"] / "bad.toml"
    bad.write_text("[mpc]\nhorizn = 3\n")
    r = subprocess.run([str(models["exe"]), "export-fmu", "--model", str(models["koopman"]), "--mpc", str(bad),
                        "--out", str(models["dir"] / "bad.fmu")], capture_output=True, text=True)
    assert r.returncode != 0 and "horizn" in r.stderr, r.stderr
    assert not (models["dir"] / "bad.fmu").exists()
    assert not [p for p in models["dir"].iterdir() if ".tmp-" in p.name]


@pytest.mark.parametrize(
    "kind, fmi, offset_free", [("koopman", "3", False), ("bilinear", "3", False), ("bilinear", "2", False), ("bilinear", "3", True)]
)
def test_fmpy_closed_loop_reproduces_the_service_closed_loop(models, damped_fmu, tmp_path, session_id, kind, fmi, offset_free):
    controller = export(models, kind, fmi, f"{kind}{fmi}{'-of' * offset_free}.fmu", offset_free)
    xs, us = fmpy_closed_loop(controller, damped_fmu)
    service = Service(models, kind, tmp_path, session_id, offset_free)
    try:
        xs_s, us_s = service_closed_loop(service, damped_fmu)
    finally:
        service.close()
    np.testing.assert_allclose(us, us_s, rtol=0, atol=1e-9)
    np.testing.assert_allclose(xs, xs_s, rtol=0, atol=1e-9)
    assert np.max(np.abs(us)) > 0.1 and np.all(np.abs(us) <= 8.0)
    if kind == "bilinear":  # the regulation task: the pendulum comes to rest near the reference
        assert np.linalg.norm(xs[-1]) < np.linalg.norm(X0) / 2, xs[-1]


def test_bad_input_is_an_error_the_master_sees_and_missing_resources_fail_instantiate(models, tmp_path):
    from fmpy.fmi1 import FMICallException  # what fmpy raises for a status >= error (FMI 1, 2 and 3)

    controller = export(models, "koopman", "3", "bad3.fmu")
    ctrl = Slave(controller, "controller")
    ctrl.init()
    ctrl.set(["theta", "theta_dot"], [0.1, 0.0])
    ctrl.step(0.0)
    with pytest.raises(FMICallException):
        ctrl.set(["theta"], [float("nan")])
    with pytest.raises(FMICallException):
        ctrl.step(DT)
    ctrl.fmu.freeInstance()
    # A parameter out of range is refused when set.
    ctrl = Slave(controller, "controller")
    ctrl.fmu.enterInitializationMode(startTime=0.0)
    with pytest.raises(FMICallException):
        ctrl.set(["q_theta"], [-1.0])
    ctrl.fmu.freeInstance()
    # Resources without the model's weights: instantiate fails, naming the file (logged).
    d = tmp_path / "broken"
    zipfile.ZipFile(controller).extractall(d)
    (d / "resources" / "model" / "model.safetensors").unlink()
    messages = []
    from fmpy import read_model_description
    from fmpy.fmi3 import FMU3Slave

    md = read_model_description(str(controller))
    fmu = FMU3Slave(guid=md.guid, unzipDirectory=str(d), modelIdentifier="koopbridge_mpc", instanceName="x")
    with pytest.raises(Exception, match="Failed to instantiate"):  # fmpy's own exception type
        fmu.instantiate(logMessage=lambda env, status, cat, msg: messages.append(msg.decode()))
    assert any("model.safetensors" in m for m in messages), messages


def libcosim_closed_loop(controller: Path, damped_fmu: Path) -> tuple[np.ndarray, np.ndarray]:
    """The closed loop run by libcosim's fixed-step master: both FMUs step over [t_k, t_k + dt)
    at once and their outputs reach the other's inputs at t_k + dt, so the command solved from
    x_k drives the pendulum over the next step. Returns the states x_k and those commands."""
    from libcosimpy._internal import get_last_error_message
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    ex = CosimExecution.from_step_size(step_size=int(round(DT * 1e9)))
    slaves = [CosimLocalSlave(fmu_path=str(p), instance_name=n) for p, n in ((damped_fmu, "pendulum"), (controller, "controller"))]
    # libcosimpy hands a NULL slave on to libcosim (a segfault): check it first.
    assert all(s.ptr() for s in slaves), get_last_error_message()
    pend, ctrl = (ex.add_local_slave(s) for s in slaves)
    assert pend >= 0 and ctrl >= 0, get_last_error_message()
    pvr = {v.name.decode(): v.reference for v in ex.slave_variables(pend)}
    cvr = {v.name.decode(): v.reference for v in ex.slave_variables(ctrl)}
    assert ex.real_initial_value(pend, pvr["theta0"], X0[0]) and ex.real_initial_value(pend, pvr["omega0"], X0[1])
    for a, b in (("theta", "theta"), ("omega", "theta_dot")):
        assert ex.connect_real_variables(pend, pvr[a], ctrl, cvr[b]) == 0  # libcosimc: 0 is success
    assert ex.connect_real_variables(ctrl, cvr["u"], pend, pvr["u"]) == 0
    obs = CosimObserver.create_last_value()
    ex.add_observer(obs)
    xs, us = [list(X0)], []
    for _ in range(STEPS):
        assert ex.step(), "libcosim step failed"
        xs.append(obs.last_real_values(pend, [pvr["theta"], pvr["omega"]]))
        us.append(obs.last_real_values(ctrl, [cvr["u"]])[0])
    return np.array(xs[:-1]), np.array(us)


def test_libcosim_closed_loop_reproduces_the_service_closed_loop_shifted_by_one_step(
    models, damped_fmu, tmp_path, session_id
):
    pytest.importorskip("libcosimpy")
    from libcosimpy._internal import get_last_error_message
    from libcosimpy.CosimSlave import CosimLocalSlave

    # libcosim loads FMI 1 and 2 only: the FMI 3 export is refused with this message (as is the
    # project's own FMI 3 double-pendulum FMU), so libcosim runs the FMI 2 export.
    fmi3 = CosimLocalSlave(fmu_path=str(export(models, "bilinear", "3", "bilinear3-cosim.fmu")), instance_name="c3")
    assert not fmi3.ptr() and "Unsupported FMI version" in get_last_error_message()
    controller = export(models, "bilinear", "2", "bilinear2-cosim.fmu")
    xs, us = libcosim_closed_loop(controller, damped_fmu)
    service = Service(models, "bilinear", tmp_path, session_id)
    try:
        xs_s, us_s = service_closed_loop(service, damped_fmu, delay=1)
    finally:
        service.close()
    np.testing.assert_allclose(us, us_s, rtol=0, atol=1e-9)
    np.testing.assert_allclose(xs, xs_s, rtol=0, atol=1e-9)
    assert np.max(np.abs(us)) > 0.1
