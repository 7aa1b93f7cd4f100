"""The task's configuration: :class:`EnvConfig` and the configs it holds, each checking
its own values (:meth:`EnvConfig.validate` names the field of any bad value)."""

from __future__ import annotations

import dataclasses

import numpy as np

from mecanum_jax.config import from_mapping, invalid, require, validated_once
from mecanum_jax.sim.description import IMPLS, RobotDescription, resolve_description
from mecanum_jax.task.commands import CommandConfig
from mecanum_jax.task.observations import NoiseConfig
from mecanum_jax.task.randomization import RandomizationConfig
from mecanum_jax.task.references import FeedbackConfig
from mecanum_jax.task.reward import RewardConfig

RESIDUAL_SPACES = ("wheel", "twist")
RESIDUAL_BASES = ("analytic", "feedback")
MAX_OBS_HISTORY = 50
"""The most earlier sensor frames a policy may observe (1 s at the default 20 ms)."""
MAX_SUBSTEPS = 100
"""Physics steps per control period at most (the shipped config takes 4)."""


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """The task. robot is a built-in description name or a path to a TOML file.

    residual_space (with residual = true): "wheel", one correction per wheel
    (± residual_scale · max_rate); or "twist", a correction of the body twist
    (± residual_scale of the largest feasible vx, vy, ωz) mapped through the nominal
    inverse model, so the policy cannot drive the wheels against each other (the
    inverse model's null space, which squeezes the rollers and only costs energy);
    residual_scale is in (0, 2].

    residual_base (with residual = true): the controller the residual corrects.
    "analytic": the nominal inverse model, desaturated uniformly (the baseline).
    "feedback": the feedback reference controller (FeedbackConfig): the
    inverse model on the command plus a yaw-rate integral correction from the gyro, with
    anti-windup, projected onto the nearest feasible twist; the policy then also observes
    that integrator (feedback_integral), so the zero action *is* that controller and
    the policy carries a true integrator instead of a leaky one (residual RL on a classical
    loop, Johannink et al. 2019).

    solver_iterations > 0 overrides the description's Newton iterations (0: keep
    them); fewer than 12 let robots on slippery floors tip over (SimSpec.iterations).

    yaw_integral_tau > 0 adds an observation a real controller can compute: the leaky
    integral of the yaw-rate error the robot *measures*, I ← e^(−dt/τ)·I + (ω_cmd −
    gyro)·dt (gyro as observed: noisy, delayed), in units of τ times the largest
    feasible ωz. It gives a feedforward policy the memory an integral controller needs
    (measured with a probe since removed); 0 leaves it out.

    action_filter = f > 0 low-passes the actions: the action applied (and observed as
    last_action next step) is f·previous + (1 − f)·new. The wheels' reflected
    rotor inertia turns step-to-step changes of the setpoints into torque spikes that
    shake the chassis; a policy whose actions flicker by 0.03 makes the yaw rate swing by
    0.3 rad/s where a constant correction makes it swing by none.

    residual_at_stop = false turns the learned correction off while the command is a
    stop (every component exactly 0; a joystick's deadzone must send 0): the action is
    taken as 0 before the filter, so the applied correction fades with the filter and the
    base stops the robot as it would alone. On the nominal robot the base's stop returns
    the robot to where the commands put it (its wheels lag the command as much on the way
    down as on the way up); a correction that brakes harder leaves it short
    (docs/evaluation.md).

    residual_deadband = d > 0 soft-thresholds the network's action, before the stop rule
    and the filter: each component within ±d becomes 0, each beyond it moves d towards 0.
    On the nominal robot's straight lines, spins and starts a learned correction is a few
    thousandths of the bound and follows the sensor noise; in a fast start's wheel slip
    such a flicker turns into yaw kicks the base never gets (docs/controller.md). The
    deadband keeps the base's own setpoints there, as `feedback`'s deadband keeps its
    integrator from the gyro's noise.

    residual_ramp_s = T > 0 ramps the applied correction in after each command change:
    its gain grows from 0 to 1 over T s of the new command (the filter's memory with it),
    so that through a transient the base acts alone, as `feedback` does, and the learned
    correction only where a command is held (mecanum_jax.control.step.act).

    obs_history = H > 0 appends the H sensor frames before the observed one (encoders,
    gyro, accelerometer, odometry twist, as observed: noisy and as delayed as the current
    frame), newest first: the 0.5 to 1 s of history (25 to 50 frames at 20 ms) from which a
    student infers what a privileged teacher reads (friction, payload, motor gains).

    path_tau = τ > 0 adds the path error the robot measures against the commanded path:
    the position (x, y) and heading of the robot minus those of the command, in the
    commanded frame, integrated from the wheel odometry and the gyro as observed, leaky
    with τ (mecanum_jax.control.step.path_step); the critic sees the true one. It is what
    a scripted sequence's drift measures, which the twist alone cannot show.
    path_integrator = "exact" turns the commanded frame by each period's whole angle and
    follows the path of the command's nearest feasible twist (the critic's: the reward's
    target), so the error stays within the leak's bound; "euler", the shipped policy's,
    turns it to first order against the command itself: on fast spins it outgrows the leak,
    so the error grows for as long as such a command is held, and beyond reach it counts the
    part of the command no wheel can drive.

    symmetric = true averages the policy over the robot's mirror group (left-right,
    front-back, half turn; mecanum_jax.control.symmetry): a command a mirror leaves
    unchanged gets a correction that mirror leaves unchanged, exactly.
    """

    robot: str = "o_rectangle"
    """A built-in robot description (configs/robots) or a path to a description TOML."""
    control_dt: float = 0.02
    """Control period, s (> 0, a whole multiple of physics_timestep)."""
    physics_timestep: float = 0.005
    """MJX physics step, s (> 0; at most MAX_SUBSTEPS of them per control period)."""
    contact_timeconst: float = 0.01
    """Contact solver time constant, s (> 0; about 2 physics steps or more)."""
    solver_iterations: int = 0
    """Newton iterations of the physics solver (>= 0; 0: the description's)."""
    physics_impl: str = ""
    """MJX implementation: "jax", "warp" (needs the warp extra), or "" (the robot's sim.impl)."""
    episode_length: int = 500
    """Control steps per training episode (>= 1)."""
    residual: bool = True
    """Actions correct the analytic baseline's setpoints (false: actions are setpoints)."""
    residual_scale: float = 0.5
    """Largest residual correction, as a fraction of the largest wheel rate or twist (> 0)."""
    residual_space: str = "twist"
    """Where the residual acts: "wheel" (one per wheel) or "twist" (vx, vy, ωz)."""
    residual_base: str = "feedback"
    """What the residual corrects: "analytic" (the baseline) or "feedback" (the PI loop)."""
    yaw_integral_tau: float = 0.0
    """Time constant of the observed leaky yaw-rate error integral, s (>= 0; 0: off)."""
    residual_at_stop: bool = True
    """Whether the residual acts while the command is a stop (false: the base alone stops)."""
    action_filter: float = 0.7
    """Low-pass factor of the actions, f in [0, 1): applied = f·previous + (1 − f)·new (0: off)."""
    residual_deadband: float = 0.02
    """Soft threshold of the network's action, in its units, in [0, 1) (0: off)."""
    residual_ramp_s: float = 0.5
    """Seconds over which the correction ramps in after a command change (>= 0; 0: off)."""
    obs_history: int = 0
    """Earlier sensor frames the policy observes, one control period apart (0 to
    MAX_OBS_HISTORY; 0: none)."""
    path_tau: float = 3.0
    """Time constant of the observed leaky path error, s (>= 0; 0: off)."""
    path_integrator: str = "exact"
    """How the path error is kept: "exact" or "euler" (the shipped policy's; see above)."""
    symmetric: bool = False
    """The policy is averaged over the robot's mirror group (exactly equivariant)."""
    commands: CommandConfig = CommandConfig()
    """How commands are drawn."""
    randomization: RandomizationConfig = RandomizationConfig()
    """Per-robot domain randomization."""
    noise: NoiseConfig = NoiseConfig()
    """Sensor noise."""
    reward: RewardConfig = RewardConfig()
    """Reward scales."""
    feedback: FeedbackConfig = FeedbackConfig()
    """The feedback reference controller's gains."""

    def _validate_direct(self, where: str) -> None:
        """residual = false: every residual-only setting must be off. The first one set is
        named, with the others set beside it (the defaults are the shipped twist residual on
        ``feedback``: a direct-rate config sets several back, as quick.toml does)."""
        on = [
            (name, value)
            for name, value, off in (
                ("residual_space", self.residual_space, "wheel"),
                ("residual_at_stop", self.residual_at_stop, True),
                ("residual_deadband", self.residual_deadband, 0.0),
                ("residual_base", self.residual_base, "analytic"),
            )
            if value != off
        ]
        if on:
            name, value = on[0]
            also = ", ".join(f"{n} = {v!r}" for n, v in on[1:])
            more = f" (so do {also}: configs/train/quick.toml sets them back)" if also else ""
            raise invalid(f"{where}.{name}", value, "needs residual = true" + more)

    @validated_once  # each config once, however many layers ask
    def validate(self, where: str = "env") -> EnvConfig:
        """Check values (not only types); raise :class:`ConfigError` naming the field."""
        self._validate_timing(where)
        if self.physics_impl not in ("", *IMPLS):
            raise invalid(
                f"{where}.physics_impl", self.physics_impl, f"expected one of {['', *IMPLS]}"
            )
        if self.residual_space not in RESIDUAL_SPACES:
            raise invalid(
                f"{where}.residual_space", self.residual_space, f"expected one of {RESIDUAL_SPACES}"
            )
        if self.residual_base not in RESIDUAL_BASES:
            raise invalid(
                f"{where}.residual_base", self.residual_base, f"expected one of {RESIDUAL_BASES}"
            )
        if not self.residual:
            self._validate_direct(where)
        self.commands.validate(f"{where}.commands")
        self.randomization.validate(f"{where}.randomization")
        self.noise.validate(f"{where}.noise")
        self.reward.validate(f"{where}.reward")
        self.feedback.validate(f"{where}.feedback")
        desc = self.description(where)  # the robot must load
        if self.symmetric:
            _require_mirrors(desc, where)
        return self

    def _validate_timing(self, where: str) -> None:
        require(
            self,
            where,
            ("control_dt", "physics_timestep", "contact_timeconst"),
            lambda v: v > 0,
            "must be > 0",
        )
        # beyond twice the reach (or the wheels' limit) every correction is clipped anyway
        require(self, where, ("residual_scale",), lambda v: 0 < v <= 2, "must be in (0, 2]")
        ratio = self.control_dt / self.physics_timestep
        if abs(ratio - round(ratio)) > 1e-6:
            raise invalid(
                f"{where}.control_dt",
                self.control_dt,
                f"must be a whole multiple of physics_timestep = {self.physics_timestep}",
            )
        if round(ratio) > MAX_SUBSTEPS:  # each one a physics step of every robot, every period
            raise invalid(
                f"{where}.physics_timestep",
                self.physics_timestep,
                f"{round(ratio)} physics steps per control period (control_dt = "
                f"{self.control_dt} s); at most {MAX_SUBSTEPS}",
            )
        require(self, where, ("episode_length",), lambda v: v >= 1, "must be >= 1")
        require(
            self,
            where,
            ("solver_iterations",),
            lambda v: v >= 0,
            "must be >= 0 (0: the robot description's sim.iterations)",
        )
        require(
            self,
            where,
            ("yaw_integral_tau", "path_tau", "residual_ramp_s"),
            lambda v: v >= 0,
            "must be >= 0 (0: off)",
        )
        require(self, where, ("symmetric",), lambda v: isinstance(v, bool), "must be true or false")
        require(
            self, where, ("path_integrator",), lambda v: v in ("exact", "euler"),
            'must be "exact" or "euler"',
        )  # fmt: skip
        in_unit = ("action_filter", "residual_deadband")
        require(self, where, in_unit, lambda v: 0 <= v < 1, "must be in [0, 1) (0: off)")
        require(
            self,
            where,
            ("obs_history",),
            lambda v: 0 <= v <= MAX_OBS_HISTORY,
            f"must be in [0, {MAX_OBS_HISTORY}] (frames of {self.control_dt} s; 0: none)",
        )

    def description(self, where: str = "env") -> RobotDescription:
        """The robot description, with this task's physics timestep and contact time constant."""
        desc = resolve_description(self.robot, where)
        sim = dataclasses.replace(
            desc.sim,
            timestep=self.physics_timestep,
            contact_timeconst=self.contact_timeconst,
            iterations=self.solver_iterations or desc.sim.iterations,
            impl=self.physics_impl or desc.sim.impl,
        )
        return dataclasses.replace(desc, sim=sim)

    def nominal(self) -> EnvConfig:
        """The nominal scenario: no randomization, no sensor noise, no latency."""
        return dataclasses.replace(
            self,
            randomization=dataclasses.replace(self.randomization, enabled=False),
            noise=dataclasses.replace(self.noise, scale=0.0),
        )


