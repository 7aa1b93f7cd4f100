"""Tracking metrics that separate what a controller can fix from what it cannot, and the
paired statistics that decide whether one controller beats another.

Raw RMSE against the command is dominated by command steps (a robot with torque limits
needs time to get there) and by commands beyond the wheels' reach (no controller gets
there). So besides it:

- **steady-state error** (``ss_*``): RMSE over the control steps at least ``settle_s``
  after each command change, against the command's *nearest feasible twist for the true
  robot* (its actual wheel radii and rate limits). This is the error a good controller
  drives toward zero.
- **settling time** (``settle_lin_s``, ``settle_wz_s``): after each command step that
  changes that axis class's target by at least ``min_step_lin`` / ``min_step_wz``, the
  time until the twist enters, and stays inside, a band around the feasible target
  (``band_fraction`` of the step, at least ``band_lin`` / ``band_wz``); a segment that
  never settles counts its whole length.
- **energy** per episode, per metre travelled, and the part spent in the wheels' null
  space (torque that produces no body wrench: wheels fighting each other).

Every metric is kept per episode as a numerator and a denominator (:class:`Part`), so a
policy and a reference evaluated on the same episodes can be compared by a paired
bootstrap of the ratio of their pooled values (:func:`paired_ratio`); a controller beats
another only where the whole interval lies on the better side (:func:`verdict`).
"""

from __future__ import annotations

import dataclasses
from typing import Literal, NamedTuple

import numpy as np

from mecanum_jax.config import require


@dataclasses.dataclass(frozen=True)
class MetricConfig:
    """Settings of the steady-state and settling metrics."""

    settle_s: float = 0.5
    """Steady state starts this long after a command change, s."""
    band_fraction: float = 0.1
    """Settling band: this fraction of the step in the feasible target."""
    band_lin: float = 0.05
    """Smallest settling band of the linear velocity, m/s."""
    band_wz: float = 0.1
    """Smallest settling band of the yaw rate, rad/s."""
    min_step_lin: float = 0.1
    """A command change counts as a linear step from this size on, m/s."""
    min_step_wz: float = 0.2
    """A command change counts as a yaw-rate step from this size on, rad/s."""

    def validate(self, where: str = "metrics") -> MetricConfig:
        """Check values; raise :class:`~mecanum_jax.config.ConfigError` naming the field."""
        names = ("settle_s", "band_lin", "band_wz", "min_step_lin", "min_step_wz")
        require(self, where, names, lambda v: np.isfinite(v) and v >= 0, "must be finite, >= 0")
        require(self, where, ("band_fraction",), lambda v: 0 <= v < 1, "must be in [0, 1)")
        return self


class Part(NamedTuple):
    """One metric per episode: ``value = f(Σ num / Σ den)``, ``f`` the square root for an
    RMS (``kind = "rms"``), the identity for a mean or a ratio (``kind = "mean"``)."""

    num: np.ndarray  # (E,)
    den: np.ndarray  # (E,)
    kind: Literal["rms", "mean"]

    def value(self) -> float | None:
        den = float(np.sum(self.den))
        if den <= 0:
            return None
        v = float(np.sum(self.num)) / den
        return float(np.sqrt(v)) if self.kind == "rms" else v


def steps_since_change(command: np.ndarray) -> np.ndarray:
    """(E, T) control steps since the command last changed (0 on the step of a change; the
    first step counts as a change, from rest)."""
    changed = np.ones(command.shape[:2], bool)
    changed[:, 1:] = np.any(command[:, 1:] != command[:, :-1], axis=-1)
    t = np.arange(command.shape[1])
    last = np.maximum.accumulate(np.where(changed, t, 0), axis=1)
    return t - last


def segment_ids(command: np.ndarray) -> np.ndarray:
    """(E, T) index of the constant-command segment each step belongs to."""
    return np.cumsum(steps_since_change(command) == 0, axis=1) - 1


