"""The velocity-tracking task: a Brax environment on the fast MJX robot.

A robot is commanded a body twist ``(vx, vy, ωz)`` and must achieve it. The environment
follows Brax's interface (``reset(rng) -> State``, ``step(State, action) -> State`` for one
robot; :class:`TrainingEnv` batches it with automatic resets), so Brax's PPO components
drive it unchanged. Its parts live beside it:

- :mod:`.config`: :class:`EnvConfig`, the task's settings;
- :mod:`.constants`: :class:`RobotConstants`, the robot as those parts see it;
- :mod:`.commands`: the commands and when they change;
- :mod:`.randomization`: the per-robot physical parameters drawn at each reset;
- :mod:`.observations`: sensors, noise, latency and the observation layouts;
- :mod:`.reward`: the named reward terms;
- :mod:`.references`: the reference controllers, the analytic baseline among them.

- **Control:** 50 Hz (``control_dt``) with ``control_dt / physics_timestep`` physics
  substeps. The default 5 ms physics step (contact time constant 10 ms) tracks steady
  twists within 0.5% like the 2 ms step, at 4 instead of 10 substeps; with the 12 Newton
  iterations no robot tips over, under the baseline or random actions (docs/training.md).
- **Actions** in [-1, 1] per wheel. ``residual = true``: wheel-rate setpoints are the
  analytic baseline's plus ``action · residual_scale · max_rate``, so the zero action *is*
  the baseline. ``residual = false``: setpoints are ``action · max_rate``.
"""

from __future__ import annotations

from typing import Any

# isort: split
import mecanum_jax._quiet_mjx  # noqa: F401  (first: keeps MJX's Warp probe quiet)

# isort: split
import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import Env, State, Wrapper

from mecanum_jax.host import host_side
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.sim.batching import chunked_vmap, cpu_chunk
from mecanum_jax.sim.physics import Robot
from mecanum_jax.sim.state import RobotParams, Sensors, select
from mecanum_jax.task import commands as cmds
from mecanum_jax.task import fidelity as fid
from mecanum_jax.task import observations as obs_
from mecanum_jax.task import randomization as rand
from mecanum_jax.task import references as refs
from mecanum_jax.task.config import EnvConfig
from mecanum_jax.task.constants import robot_constants
from mecanum_jax.task.observations import NoiseConfig
from mecanum_jax.task.references import FeedbackConfig
from mecanum_jax.task.reward import METRIC_NAMES, step_reward