def _require_mirrors(desc: RobotDescription, where: str) -> None:
    """A mirror-averaged policy needs a robot that each mirror maps onto itself (refused
    here, before a run builds anything, rather than when the controller is built)."""
    from mecanum_jax.control.symmetry import TWIST_SIGNS, AsymmetricRobotError, wheel_map
    from mecanum_jax.kinematics import model as kinematics

    jacobian = np.asarray(kinematics.jacobian(desc.build_geometry()))
    for name, signs in TWIST_SIGNS.items():
        try:
            wheel_map(jacobian, signs, name)
        except AsymmetricRobotError:
            raise invalid(
                f"{where}.symmetric",
                True,
                f"robot {desc.robot.name!r} is not mirror-symmetric (its {name} mirror maps a "
                f"wheel onto none); train it with {where}.symmetric = false",
            ) from None


PLAYED_FIELDS = ("residual_deadband",)
"""Fields a trained policy may be played with other than it was trained with: they shape the
robot-side controller's output only, never the observations or the networks."""


def played_with(env: EnvConfig, changes: object, where: str) -> EnvConfig:
    """``env`` as a model is played (its ``provenance.json``'s ``played_with``, a table of
    ``"env.FIELD": value`` over :data:`PLAYED_FIELDS`), validated; the checkpoint keeps the
    task it was trained with."""
    if not isinstance(changes, dict):
        raise invalid(where, changes, 'expected a table of "env.FIELD": value')
    fields: dict[str, object] = {}
    for name, value in changes.items():
        field = str(name).removeprefix("env.")
        if not str(name).startswith("env.") or field not in PLAYED_FIELDS:
            raise invalid(
                f"{where}.{name}", value, f"only {[f'env.{f}' for f in PLAYED_FIELDS]} may differ"
            )
        fields[field] = value
    return changed_env(env, fields, f"{where}.env")


