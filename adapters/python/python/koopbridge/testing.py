"""``check_adapter(sim)``: what an adapter author runs in a test to check a ``Simulator`` the way
the bridge will use it, in-process and served through a real Zenoh session to the Rust client."""

from __future__ import annotations

import socket
import threading
import uuid
from typing import Any, Self

import numpy as np

from ._native import Client, InvalidInput, RemoteError, Unsupported
from .serving import SimulatorAdapter
from .simulator import SimInfo, Simulator

__all__ = ["ServedOnThread", "check_adapter", "listening_client", "sample_inputs"]


def _fail(msg: str) -> None:
    raise AssertionError(f"check_adapter: {msg}")


def sample_inputs(info: SimInfo, n: int, seed: int) -> np.ndarray:
    """``n`` inputs drawn uniformly inside the bounds (an infinite side is taken 1 from the
    other, or ±1 when both are), deterministic by ``seed``; shape ``(n, nu)``."""
    lo, hi = np.array(info.u_min), np.array(info.u_max)
    lo2 = np.where(np.isfinite(lo), lo, np.where(np.isfinite(hi), hi - 1.0, -1.0))
    hi2 = np.where(np.isfinite(hi), hi, lo2 + np.where(np.isfinite(lo), 1.0, 2.0))
    return np.random.default_rng(seed).uniform(lo2, hi2, size=(n, info.nu))


def _state(x: Any, info: SimInfo, what: str) -> np.ndarray:
    a = np.asarray(x)
    if a.shape != (info.nx,):
        _fail(f"{what} returned shape {a.shape}, info says nx = {info.nx}")
    if not np.issubdtype(a.dtype, np.floating) or not np.all(np.isfinite(a)):
        _fail(f"{what} returned a non-finite or non-float state: {a}")
    return a.astype(np.float64)


def _run(sim: Simulator, info: SimInfo, us: np.ndarray, **reset: Any) -> np.ndarray:
    xs = [_state(sim.reset(**reset), info, f"reset({reset})")]
    for u in us:
        xs.append(_state(sim.step(u.copy()), info, "step(u)"))
    return np.array(xs)


def _raises(what: str, exc: type[BaseException], fn: Any, *args: Any) -> None:
    try:
        fn(*args)
    except exc:
        return
    except Exception as e:
        _fail(f"{what} raised {type(e).__name__}: {e}, expected {exc.__name__}")
    _fail(f"{what} raised nothing, expected {exc.__name__}")


def _free_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def listening_client(session: str, *, tries: int = 5) -> tuple[Client, str]:
    """A ``Client`` of ``session`` listening on a free loopback port, and that endpoint, for the
    peers (adapters, services) to ``connect`` to.

    The client binds before any peer starts, so nothing else can take the port between the probe
    and the bind unnoticed: a port taken in that gap fails the bind at once and another is tried
    (``tries`` in all). The other order (a peer listens, the client connects) fails only after
    the client's whole timeout, with nothing said about the peer's failed bind."""
    for attempt in range(tries):
        ep = _free_endpoint()
        try:
            return Client(session=session, listen=[ep]), ep
        except Exception as e:  # noqa: BLE001 - a taken port is the only expected failure
            if "Address already in use" not in str(e) or attempt + 1 == tries:
                raise
    raise AssertionError("unreachable")


class ServedOnThread:
    """``adapter.serve(**kw)`` on a background thread, as a context manager: started on entry,
    stopped and joined (10 s) on exit. ``stats`` is what serve() returned, ``error`` what it
    raised; an exception leaving the ``with`` block gets serve()'s failure added as a note (a
    client's timeout then names the failed bind behind it)."""

    def __init__(self, adapter: Any, **kw: Any) -> None:
        self.adapter = adapter
        self.stats: Any = None
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, kwargs=kw, daemon=True)

    def _run(self, **kw: Any) -> None:
        try:
            self.stats = self.adapter.serve(**kw)
        except BaseException as e:  # kept for the caller
            self.error = e

    def __enter__(self) -> Self:
        self.thread.start()
        return self

    def __exit__(self, exc_type: object, exc: BaseException | None, tb: object) -> None:
        if exc is not None and self.error is not None:
            exc.add_note(f"serve() on the background thread had failed: {self.error!r}")
        self.adapter.stop()
        self.thread.join(timeout=10)
        if self.thread.is_alive():
            _fail("serve() still running 10 s after stop()")


