"""The trainer: run configs, the PPO learner, run directories, checkpoints and the CLIs."""
