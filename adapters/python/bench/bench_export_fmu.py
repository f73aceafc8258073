"""The exported controller FMU's ``doStep`` through fmpy against the MPC service's solve for the
same model, in one run (issue 27, §3): the FMU should cost the solve plus microseconds, with no
Zenoh round trip.

The closed loop of the damped-pendulum FMU with the controller FMU (fmpy, Gauss-Seidel) gives the
states; the same states are then sent to ``koopbridge serve mpc`` (configured with the same MPC
file) through ``koopbridge.Client``. Blocks of ``--block`` steps alternate between the two so that
a change of machine load hits both. Reported per step (median, p90, in microseconds): the FMU's
``doStep`` call (fmpy's ctypes call included), the service's own solve time (what the service
measures inside), and the Client's round trip. Run it on a quiet machine:

    .venv/bin/python adapters/python/bench/bench_export_fmu.py --model models/damped --mpc mpc.toml
    .venv/bin/python adapters/python/bench/bench_export_fmu.py --bilinear models/damped-bil --mpc mpc.toml
"""

from __future__ import annotations

import argparse
import json
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import numpy as np

import koopbridge

ROOT = Path(__file__).resolve().parents[3]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument("--model", type=Path, help="a lifted model folder (koopbridge train)")
    g.add_argument("--bilinear", type=Path, help="a bilinear model folder (koopbridge train --model bilinear)")
    ap.add_argument("--mpc", type=Path, help="the MPC file of koopbridge export-fmu (TOML)")
    ap.add_argument("--fmi", default="3", choices=["3", "2"])
    ap.add_argument("--steps", type=int, default=2000, help="closed-loop steps (the pendulum restarts every 200)")
    ap.add_argument("--block", type=int, default=100, help="steps per alternation block")
    ap.add_argument("--x0", default="-1.0,0.1", help="the pendulum's initial state")
    ap.add_argument("--exe", type=Path, default=ROOT / "target" / "release" / "koopbridge")
    args = ap.parse_args()
    import tomllib

    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    from fmpy.fmi3 import FMU3Slave

    tmp = Path(tempfile.mkdtemp(prefix="bench-export-fmu-"))
    model = args.bilinear or args.model
    fmu_path = tmp / "controller.fmu"
    cmd = [str(args.exe), "export-fmu", "--bilinear" if args.bilinear else "--model", str(model),
           "--fmi", args.fmi, "--out", str(fmu_path)]
    if args.mpc:
        cmd += ["--mpc", str(args.mpc)]
    subprocess.run(cmd, check=True)
    settings = tomllib.loads(args.mpc.read_text()) if args.mpc else {}
    reference = settings.get("reference", [0.0, 0.0])

    def slave(path: Path, name: str):
        md = read_model_description(str(path))
        cls = FMU3Slave if md.fmiVersion.startswith("3") else FMU2Slave
        f = cls(guid=md.guid, unzipDirectory=extract(str(path)), modelIdentifier=md.coSimulation.modelIdentifier,
                instanceName=name)
        f.instantiate()
        return f, {v.name: v.valueReference for v in md.modelVariables}, md.fmiVersion.startswith("3")

    ctrl, cvr, v3 = slave(fmu_path, "controller")
    if v3:
        ctrl.enterInitializationMode(startTime=0.0)
    else:
        ctrl.setupExperiment(startTime=0.0)
        ctrl.enterInitializationMode()
    ctrl.exitInitializationMode()
    cset = ctrl.setFloat64 if v3 else ctrl.setReal
    cget = ctrl.getFloat64 if v3 else ctrl.getReal
    x_vrs = [v for n, v in cvr.items() if n in ("theta", "theta_dot", "x0", "x1")][:2]
    u_vr = cvr["u"] if "u" in cvr else cvr["u0"]
    pend_fmu = ROOT / "adapters" / "fmu" / "build" / "damped_pendulum.fmu"
    x0 = [float(v) for v in args.x0.split(",")]

    def new_pendulum():
        p, pvr, _ = slave(pend_fmu, "pendulum")
        p.setupExperiment(startTime=0.0)
        p.enterInitializationMode()
        p.setReal([pvr["theta0"], pvr["omega0"]], x0)
        p.exitInitializationMode()
        return p, pvr

    store = tmp / "store"
    shutil.copytree(model, store / "m")
    session = "bench" + uuid.uuid4().hex[:8]
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        ep = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    serve = subprocess.Popen([str(args.exe), "serve", "mpc", "--session", session, "--id", "s0", "--store", str(store),
                              "--state-dir", str(tmp / "state"), "--listen", ep], stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
    client = koopbridge.Client(session=session, connect=[ep])
    try:
        t_end = time.monotonic() + 30
        while True:
            try:
                client.configure_mpc("s0", "m", **settings.get("mpc", {}),
                                     **({"offset_free": settings["offset_free"]} if "offset_free" in settings else {}))
                break
            except koopbridge.BridgeTimeout:
                if time.monotonic() > t_end:
                    raise
        do_step, solve_in, round_trip = [], [], []
        pend, pvr = new_pendulum()
        t = 0.0
        for start in range(0, args.steps, args.block):
            # FMU block: the closed loop through fmpy; its states are replayed to the service.
            states = []
            for k in range(start, min(start + args.block, args.steps)):
                if k % 200 == 0 and k > 0:
                    pend.terminate()
                    pend.freeInstance()
                    pend, pvr = new_pendulum()
                    t = 0.0
                x = list(pend.getReal([pvr["theta"], pvr["omega"]]))
                states.append(x)
                cset(x_vrs, x)
                t0 = time.perf_counter_ns()
                ctrl.doStep(t, 0.02)
                do_step.append(time.perf_counter_ns() - t0)
                (u,) = cget([u_vr])
                pend.setReal([pvr["u"]], [u])
                pend.doStep(t, 0.02)
                t += 0.02
            # Service block: the same states.
            for x in states:
                t0 = time.perf_counter_ns()
                r = client.solve("s0", x, reference, model="m", nu=1)
                round_trip.append(time.perf_counter_ns() - t0)
                solve_in.append(r["solve_time"] * 1e9)
    finally:
        client.close()
        serve.kill()
        serve.wait()

    def stats(ns):
        a = np.array(ns, dtype=float) / 1e3
        return {"median_us": round(float(np.median(a)), 2), "p90_us": round(float(np.percentile(a, 90)), 2)}

    out = {
        "model": str(model),
        "fmi": args.fmi,
        "steps": args.steps,
        "fmu_doStep_via_fmpy": stats(do_step),
        "service_solve_inside": stats(solve_in),
        "service_round_trip_via_client": stats(round_trip),
    }
    out["doStep_minus_solve_median_us"] = round(
        out["fmu_doStep_via_fmpy"]["median_us"] - out["service_solve_inside"]["median_us"], 2
    )
    print(json.dumps(out, indent=2))
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
