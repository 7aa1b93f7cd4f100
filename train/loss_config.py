"""The settings of the losses added to PPO's (:mod:`train.learner.losses`): the smoothness
terms (``ppo.smoothness``) and the anchor (``ppo.anchor``); sections of
:class:`train.config_sections.PPOConfig`."""

from __future__ import annotations

import dataclasses

from mecanum_jax.config import require


@dataclasses.dataclass(frozen=True)
class SmoothnessConfig:
    """Weights of the CAPS-style terms (0: off) and the spatial perturbation's scale."""

    temporal: float = 1.0
    """Weight of ‖μ(s_t) − μ(s_{t+1})‖² (>= 0; 0: off)."""
    spatial: float = 10.0
    """Weight of ‖μ(s) − μ(s + ε)‖² (>= 0; 0: off)."""
    sigma: float = 0.02
    """Standard deviation of ε, in the policy observation's scaled units (> 0)."""

    def validate(self, where: str = "ppo.smoothness") -> None:
        """Check values; raise :class:`ConfigError` naming the field."""
        require(self, where, ("temporal", "spatial"), lambda v: v >= 0, "must be >= 0 (0: off)")
        require(self, where, ("sigma",), lambda v: v > 0, "must be > 0")

    @property
    def enabled(self) -> bool:
        return self.temporal > 0 or self.spatial > 0


@dataclasses.dataclass(frozen=True)
class AnchorConfig:
    """Weight of anchor_loss (0: off) and where it applies; needs a twist-space
    residual."""

    weight: float = 1000.0
    """Weight of the mean of μ_k(s)² over the states and components where the base is
    exact (>= 0; 0: off)."""
    spins: bool = True
    """Also every component on the nominal robot's steady pure spins (within reach) and
    stops, where the base holds v and ωz exactly; off: only ωz on steady no-yaw commands."""
    translations: bool = True
    """Also every component on the nominal robot's steady pure translations within reach,
    where the base's setpoints are analytic's; off: only their ωz."""

    def validate(self, where: str = "ppo.anchor") -> None:
        """Check values; raise :class:`ConfigError` naming the field."""
        require(self, where, ("weight",), lambda v: v >= 0, "must be >= 0 (0: off)")
        flags = ("spins", "translations")
        require(self, where, flags, lambda v: isinstance(v, bool), "must be true or false")

    @property
    def enabled(self) -> bool:
        return self.weight > 0


__all__ = ["AnchorConfig", "SmoothnessConfig"]