class MecanumEnv(Env):
    """One robot tracking body-twist commands (Brax ``Env``); batch with :class:`TrainingEnv`."""

    metric_names = METRIC_NAMES

    @host_side  # its constants on the CPU (mecanum_jax.host)
    def __init__(self, config: EnvConfig | None = None, robots: int = 1, fidelity: str = "fast"):
        """``robots``: the most robots one batched call simulates (all vmapped axes
        together), for MuJoCo Warp's shared contact buffer (:class:`Robot`). ``fidelity``:
        the physics model, "fast" or "reference" (:mod:`.fidelity`)."""
        self.config = config = (config or EnvConfig()).validate()
        self.desc = config.description()
        self.robot = Robot(*fid.model(config, fidelity), robots=robots)
        self.substeps = fid.substeps(config, self.robot.desc, self.robot.fidelity)
        # what the task's parts read of the robot, built once and handed to them
        c = self.constants = robot_constants(
            self.desc, self.robot.geometry, self.robot.nominal_params()
        )
        self.geometry, self.n_wheels, self.max_rates = c.geometry, c.n_wheels, c.max_rates
        self.command_scale, self.nominal_params = c.command_scale, c.nominal_params
        self.jacobian = c.jacobian
        n = self.n_wheels
        self.max_rate = float(np.max(np.asarray(self.max_rates)))
        self.max_latency = config.randomization.latency_steps[1]
        self.twist_residual = config.residual and config.residual_space == "twist"
        self._action_size = 3 if self.twist_residual else n
        self.sensor_size = obs_.sensor_size(n)
        # the sensor frames kept: the latest latency_steps[1] + 1 and the observed history
        self.history_frames = self.max_latency + 1 + config.obs_history
        self.feedback_base = config.residual and config.residual_base == "feedback"
        self.layout = obs_.policy_layout(
            n,
            self._action_size,
            config.yaw_integral_tau > 0,
            self.feedback_base,
            config.obs_history,
        )
        self.privileged_layout = obs_.privileged_layout(self.layout, n)

    # --- Brax interface ---------------------------------------------------------------------

    @property
    def observation_size(self) -> dict[str, tuple[int, ...]]:
        return {
            "state": (sum(s for _, s in self.layout),),
            "privileged_state": (sum(s for _, s in self.privileged_layout),),
        }

    @property
    def action_size(self) -> int:
        return self._action_size

    @property
    def backend(self) -> str:
        return "mjx"

    def reset(self, rng: jax.Array) -> State:
        k_params, rng = jax.random.split(rng)
        params, latency = rand.sample_params(self.constants, k_params, self.config.randomization)
        return self.reset_to(rng, params, latency, self.noise_std())

    def reset_to(
        self, rng: jax.Array, params: RobotParams, latency: jax.Array, noise_std: jax.Array
    ) -> State:
        """Reset with given physics ``params``, ``latency`` (control steps, at most the
        config's ``latency_steps[1]``) and sensor ``noise_std`` (wheel rate, gyro, accel).

        Evaluation uses this to run scenarios whose parameters are data, so that one
        compiled program serves them all.
        """
        k_cmd, k_time, k_noise, rng = jax.random.split(rng, 4)
        c, commands = self.constants, self.config.commands
        sim = self.robot.reset(params)
        sens = self.robot.sensors(sim)
        noise_std = jnp.asarray(noise_std, jnp.float32)
        sensors = obs_.sensor_vector(c, sens, k_noise, noise_std)
        start = jnp.asarray(0, jnp.int32)
        info = {
            "rng": rng,
            "params": params,
            "latency": jnp.asarray(latency, jnp.int32),
            "noise_std": noise_std,
            "command": cmds.sample_command(c, k_cmd, commands),
            "next_resample": cmds.resample_time(k_time, start, commands, self.config.control_dt),
            "step": jnp.asarray(0, jnp.int32),
            "last_action": jnp.zeros(self.action_size),
            "history": jnp.broadcast_to(sensors, (self.history_frames, self.sensor_size)),
            "yaw_integral": jnp.asarray(0.0),
            "feedback_integral": jnp.asarray(0.0),
            "feedback_gains": self.feedback_gains(),
            "truncation": jnp.asarray(0.0),
        }
        info = refs.track_command(self.config.feedback, self.config.control_dt, info)
        obs = self._observe(sens, info)
        metrics = {k: jnp.asarray(0.0) for k in self.metric_names}
        return State(sim, obs, jnp.asarray(0.0), jnp.asarray(0.0), metrics, info)

    def step(self, state: State, action: jax.Array, reference: jax.Array | None = None) -> State:
        """One control step under ``action``; with ``reference`` (an index into
        :data:`REFERENCES`, may be traced; negative: none) that reference controller's
        setpoints replace the action's. The feedback controller's integrator is updated only
        when ``reference`` is given."""
        info = dict(state.info)
        c, cfg = self.constants, self.config
        action = jnp.clip(action, -1.0, 1.0)
        if cfg.residual_deadband > 0:  # small corrections dropped (EnvConfig)
            d = cfg.residual_deadband
            action = jnp.sign(action) * jnp.maximum(jnp.abs(action) - d, 0.0)
        if not cfg.residual_at_stop:  # the base alone stops (EnvConfig)
            action = jnp.where(jnp.all(info["command"] == 0.0), 0.0, action)
        if cfg.action_filter > 0:  # the applied action, low-passed (EnvConfig)
            f = cfg.action_filter
            action = f * info["last_action"] + (1.0 - f) * action
        params: RobotParams = info["params"]
        command = info["command"]
        rates = self.wheel_setpoints(command, action, state.info)
        if reference is not None:
            chosen = refs.reference_rates(c, reference, state.info, cfg.feedback)
            rates = jnp.where(reference >= 0, chosen, rates)
        if reference is not None or self.feedback_base:
            # the feedback controller's integrator runs where it may act: a reference in
            # evaluation, or the base of the policy's residual
            info["feedback_integral"] = refs.feedback_integral(
                c, state.info, cfg.feedback, cfg.control_dt
            )
        sim = self.robot.step(state.pipeline_state, rates, params, self.substeps)
        sens = self.robot.sensors(sim)
        target = command
        if cfg.reward.target == "feasible":  # what the evaluation scores (RewardConfig)
            target = self.feasible_target(command, params.radius_scale)
        reward, metrics = step_reward(
            cfg.reward, sens, target, action, info["last_action"], params,
            cfg.control_dt,
        )  # fmt: skip
        metrics["unstable"] = sim.unstable.astype(jnp.float32)
        rng, k_noise, k_cmd, k_time = jax.random.split(info["rng"], 4)
        step = info["step"] + 1
        resample = step >= info["next_resample"]
        new_command = jnp.where(resample, cmds.sample_command(c, k_cmd, cfg.commands), command)
        info = refs.track_command(cfg.feedback, cfg.control_dt, info, new_command)
        info["command"] = new_command
        due = cmds.resample_time(k_time, step, cfg.commands, cfg.control_dt)
        info["next_resample"] = jnp.where(resample, due, info["next_resample"])
        info.update(step=step, rng=rng, last_action=action)
        sensors = obs_.sensor_vector(c, sens, k_noise, info["noise_std"])
        info["history"] = jnp.concatenate([sensors[None], info["history"][:-1]], axis=0)
        if cfg.yaw_integral_tau > 0:  # against the command tracked in this step
            info["yaw_integral"] = obs_.yaw_integral(
                c, info, command, cfg.yaw_integral_tau, cfg.control_dt
            )
        obs = self._observe(sens, info)
        return state.replace(pipeline_state=sim, obs=obs, reward=reward, metrics=metrics, info=info)

    def set_command(self, state: State, command: jax.Array) -> State:
        """Impose ``command`` from now on (scripted sequences): it replaces the current
        command, in the observations too, and the environment stops resampling."""
        fb, dt = self.config.feedback, self.config.control_dt
        info = refs.track_command(fb, dt, dict(state.info), command, advance=False)
        info["command"] = command
        info["next_resample"] = jnp.asarray(jnp.iinfo(jnp.int32).max, jnp.int32)
        scaled = command / self.command_scale
        obs = {k: v.at[:3].set(scaled) for k, v in state.obs.items()}  # command comes first
        if self.config.feedback.reset and self.feedback_base:  # the integrator, restarted
            at = obs_.entry_start(self.layout, "feedback_integral")
            value = info["feedback_integral"] / self.command_scale[2]
            obs = {k: v.at[at].set(value) for k, v in obs.items()}
        return state.replace(obs=obs, info=info)

    def wheel_setpoints(
        self, command: jax.Array, action: jax.Array, info: dict[str, Any] | None = None
    ) -> jax.Array:
        """Wheel-rate setpoints (rad/s) for an action in [-1, 1]^action_size under ``command``
        (``info``: the state, for a residual on the ``feedback`` controller)."""
        if self.feedback_base:
            if info is None:
                raise ValueError("wheel_setpoints: residual_base = 'feedback' needs the state")
            base = refs.feedback_rates(
                self.constants, dict(info, command=command), self.config.feedback
            )
        elif self.config.residual:
            base = refs.baseline_rates(self.constants, command)
        if self.twist_residual:
            correction = action * (self.config.residual_scale * self.command_scale)
            rates = base + kinematics.apply_rows(self.jacobian, correction)
        elif self.config.residual:
            rates = base + action * (self.config.residual_scale * self.max_rates)
        else:
            rates = action * self.max_rates
        return jnp.clip(rates, -self.max_rates, self.max_rates)

    def _observe(self, sens: Sensors, info: dict[str, Any]) -> dict[str, jax.Array]:
        cfg = self.config
        return obs_.observe(
            self.constants, sens, info, cfg.yaw_integral_tau, self.feedback_base, cfg.obs_history
        )

    def noise_std(self, noise: NoiseConfig | None = None) -> jax.Array:
        """Sensor noise standard deviations (wheel rate, gyro, accel) of a noise config."""
        return (noise or self.config.noise).std()

    def feedback_gains(self, feedback: FeedbackConfig | None = None) -> jax.Array:
        """``(kp, ki, i_max)`` of a feedback config (default: this task's)."""
        return (feedback or self.config.feedback).gains()

    def feasible_target(self, command: jax.Array, radius_scale: jax.Array) -> jax.Array:
        """:func:`.references.feasible_target` in this task's metric: the steady-state
        error's target."""
        w = self.config.feedback.omega_weight
        return refs.feasible_target(self.constants, command, radius_scale, w)


