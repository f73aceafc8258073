"""Clear errors naming the FMU: missing file, no co-simulation, unknown variable, failing doStep."""

from __future__ import annotations

import re
import zipfile

import numpy as np
import pytest

from koopbridge import InvalidInput, KoopbridgeError, Unsupported
from koopbridge.adapters.fmu.sim import FmuError, FmuSimulator


def test_missing_file(tmp_path):
    with pytest.raises(FmuError, match=r"FMU '.*nothing\.fmu': file not found"):
        FmuSimulator(str(tmp_path / "nothing.fmu"), ["u"], ["theta"])


def test_not_an_fmu(tmp_path):
    p = tmp_path / "junk.fmu"
    p.write_bytes(b"this is not a zip archive")
    with pytest.raises(FmuError, match=r"FMU 'junk\.fmu': cannot read its modelDescription\.xml"):
        FmuSimulator(str(p), ["u"], ["theta"])


def test_model_exchange_only(tmp_path, damped_fmu):
    # The same FMU with its CoSimulation element turned into ModelExchange.
    me = tmp_path / "me_only.fmu"
    with zipfile.ZipFile(damped_fmu) as src, zipfile.ZipFile(me, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename == "modelDescription.xml":
                text = data.decode()
                text = re.sub(r"<CoSimulation\s[^>]*/>", '<ModelExchange modelIdentifier="damped_pendulum"/>', text)
                data = text.encode()
            dst.writestr(item, data)
    with pytest.raises(FmuError, match=r"FMU 'me_only\.fmu': it has no co-simulation interface"):
        FmuSimulator(str(me), ["u"], ["theta"])


def test_unknown_variable(damped_fmu):
    with pytest.raises(FmuError, match=r"FMU 'damped_pendulum\.fmu': unknown variable 'phi' \(known: .*theta"):
        FmuSimulator(str(damped_fmu), ["u"], ["phi", "omega"])
    with pytest.raises(FmuError, match="unknown variable 'torque'"):
        FmuSimulator(str(damped_fmu), ["torque"], ["theta", "omega"])


def test_output_cannot_be_an_input(damped_fmu):
    with pytest.raises(FmuError, match="'theta' has causality 'output', it cannot be an input"):
        FmuSimulator(str(damped_fmu), ["theta"], ["omega"])


def test_failing_do_step_names_the_fmu_and_recovers(damped_fmu):
    sim = FmuSimulator(str(damped_fmu), ["u"], ["theta", "omega"], dt=0.02, initial=["theta0", "omega0"])
    sim.reset(x0=[0.3, 0.0])
    with pytest.raises(FmuError) as e:
        sim.step([np.nan])
    msg = str(e.value)
    assert "FMU 'damped_pendulum.fmu': doStep failed at t = 0 s" in msg
    assert "input u is not finite" in msg  # the FMU's own log message is quoted
    # Stepping again needs a reset; after it the FMU works as before.
    with pytest.raises(InvalidInput, match="not reset yet"):
        sim.step([0.0])
    x = sim.reset(x0=[0.3, 0.0])
    np.testing.assert_array_equal(x, [0.3, 0.0])
    assert np.all(np.isfinite(sim.step([1.0])))


def test_failing_initialisation_names_the_fmu(damped_fmu):
    sim = FmuSimulator(str(damped_fmu), ["u"], ["theta", "omega"], parameters={"l": 0.0})
    with pytest.raises(FmuError, match=r"FMU 'damped_pendulum\.fmu': reset failed .*l and m must be positive"):
        sim.reset()


def test_reset_requests_it_cannot_honour(damped_fmu):
    sim = FmuSimulator(str(damped_fmu), ["u"], ["theta", "omega"], initial=[])
    with pytest.raises(Unsupported, match="seeded reset needs an initial-state range"):
        sim.reset(seed=3)
    with pytest.raises(Unsupported, match="no initial-state variables"):
        sim.reset(x0=[0.1, 0.2])
    ok = FmuSimulator(str(damped_fmu), ["u"], ["theta", "omega"], initial=["theta0", "omega0"])
    with pytest.raises(InvalidInput, match="x0 must be 2 finite values"):
        ok.reset(x0=[0.1])
    assert issubclass(FmuError, KoopbridgeError)
