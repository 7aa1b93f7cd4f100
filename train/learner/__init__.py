"""The PPO learner: its state, losses, programs over devices, periodic evaluation, and
one seed's policy restored from a checkpoint. Imports
``train.config`` and ``train.store`` only."""