class TrainingEnv(Wrapper):
    """A batch of :class:`MecanumEnv` robots with episode limits and automatic resets.

    Unlike Brax's ``AutoResetWrapper`` (which restores each slot's first state, so a slot
    keeps its randomized robot forever), a finished episode is reset from that robot's own
    rng stream: a fresh robot, command and latency per episode.
    ``state.info["truncation"]`` is 1 on the step an episode hits ``episode_length``.
    """

    def __init__(
        self, env: MecanumEnv, episode_length: int | None = None, chunk: int | None = None
    ):
        super().__init__(env)
        self.menv = env
        self.episode_length = episode_length or env.config.episode_length
        self.chunk = chunk if chunk is not None else cpu_chunk(env.robot.fidelity, env.robot.impl)

    def reset(self, rng: jax.Array) -> State:
        return chunked_vmap(self.env.reset, self.chunk)(rng)

    def step(self, state: State, action: jax.Array) -> State:
        def one(s: State, a: jax.Array) -> State:
            nxt = self.env.step(s, a)
            done = nxt.info["step"] >= self.episode_length
            k_reset, k_next = jax.random.split(nxt.info["rng"])
            fresh = self.env.reset(k_reset)
            fresh.info["rng"] = k_next
            merged = jax.tree.map(
                lambda f, x: jnp.where(done, f, x),
                fresh.replace(pipeline_state=None),
                nxt.replace(pipeline_state=None),
            ).replace(pipeline_state=select(done, fresh.pipeline_state, nxt.pipeline_state))
            info = dict(merged.info)
            info["truncation"] = done.astype(jnp.float32)
            return merged.replace(
                reward=nxt.reward,
                metrics=nxt.metrics,
                done=done.astype(jnp.float32),
                info=info,
            )

        return chunked_vmap(one, self.chunk)(state, action)


__all__ = ["MecanumEnv", "TrainingEnv"]
