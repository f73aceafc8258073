"""The paper's experiments on top of koopbridge — data makers, reference writers, the hooks of the
legged, Franka, Kinova and Gymnasium scenarios, table writers and speed scripts; not part of the
``koopbridge`` wheel: ``scripts/setup-python.sh`` puts ``experiments/`` on the development venv's
path (``python -m koopbridge_experiments.MODULE --help``)."""
