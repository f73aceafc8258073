"""Legged robots in MuJoCo: the robot-agnostic pieces (``common``: floating-base state, PD drive,
falls; ``sim``: the shared simulator; ``policy``: the ONNX walking expert; ``collect``: expert
data; ``perturbation``: episode perturbations) and one subpackage per robot (``go2``, ``g1``)."""
