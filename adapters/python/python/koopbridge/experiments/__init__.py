"""Experiments run on the Python side of koopbridge: the Franka Panda's SPEC dataset
(``franka_data``) and its figure-8 tracking through the bridge (``figure8``)."""
