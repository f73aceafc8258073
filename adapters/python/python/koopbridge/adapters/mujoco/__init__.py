"""The MuJoCo adapter: the Franka Panda (``model``: robosuite's MJCF edited for koopbridge,
``sim``: the simulator, ``ik``: figure-8 joint references; ``python -m koopbridge.adapters.mujoco``)."""