def check_adapter(sim: Simulator, *, seed: int = 1, steps: int = 5, atol: float = 1e-9, zenoh: bool = True, timeout: float = 20.0) -> SimInfo:
    """Checks ``sim`` as the bridge will use it; raises ``AssertionError`` naming the first
    problem, returns its ``SimInfo``. Leaves ``sim`` open (the caller closes it).

    In-process: ``info()`` is a valid ``SimInfo``; ``reset(seed=)`` then ``steps`` steps give
    finite ``nx``-vectors and the same states, bit for bit, on a second run; ``reset(x0=)`` at a
    state of that run returns it and the next step from there matches the run within ``atol``
    (the state is complete); a wrong-length input raises, and through ``SimulatorAdapter`` a
    wrong-length or NaN ``u`` and a wrong-length ``x0`` raise ``InvalidInput``. A simulator
    that raises ``Unsupported`` for a seeded reset is run from ``reset()``; one that refuses
    ``x0`` skips that check.

    With ``zenoh=True``, served on a real Zenoh session and driven by the Rust client: the
    ``info`` reply carries the same fields and ``extra``; reset and steps give the in-process
    states bit for bit; a repeated step request (same ``k``, same ``u``) is answered from the
    cache without stepping the simulator, another ``u`` for that ``k`` is a ``conflict``;
    wrong-length and NaN inputs are typed error replies after which serving goes on; a short
    free run publishes its states.
    """
    if not isinstance(sim, Simulator):
        _fail(f"{type(sim).__name__} is not a Simulator (needs info, reset, step)")
    info = sim.info()
    if not isinstance(info, SimInfo):
        _fail(f"info() returned {type(info).__name__}, expected a koopbridge.SimInfo")
    info.validate()
    if SimInfo.from_dict(info.to_dict()) != info:
        _fail("SimInfo does not survive to_dict/from_dict")
    us = sample_inputs(info, steps, seed)

    reset: dict[str, Any] = {"seed": seed}
    try:
        sim.reset(seed=seed)
    except Unsupported:
        reset = {}
    a = _run(sim, info, us, **reset)
    b = _run(sim, info, us, **reset)
    if not np.array_equal(a, b):
        _fail(f"two runs from reset({reset}) with the same inputs differ (max {np.max(np.abs(a - b)):.3g}): not deterministic")
    if reset and info.nx > 0:
        other = _state(sim.reset(seed=seed + 1), info, "reset(seed + 1)")
        if np.array_equal(other, a[0]):
            _fail(f"reset(seed={seed}) and reset(seed={seed + 1}) give the same state: the seed is ignored")

    k = steps // 2
    try:
        x0 = sim.reset(x0=a[k].copy())
    except Unsupported:
        x0 = None
    if x0 is not None:
        x0 = _state(x0, info, "reset(x0=)")
        if not np.allclose(x0, a[k], rtol=0, atol=atol):
            _fail(f"reset(x0=x) returned another state (max diff {np.max(np.abs(x0 - a[k])):.3g})")
        nxt = _state(sim.step(us[k].copy()), info, "step after reset(x0=)")
        if not np.allclose(nxt, a[k + 1], rtol=0, atol=atol):
            _fail(f"stepping from reset(x0=x_k) differs from the run by {np.max(np.abs(nxt - a[k + 1])):.3g}: the state does not determine the next one")

    sim.reset(**reset)
    try:
        sim.step(np.zeros(info.nu + 1))
    except Exception:
        pass
    else:
        _fail(f"step() accepted {info.nu + 1} input values, the simulator has {info.nu}")
    adapter = SimulatorAdapter(sim)
    adapter.reset(**reset)
    _raises("SimulatorAdapter.step(wrong length)", InvalidInput, adapter.step, np.zeros(info.nu + 1))
    if info.nu:
        _raises("SimulatorAdapter.step(NaN)", InvalidInput, adapter.step, np.full(info.nu, np.nan))
    _raises("SimulatorAdapter.reset(x0 of wrong length)", InvalidInput, lambda: adapter.reset(x0=np.zeros(info.nx + 1)))
    if zenoh:
        _check_served(adapter, info, us, a, reset, timeout)
    return info


def _check_served(adapter: SimulatorAdapter, info: SimInfo, us: np.ndarray, a: np.ndarray, reset: dict[str, Any], timeout: float) -> None:
    session, sim_id = "check" + uuid.uuid4().hex[:10], "sim0"
    client, ep = listening_client(session)
    served = ServedOnThread(adapter, session=session, id=sim_id, connect=[ep])
    with served, client as c:
        reply = c.connect_sim(sim_id, timeout=timeout)
        for key in ("env", "kind", "version", "state_names", "input_names", "angle_indices"):
            if reply[key] != getattr(info, key):
                _fail(f"info reply's {key} is {reply[key]!r}, the simulator says {getattr(info, key)!r}")
        if reply["dt"] != info.dt or reply.get("extra", {}) != info.extra:
            _fail("info reply's dt or extra differs from the simulator's SimInfo")
        x = c.reset(sim_id, **reset)
        if not np.array_equal(x, a[0]):
            _fail("reset over Zenoh differs from the in-process reset")
        for i, u in enumerate(us):
            k, t, x = c.step(sim_id, u)
            if k != i + 1 or not np.array_equal(x, a[i + 1]):
                _fail(f"step {i} over Zenoh: k = {k}, state differs from in-process by {np.max(np.abs(x - a[i + 1])):.3g}")
        n = len(us)
        if n:
            k, _, x = c.step_at(sim_id, n - 1, us[-1])
            if k != n or not np.array_equal(x, a[n]):
                _fail("a repeated step request was not answered with the first reply")
        if n and info.nu:
            try:
                c.step_at(sim_id, n - 1, us[-1] * 0.5 + 0.25)
                _fail("a repeated step k with another u was accepted")
            except RemoteError as e:
                if e.code != "conflict":
                    _fail(f"a repeated step k with another u gave {e.code}, expected conflict")
        for bad, code in ((np.zeros(info.nu + 1), "dimension"), (np.full(info.nu, np.nan), "bad_request")):
            if bad.size == 0:
                continue
            try:
                c.step(sim_id, bad)
                _fail(f"step with {bad} was accepted")
            except RemoteError as e:
                if e.code != code:
                    _fail(f"step with {bad} gave {e.code}, expected {code}")
        stats = c.connect_sim(sim_id, timeout=timeout)["stats"]
        if stats["steps"] != n or stats["cache_hits"] != (1 if n else 0):
            _fail(f"adapter counters after {n} steps and one repeat: {stats}")
        if n:
            k, _, _ = c.step(sim_id, us[0])
            if k != n + 1:
                _fail(f"after the refused requests the next step has k = {k}, expected {n + 1}")
    if served.error is not None:
        _fail(f"serve() did not end cleanly: {served.error}")
    stats = adapter.serve(session=session, id="free0", free_run=True, rate_hz=1000.0, steps=3, **reset)
    if stats["steps"] != 3 or stats["published"] != 4:
        _fail(f"free run of 3 steps: counters {stats}")
