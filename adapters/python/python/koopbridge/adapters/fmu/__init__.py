"""The FMU adapter: any FMI 2.0 / 3.0 co-simulation FMU through fmpy (``sim``: the simulator,
``variables``: FMI variables as float64 components; ``python -m koopbridge.adapters.fmu``)."""
