"""The trainer: run configs, the PPO learner, run directories, checkpoints and the CLIs."""

# Brax's training code calls jax.device_put_replicated, which JAX >= 0.10 removed; the
# trainer supplies it, so that importing the library (mecanum_jax) changes nothing.
from mecanum_jax import compat as _compat

_compat.install()
