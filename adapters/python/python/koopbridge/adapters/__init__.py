"""Simulator adapters shipped with the koopbridge Python package (``fmu``: any FMI 2/3 CS FMU;
``mujoco``: the Franka Panda in MuJoCo), each a ``Simulator`` served by ``run_main``."""
