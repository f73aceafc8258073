"""The Kinova Gen3 in Drake (``model``: the arm's MJCF and limits, ``sim``: the simulator,
``plan``: two-pass trajectory optimisation, ``planner``: the planner service, ``windows``: windows
from planned trajectories, ``collect``: the Kinova datasets; ``python -m
koopbridge.adapters.drake_sim`` / ``drake_planner`` / ``drake_collect``)."""