def changed_env(env: EnvConfig, changes: dict[str, object], where: str) -> EnvConfig:
    """``env`` with ``changes`` (``"FIELD"`` or ``"SECTION.FIELD"``: a value as a config
    file would give it), each checked as a config file's key and value, then validated."""
    top: dict[str, object] = {}
    sections: dict[str, dict[str, object]] = {}
    for name, value in changes.items():
        section, dot, field = name.partition(".")
        if not dot and dataclasses.is_dataclass(getattr(env, name, None)):
            raise invalid(f"{where}.{name}", value, f"a section: change its fields ({name}.FIELD)")
        if not dot:
            top[name] = value
        elif not dataclasses.is_dataclass(getattr(env, section, None)):
            raise invalid(f"{where}.{name}", value, f"{section!r} is not a section of env")
        else:
            sections.setdefault(section, {})[field] = value
    typed = from_mapping(EnvConfig, top, where)
    out = dataclasses.replace(env, **{f: getattr(typed, f) for f in top})
    for section, fields in sections.items():
        part = getattr(env, section)
        typed_part = from_mapping(type(part), fields, f"{where}.{section}")
        part = dataclasses.replace(part, **{f: getattr(typed_part, f) for f in fields})
        out = dataclasses.replace(out, **{section: part})
    return out.validate("env")


__all__ = [
    "MAX_OBS_HISTORY",
    "PLAYED_FIELDS",
    "RESIDUAL_BASES",
    "RESIDUAL_SPACES",
    "CommandConfig",
    "EnvConfig",
    "FeedbackConfig",
    "NoiseConfig",
    "RandomizationConfig",
    "RewardConfig",
    "changed_env",
    "played_with",
]
