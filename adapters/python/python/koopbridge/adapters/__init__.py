"""Simulator adapters shipped with the koopbridge Python package (``fmu``: any FMI 2/3 CS FMU)."""
