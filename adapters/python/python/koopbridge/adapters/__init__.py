"""Simulator adapters shipped with the koopbridge Python package, one subpackage per simulator
family, each a ``Simulator`` served by ``run_main``:

- ``fmu``: any FMI 2.0 / 3.0 co-simulation FMU (``python -m koopbridge.adapters.fmu``);
- ``mujoco``: the Franka Panda in MuJoCo (``python -m koopbridge.adapters.mujoco``);
- ``legged``: legged robots in MuJoCo, the shared pieces and ``legged.go2`` (the Unitree Go2,
  ``python -m koopbridge.adapters.go2``) and ``legged.g1`` (the Unitree G1, ``python -m
  koopbridge.adapters.g1``);
- ``drake``: the Kinova Gen3 in Drake, its planner and data collection (``python -m
  koopbridge.adapters.drake_sim``, ``drake_planner``, ``drake_collect``);
- ``gym``: any Gymnasium environment with a Box action space (``python -m koopbridge.adapters.gym``).

``go2``, ``g1``, ``drake_sim``, ``drake_planner`` and ``drake_collect`` here are aliases of those
command lines; ``state_memory`` is shared by the MuJoCo-based simulators that restore states
exactly (legged, gym)."""
