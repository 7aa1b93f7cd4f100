"""Checkpoints on disk: a pytree's leaves by name (``leaves``) and orbax's save and
restore of a run's training state (``checkpoint``). Imports no other room of ``train``."""
