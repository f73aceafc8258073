"""The viewer participant: follows a koopbridge session over Zenoh and shows it in Rerun
(``python -m koopbridge.view``; ``koopbridge run --view`` starts it)."""

from .logger import RunLogger, SimLayout, loop_path, state_groups

__all__ = ["RunLogger", "SimLayout", "loop_path", "state_groups"]
