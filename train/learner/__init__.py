"""The PPO learner: its state, losses, programs over devices, periodic evaluation, and
one seed's policy restored from a checkpoint. Imports the trainer's config
(``train.config``, ``train.config_loading``) and ``train.store`` only."""