def settling_times(
    error: np.ndarray,
    step_size: np.ndarray,
    seg: np.ndarray,
    dt: float,
    band_fraction: float,
    band_min: float,
    min_step: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Per episode, the sum and the count of the settling times (s) of the segments whose
    step is at least ``min_step``.

    ``error`` (E, T): distance of the twist from the segment's target at the end of each
    step; ``step_size`` (E, T): the size of the step that began the segment (constant over
    it); ``seg`` (E, T): segment ids. The settling time of a segment is the time, from the
    command change, of the first sample after which the twist stays in the band (samples
    come at the end of each step; ``dt`` when it never leaves the band); a segment whose
    last sample is outside counts its whole length."""
    E, T = error.shape
    band = np.maximum(band_fraction * step_size, band_min)
    outside = error > band
    n_seg = int(seg.max()) + 1 if seg.size else 0
    rows = np.repeat(np.arange(E), T)
    pos = np.tile(np.arange(T), E)
    first = np.full((E, n_seg), T, np.int64)
    np.minimum.at(first, (rows, seg.ravel()), pos)
    last_out = np.full((E, n_seg), -1, np.int64)
    flat_out = outside.ravel()
    np.maximum.at(last_out, (rows[flat_out], seg.ravel()[flat_out]), pos[flat_out])
    length = np.zeros((E, n_seg), np.int64)
    np.add.at(length, (rows, seg.ravel()), 1)
    size = np.zeros((E, n_seg))
    size[rows, seg.ravel()] = step_size.ravel()
    present = first < T
    settle = np.minimum(np.where(last_out >= 0, last_out - first + 2, 1), length) * dt
    counted = present & (size >= min_step)
    return np.sum(np.where(counted, settle, 0.0), axis=1), np.sum(counted, axis=1).astype(float)


def null_space_projector(jacobian: np.ndarray) -> np.ndarray:
    """(n, n) projector onto the wheel torques that produce no body wrench: the null space
    of ``Jᵀ`` for the inverse-kinematics matrix ``J`` (n, 3), ``rates = J · twist``."""
    J = np.asarray(jacobian, np.float64)
    return np.eye(J.shape[0]) - J @ np.linalg.pinv(J)


def episode_parts(
    command: np.ndarray,
    target: np.ndarray,
    twist: np.ndarray,
    pose: np.ndarray,
    start: np.ndarray,
    energy_j: np.ndarray,
    saturated: np.ndarray,
    wheel_torque: np.ndarray,
    wheel_rate: np.ndarray,
    jacobian: np.ndarray,
    dt: float,
    cfg: MetricConfig | None = None,
) -> dict[str, Part]:
    """Every metric of one rollout, per episode (arrays as in ``evaluation.Trace``)."""
    cfg = cfg or MetricConfig()
    E = command.shape[0]
    out = tracking_parts(command, target, twist, dt, cfg)
    out.update(_settling_parts(command, target, twist, dt, cfg))
    out.update(_energy_parts(pose, start, energy_j, wheel_torque, wheel_rate, jacobian, dt))
    out["saturated"] = Part(np.mean(saturated, axis=1), np.ones(E), "mean")
    return out


def steady_mask(command: np.ndarray, dt: float, cfg: MetricConfig) -> np.ndarray:
    """1 on the control steps at least ``settle_s`` after a command change, else 0: the
    steps the steady-state metrics count."""
    since = steps_since_change(command)
    return ((since + 1) * dt >= cfg.settle_s - 1e-9).astype(float)


def tracking_parts(
    command: np.ndarray, target: np.ndarray, twist: np.ndarray, dt: float, cfg: MetricConfig
) -> dict[str, Part]:
    """Raw RMSE against the command and steady-state RMSE against the feasible target."""
    T = command.shape[1]
    full = np.full(command.shape[0], float(T))
    out: dict[str, Part] = {}
    err = twist - command
    for i, axis in enumerate(("vx", "vy", "wz")):
        out[f"rmse_{axis}"] = Part(np.sum(err[..., i] ** 2, axis=1), full, "rms")
    out["rmse_lin"] = Part(np.sum(err[..., 0] ** 2 + err[..., 1] ** 2, axis=1), full, "rms")
    steady = steady_mask(command, dt, cfg)
    ss = twist - target
    count = np.sum(steady, axis=1)
    for i, axis in enumerate(("vx", "vy", "wz")):
        out[f"ss_{axis}"] = Part(np.sum(steady * ss[..., i] ** 2, axis=1), count, "rms")
    lin2 = ss[..., 0] ** 2 + ss[..., 1] ** 2
    out["ss_lin"] = Part(np.sum(steady * lin2, axis=1), count, "rms")
    return out


def _settling_parts(
    command: np.ndarray, target: np.ndarray, twist: np.ndarray, dt: float, cfg: MetricConfig
) -> dict[str, Part]:
    """Settling times after the command steps, translation and spin apart."""
    T = command.shape[1]
    since = steps_since_change(command)
    ss = twist - target
    seg = segment_ids(command)
    previous = np.concatenate([np.zeros_like(target[:, :1]), target[:, :-1]], axis=1)
    jump = np.where((since == 0)[..., None], target - previous, 0.0)
    # the step that began each step's segment, spread over the segment
    first_idx = np.arange(T)[None, :] - since
    jump = np.take_along_axis(jump, first_idx[..., None], axis=1)
    lin_err = np.sqrt(ss[..., 0] ** 2 + ss[..., 1] ** 2)
    lin_step = np.hypot(jump[..., 0], jump[..., 1])
    lin = settling_times(
        lin_err, lin_step, seg, dt, cfg.band_fraction, cfg.band_lin, cfg.min_step_lin
    )
    wz = settling_times(
        np.abs(ss[..., 2]), np.abs(jump[..., 2]), seg, dt, cfg.band_fraction, cfg.band_wz,
        cfg.min_step_wz,
    )  # fmt: skip
    return {"settle_lin_s": Part(*lin, "mean"), "settle_wz_s": Part(*wz, "mean")}


def _energy_parts(
    pose: np.ndarray,
    start: np.ndarray,
    energy_j: np.ndarray,
    wheel_torque: np.ndarray,
    wheel_rate: np.ndarray,
    jacobian: np.ndarray,
    dt: float,
) -> dict[str, Part]:
    """Energy per episode and per metre travelled, and the part spent in the null space."""
    ones = np.ones(pose.shape[0])
    energy = np.sum(energy_j, axis=1)
    xy = np.concatenate([start[:, None, :2], pose[..., :2]], axis=1)
    travelled = np.sum(np.linalg.norm(np.diff(xy, axis=1), axis=-1), axis=1)
    P = null_space_projector(jacobian)
    null_torque = np.einsum("ij,etj->eti", P, wheel_torque)
    null_power = np.sum(np.abs(null_torque * wheel_rate), axis=-1)
    return {
        "energy_j": Part(energy, ones, "mean"),
        "energy_per_m": Part(energy, travelled, "mean"),
        "null_energy_j": Part(np.sum(null_power, axis=1) * dt, ones, "mean"),
    }


class Comparison(NamedTuple):
    """``ratio`` = a's pooled value / b's, with a bootstrap interval ``[lo, hi]``."""

    ratio: float
    lo: float
    hi: float

    def as_dict(self) -> dict[str, float | str]:
        return {"ratio": self.ratio, "lo": self.lo, "hi": self.hi, "verdict": verdict(self)}


def bootstrap_weights(episodes: int, n_boot: int = 2000, seed: int = 0) -> np.ndarray:
    """(n_boot, episodes) counts of each episode in each bootstrap resample."""
    rng = np.random.default_rng(seed)
    return rng.multinomial(episodes, np.full(episodes, 1.0 / episodes), size=n_boot).astype(float)


def paired_ratio(
    a: Part,
    b: Part,
    n_boot: int = 2000,
    level: float = 0.95,
    seed: int = 0,
    weights: np.ndarray | None = None,
) -> Comparison | None:
    """Ratio of ``a``'s pooled metric to ``b``'s, both measured on the *same* episodes,
    with a percentile bootstrap interval: episodes are resampled with replacement, the same
    draw for both (a paired design). ``None`` where either is undefined (no steps counted,
    or a zero reference). ``weights``: :func:`bootstrap_weights` to reuse (then ``n_boot``
    and ``seed`` are theirs)."""
    if len(a.num) != len(b.num):
        raise ValueError(f"paired_ratio: {len(a.num)} episodes against {len(b.num)}")
    va, vb = a.value(), b.value()
    if va is None or vb is None or vb == 0:
        return None
    W = bootstrap_weights(len(a.num), n_boot, seed) if weights is None else weights  # (B, E)

    def pooled(p: Part) -> np.ndarray:
        den = W @ p.den
        with np.errstate(divide="ignore", invalid="ignore"):
            v = np.where(den > 0, (W @ p.num) / den, np.nan)
        return np.sqrt(v) if p.kind == "rms" else v

    with np.errstate(divide="ignore", invalid="ignore"):
        r = pooled(a) / pooled(b)
    r = r[np.isfinite(r)]
    if len(r) == 0:
        return None
    q = (1 - level) / 2
    lo, hi = np.quantile(r, [q, 1 - q])
    return Comparison(va / vb, float(lo), float(hi))


def bootstrap_interval(
    part: Part, n_boot: int = 2000, level: float = 0.95, seed: int = 0
) -> tuple[float, float] | None:
    """A percentile bootstrap interval of one controller's pooled metric: its episodes
    resampled with replacement (:func:`bootstrap_weights`). ``None`` where undefined."""
    W = bootstrap_weights(len(part.num), n_boot, seed)
    den = W @ part.den
    with np.errstate(divide="ignore", invalid="ignore"):
        v = np.where(den > 0, (W @ part.num) / den, np.nan)
    v = (np.sqrt(v) if part.kind == "rms" else v)[np.isfinite(v)]
    if len(v) == 0:
        return None
    q = (1 - level) / 2
    lo, hi = np.quantile(v, [q, 1 - q])
    return float(lo), float(hi)


def verdict(c: Comparison | None, lower_is_better: bool = True) -> str:
    """``"better"`` / ``"worse"`` only where the whole interval excludes 1; else ``"tie"``."""
    if c is None:
        return "n/a"
    if c.hi < 1:
        return "better" if lower_is_better else "worse"
    if c.lo > 1:
        return "worse" if lower_is_better else "better"
    return "tie"


def flicker_part(action: np.ndarray) -> Part:
    """Flicker: the mean ``|a_t − a_(t−1)|`` per control step and action entry, of actions
    (E, T, a) in [-1, 1] (0 for a controller without actions, the references)."""
    step = np.abs(np.diff(action, axis=1))  # (E, T-1, a)
    E, T1, a = step.shape
    return Part(np.sum(step, axis=(1, 2)), np.full(E, float(max(T1 * a, 1))), "mean")


def summary(parts: dict[str, Part]) -> dict[str, float | None]:
    return {k: p.value() for k, p in parts.items()}


__all__ = [
    "Comparison",
    "MetricConfig",
    "Part",
    "bootstrap_interval",
    "bootstrap_weights",
    "episode_parts",
    "flicker_part",
    "null_space_projector",
    "paired_ratio",
    "segment_ids",
    "settling_times",
    "steady_mask",
    "steps_since_change",
    "summary",
    "tracking_parts",
    "verdict",
]
