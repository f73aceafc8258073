"""The Unitree G1 humanoid (``model``: mjlab's model and holosoma's expert, ``sim``: the simulator;
``python -m koopbridge.adapters.g1``, an alias of ``python -m koopbridge.adapters.legged.g1``)."""
