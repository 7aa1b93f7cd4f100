"""The velocity-tracking task: a Brax environment on the fast MJX robot.

A robot is commanded a body twist ``(vx, vy, ωz)`` and must achieve it. The environment
follows Brax's interface (``reset(rng) -> State``, ``step(State, action) -> State`` for one
robot; :class:`TrainingEnv` batches it with automatic resets), so Brax's PPO components
drive it unchanged. Its parts live beside it:

- :mod:`.config`: :class:`EnvConfig`, the task's settings;
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
from mecanum_jax.kinematics import limits
from mecanum_jax.kinematics import model as kinematics
from mecanum_jax.sim.physics import Robot, RobotParams, chunked_vmap, cpu_chunk, select
from mecanum_jax.task import commands as cmds
from mecanum_jax.task import fidelity as fid
from mecanum_jax.task import observations as obs_
from mecanum_jax.task import randomization as rand
from mecanum_jax.task import references as refs
from mecanum_jax.task.commands import CommandConfig
from mecanum_jax.task.config import EnvConfig
from mecanum_jax.task.observations import NoiseConfig
from mecanum_jax.task.randomization import RandomizationConfig
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
        self.geometry = self.robot.geometry
        self.n_wheels = n = self.geometry.n_wheels
        self.substeps = fid.substeps(config, self.robot.desc, self.robot.fidelity)
        self.max_rates = self.desc.max_wheel_rates(self.geometry).astype(jnp.float32)
        self.max_rate = float(np.max(np.asarray(self.max_rates)))
        axes = np.eye(3, dtype=np.float32)
        # scale of each command axis: the largest feasible pure vx, vy, ωz
        self.command_scale = jnp.asarray(
            np.asarray(limits.max_speed(self.geometry, axes, self.max_rates)), jnp.float32
        )
        self.nominal_params = self.robot.nominal_params()
        self.jacobian = jnp.asarray(kinematics.jacobian(self.geometry), jnp.float32)
        kinematics.require_full_rank(self.geometry)
        self.forward_matrix = jnp.asarray(kinematics.forward_matrix(self.geometry), jnp.float32)
        self.max_latency = config.randomization.latency_steps[1]
        self.twist_residual = config.residual and config.residual_space == "twist"
        self._action_size = 3 if self.twist_residual else n
        self.sensor_size = obs_.sensor_size(n)
        # the sensor frames kept: the latest latency_steps[1] + 1 and the observed history
        self.history_frames = self.max_latency + 1 + config.obs_history
        tau = config.yaw_integral_tau
        self.yaw_decay = float(np.exp(-config.control_dt / tau)) if tau > 0 else 0.0
        self.feedback_base = config.residual and config.residual_base == "feedback"
        self.layout = obs_.policy_layout(
            n, self._action_size, tau > 0, self.feedback_base, config.obs_history
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
        params, latency = self.sample_params(k_params)
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
        sim = self.robot.reset(params)
        sens = self.robot.sensors(sim)
        noise_std = jnp.asarray(noise_std, jnp.float32)
        sensors = obs_.sensor_vector(self, sens, k_noise, noise_std)
        info = {
            "rng": rng,
            "params": params,
            "latency": jnp.asarray(latency, jnp.int32),
            "noise_std": noise_std,
            "command": self.sample_command(k_cmd),
            "next_resample": cmds.resample_time(self, k_time, jnp.asarray(0, jnp.int32)),
            "step": jnp.asarray(0, jnp.int32),
            "last_action": jnp.zeros(self.action_size),
            "history": jnp.broadcast_to(sensors, (self.history_frames, self.sensor_size)),
            "yaw_integral": jnp.asarray(0.0),
            "feedback_integral": jnp.asarray(0.0),
            "feedback_gains": self.feedback_gains(),
            "truncation": jnp.asarray(0.0),
        }
        info = refs.track_command(self, info)
        obs = obs_.observe(self, sens, info)
        metrics = {k: jnp.asarray(0.0) for k in self.metric_names}
        return State(sim, obs, jnp.asarray(0.0), jnp.asarray(0.0), metrics, info)

    def step(self, state: State, action: jax.Array, reference: jax.Array | None = None) -> State:
        """One control step under ``action``; with ``reference`` (an index into
        :data:`REFERENCES`, may be traced; negative: none) that reference controller's
        setpoints replace the action's. The feedback controller's integrator is updated only
        when ``reference`` is given."""
        info = dict(state.info)
        action = jnp.clip(action, -1.0, 1.0)
        if not self.config.residual_at_stop:  # the base alone stops (EnvConfig)
            action = jnp.where(jnp.all(info["command"] == 0.0), 0.0, action)
        if self.config.action_filter > 0:  # the applied action, low-passed (EnvConfig)
            f = self.config.action_filter
            action = f * info["last_action"] + (1.0 - f) * action
        params: RobotParams = info["params"]
        command = info["command"]
        rates = self.wheel_setpoints(command, action, state.info)
        if reference is not None:
            rates = jnp.where(reference >= 0, self.reference_rates(reference, state.info), rates)
        if reference is not None or self.feedback_base:
            # the feedback controller's integrator runs where it may act: a reference in
            # evaluation, or the base of the policy's residual
            info["feedback_integral"] = refs.feedback_integral(self, state.info)
        sim = self.robot.step(state.pipeline_state, rates, params, self.substeps)
        sens = self.robot.sensors(sim)
        reward, metrics = step_reward(
            self.config.reward, sens, command, action, info["last_action"], params,
            self.config.control_dt,
        )  # fmt: skip
        metrics["unstable"] = sim.unstable.astype(jnp.float32)
        rng, k_noise, k_cmd, k_time = jax.random.split(info["rng"], 4)
        step = info["step"] + 1
        resample = step >= info["next_resample"]
        new_command = jnp.where(resample, self.sample_command(k_cmd), command)
        info = refs.track_command(self, info, new_command)
        info["command"] = new_command
        info["next_resample"] = jnp.where(
            resample, cmds.resample_time(self, k_time, step), info["next_resample"]
        )
        info.update(step=step, rng=rng, last_action=action)
        sensors = obs_.sensor_vector(self, sens, k_noise, info["noise_std"])
        info["history"] = jnp.concatenate([sensors[None], info["history"][:-1]], axis=0)
        if self.config.yaw_integral_tau > 0:  # against the command tracked in this step
            info["yaw_integral"] = obs_.yaw_integral(self, info, command)
        obs = obs_.observe(self, sens, info)
        return state.replace(pipeline_state=sim, obs=obs, reward=reward, metrics=metrics, info=info)

    def set_command(self, state: State, command: jax.Array) -> State:
        """Impose ``command`` from now on (scripted sequences): it replaces the current
        command, in the observations too, and the environment stops resampling."""
        info = refs.track_command(self, dict(state.info), command, advance=False)
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
            base = refs.feedback_rates(self, dict(info, command=command))
        elif self.config.residual:
            base = self.baseline_rates(command)
        if self.twist_residual:
            correction = action * (self.config.residual_scale * self.command_scale)
            rates = base + kinematics.apply_rows(self.jacobian, correction)
        elif self.config.residual:
            rates = base + action * (self.config.residual_scale * self.max_rates)
        else:
            rates = action * self.max_rates
        return jnp.clip(rates, -self.max_rates, self.max_rates)

    # --- the task's parts, bound to this robot (see the modules beside this one) ------------

    def sample_params(
        self, key: jax.Array, randomization: RandomizationConfig | None = None
    ) -> tuple[RobotParams, jax.Array]:
        """:func:`.randomization.sample_params`: physical parameters and latency."""
        return rand.sample_params(self, key, randomization)

    def sample_command(self, key: jax.Array, commands: CommandConfig | None = None) -> jax.Array:
        """:func:`.commands.sample_command`: one command from the mix of kinds."""
        return cmds.sample_command(self, key, commands)

    def command_schedule(
        self, key: jax.Array, steps: int, commands: CommandConfig | None = None
    ) -> jax.Array:
        """:func:`.commands.command_schedule`: ``(steps, 3)`` commands as an episode draws them."""
        return cmds.command_schedule(self, key, steps, commands)

    def noise_std(self, noise: NoiseConfig | None = None) -> jax.Array:
        """Sensor noise standard deviations (wheel rate, gyro, accel) of a noise config."""
        return (noise or self.config.noise).std()

    def feedback_gains(self, feedback: FeedbackConfig | None = None) -> jax.Array:
        """``(kp, ki, i_max)`` of a feedback config (default: this task's)."""
        return (feedback or self.config.feedback).gains()

    def measured_yaw_rate(self, info: dict[str, Any]) -> jax.Array:
        """The gyro's yaw rate as the controller sees it now (noisy, ``latency`` steps old)."""
        return obs_.measured_yaw_rate(self, info)

    def command_from_obs(self, obs: dict[str, jax.Array]) -> jax.Array:
        """The (noise-free) command carried in the first three policy observations."""
        return obs_.command_from_obs(self, obs)

    def baseline_rates(self, command: jax.Array) -> jax.Array:
        """The analytic baseline: the nominal inverse model, desaturated to the rate limits."""
        return refs.baseline_rates(self, command)

    def nearest_rates(self, twist: jax.Array) -> jax.Array:
        """Wheel rates of the feasible twist nearest ``twist`` (nominal geometry)."""
        return refs.nearest_rates(self, twist)

    def feasible_target(self, command: jax.Array, radius_scale: jax.Array) -> jax.Array:
        """:func:`.references.feasible_target`: the steady-state error's target."""
        return refs.feasible_target(self, command, radius_scale)

    def reference_rates(self, reference: int | jax.Array, info: dict[str, Any]) -> jax.Array:
        """:func:`.references.reference_rates`: setpoints of reference ``reference``."""
        return refs.reference_rates(self, reference, info)


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
