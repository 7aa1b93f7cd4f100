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

# isort: split
import mecanum_jax._quiet_mjx  # noqa: F401  (first: keeps MJX's Warp probe quiet)

# isort: split
import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import Env, State, Wrapper

from mecanum_jax.control import sensor_size
from mecanum_jax.control import step as ctl
from mecanum_jax.host import host_side
from mecanum_jax.sim.batching import chunked_vmap, cpu_chunk
from mecanum_jax.sim.physics import Robot
from mecanum_jax.sim.state import RobotParams, Sensors, select
from mecanum_jax.task import commands as cmds
from mecanum_jax.task import fidelity as fid
from mecanum_jax.task import observations as obs_
from mecanum_jax.task import randomization as rand
from mecanum_jax.task import references as refs
from mecanum_jax.task.config import EnvConfig
from mecanum_jax.task.controller import (
    EpisodeInfo,
    TaskInfo,
    allow_rank_promotion,
    control_state,
    task_info,
    with_control,
)
from mecanum_jax.task.observations import NoiseConfig
from mecanum_jax.task.references import FeedbackConfig
from mecanum_jax.task.reward import METRIC_NAMES, step_reward
from mecanum_jax.task.shapes import task_shapes


class MecanumEnv(Env):
    """One robot tracking body-twist commands (Brax ``Env``); batch with :class:`TrainingEnv`."""

    metric_names = METRIC_NAMES

    @host_side  # its constants on the CPU (mecanum_jax.host)
    def __init__(self, config: EnvConfig | None = None, robots: int = 1, fidelity: str = "fast"):
        """``robots``: the most robots one batched call simulates (all vmapped axes
        together), for MuJoCo Warp's shared contact buffer (:class:`Robot`). ``fidelity``:
        the physics model, "fast" or "reference" (:mod:`.fidelity`)."""
        self.config = config = (config or EnvConfig()).validate()
        # the task's description, what its parts read of the robot (derived once and
        # handed to them), the controller and the layouts: a restored policy's (.shapes)
        self.shapes = shapes = task_shapes(config)
        self.desc = shapes.desc
        self.robot = Robot(*fid.model(config, fidelity, shapes.desc), robots=robots)
        self.substeps = fid.substeps(config, self.robot.desc, self.robot.fidelity)
        c = self.constants = shapes.constants
        self.geometry, self.n_wheels, self.max_rates = c.geometry, c.n_wheels, c.max_rates
        self.command_scale, self.nominal_params = c.command_scale, c.nominal_params
        self.jacobian = c.jacobian
        n = self.n_wheels
        self.max_rate = float(np.max(np.asarray(self.max_rates)))
        self.max_latency = config.randomization.latency_steps[1]
        # the robot-side controller, one description for the environment and its exports
        self.control = spec = shapes.control
        self.twist_residual = spec.twist_residual
        self.sensor_size = sensor_size(n)
        # the sensor frames kept: the latest latency_steps[1] + 1 and the observed history
        self.history_frames = self.max_latency + 1 + config.obs_history
        self.feedback_base = spec.feedback_base
        self.layout = spec.layout
        tau = config.path_tau
        self.path_scale = jnp.asarray(tau * np.asarray(c.command_scale)) if tau > 0 else None
        self.privileged_layout = shapes.privileged_layout

    # --- Brax interface ---------------------------------------------------------------------

    @property
    def observation_size(self) -> dict[str, tuple[int, ...]]:
        return self.shapes.observation_size

    @property
    def action_size(self) -> int:
        return self.shapes.action_size

    @property
    def backend(self) -> str:
        return "mjx"

    def reset(self, rng: jax.Array) -> State:
        k_params, rng = jax.random.split(rng)
        params, latency = rand.sample_params(self.constants, k_params, self.config.randomization)
        return self.reset_to(rng, params, latency, self.noise_std())

    @allow_rank_promotion
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
        start = jnp.asarray(0, jnp.int32)
        command = cmds.sample_command(c, k_cmd, commands)
        first = obs_.sensor_vector(self.control, sens, k_noise, noise_std)
        control = ctl.initial_state(self.control, first, command, self.history_frames, jnp)
        episode: EpisodeInfo = {
            "rng": rng,
            "params": params,
            "latency": jnp.asarray(latency, jnp.int32),
            "noise_std": noise_std,
            "next_resample": cmds.resample_time(k_time, start, commands, self.config.control_dt),
            "step": jnp.asarray(0, jnp.int32),
            "true_path_error": jnp.zeros(3),
            "truncation": jnp.asarray(0.0),
        }
        info = with_control(episode, control._replace(feedback_gains=self.feedback_gains()))
        obs = self._observe(sens, info)
        metrics = {k: jnp.asarray(0.0) for k in self.metric_names}
        return State(sim, obs, jnp.asarray(0.0), jnp.asarray(0.0), metrics, info)

    @allow_rank_promotion
    def step(self, state: State, action: jax.Array, reference: jax.Array | None = None) -> State:
        """One control step under ``action``; with ``reference`` (an index into
        :data:`REFERENCES`, may be traced; negative: none) that reference controller's
        setpoints replace the action's. The feedback controller's integrator is updated only
        when ``reference`` is given."""
        info = task_info(state)
        c, cfg, spec = self.constants, self.config, self.control
        before = control_state(info)
        latency = info["latency"]
        rates, after = ctl.act(spec, before, action, latency, jnp)
        if reference is not None:
            chosen = refs.reference_rates(c, reference, info, cfg.feedback, spec)
            rates = jnp.where(reference >= 0, chosen, rates)
            if not self.feedback_base:  # the feedback reference's integrator runs too
                gyro = ctl.measured_yaw_rate(spec, before, latency, jnp)
                integral = ctl.feedback_integral_step(
                    spec, before.command, gyro, before.feedback_integral[None],
                    before.feedback_gains, before.command_age[..., None], jnp,
                )  # fmt: skip
                after = after._replace(feedback_integral=integral[0])
        action = after.last_action
        params: RobotParams = info["params"]
        command = before.command
        sim = self.robot.step(state.pipeline_state, rates, params, self.substeps)
        sens = self.robot.sensors(sim)
        target = command
        if cfg.reward.target == "feasible":  # what the evaluation scores (RewardConfig)
            target = self.feasible_target(command, params.radius_scale)
        path = info["true_path_error"]
        if cfg.path_tau > 0:  # the true twist against this step's command (exact: its target)
            reference = target if cfg.path_integrator == "exact" else command
            path = ctl.path_step(spec, path, sens.twist, reference, jnp)
        reward, metrics = step_reward(
            cfg.reward, sens, target, action, before.last_action, params,
            cfg.control_dt, path,
        )  # fmt: skip
        metrics["unstable"] = sim.unstable.astype(jnp.float32)
        rng, k_noise, k_cmd, k_time = jax.random.split(info["rng"], 4)
        step = info["step"] + 1
        resample = step >= info["next_resample"]
        new_command = jnp.where(resample, cmds.sample_command(c, k_cmd, cfg.commands), command)
        due = cmds.resample_time(k_time, step, cfg.commands, cfg.control_dt)
        info["next_resample"] = jnp.where(resample, due, info["next_resample"])
        info["step"], info["rng"], info["true_path_error"] = step, rng, path
        frame = obs_.sensor_vector(spec, sens, k_noise, info["noise_std"])
        info = with_control(info, ctl.sense(spec, after, frame, new_command, latency, jnp))
        obs = self._observe(sens, info)
        return state.replace(pipeline_state=sim, obs=obs, reward=reward, metrics=metrics, info=info)

    @allow_rank_promotion
    def set_command(self, state: State, command: jax.Array) -> State:
        """Impose ``command`` from now on (scripted sequences): it replaces the current
        command, in the observations too, and the environment stops resampling."""
        info = task_info(state)
        changed = jnp.any(command != info["command"])
        info["command_age"] = jnp.where(changed, 0, info["command_age"]).astype(jnp.int32)
        if self.control.feedback.reset:  # the integrator restarts with a new command
            info["feedback_integral"] = jnp.where(changed, 0.0, info["feedback_integral"])
        info["command"] = command
        info["next_resample"] = jnp.asarray(jnp.iinfo(jnp.int32).max, jnp.int32)
        policy = ctl.observe(self.control, control_state(info), info["latency"], jnp)
        size = policy.shape[0]  # the policy's part comes first in both observations
        obs = {k: v.at[:size].set(policy) for k, v in state.obs.items()}
        return state.replace(obs=obs, info=info)

    @allow_rank_promotion
    def wheel_setpoints(
        self, command: jax.Array, action: jax.Array, info: TaskInfo | None = None
    ) -> jax.Array:
        """Wheel-rate setpoints (rad/s) for an applied action in [-1, 1]^action_size under
        ``command`` (``info``: the state, for a residual on the ``feedback`` controller)."""
        spec = self.control
        if self.feedback_base:
            if info is None:
                raise ValueError("wheel_setpoints: residual_base = 'feedback' needs the state")
            s = control_state(info)
            gyro = ctl.measured_yaw_rate(spec, s, info["latency"], jnp)
            integral, gains = s.feedback_integral[..., None], s.feedback_gains
        else:
            gyro = integral = jnp.zeros(1)
            gains = ctl.gains(spec, jnp)
        return ctl.setpoints(spec, command, jnp.clip(action, -1.0, 1.0), gyro, integral, gains, jnp)

    @allow_rank_promotion
    def _observe(self, sens: Sensors, info: TaskInfo) -> dict[str, jax.Array]:
        policy = ctl.observe(self.control, control_state(info), info["latency"], jnp)
        return obs_.observe(self.constants, sens, info, policy, self.path_scale)

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
