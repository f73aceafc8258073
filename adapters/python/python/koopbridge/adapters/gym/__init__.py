"""The Gymnasium adapter: any Gymnasium environment with a Box action space (``sim``: the
simulator; ``python -m koopbridge.adapters.gym``)."""
