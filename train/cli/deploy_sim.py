"""``mecanum-deploy-sim``: rehearse a deployment — the exported policy in its NumPy
control loop (``mecanum_jax.deploy.loop``, as a robot would run it, at the control rate)
driving the robot in plain C MuJoCo (``mecanum_jax.deploy.plant``), scored with
mecanum-eval's metrics.

Examples::

    mecanum-deploy-sim                                   # models/o_rectangle, nominal scenario
    mecanum-deploy-sim models/o_rectangle --backend onnx --fidelity reference
    mecanum-deploy-sim --scenario sensor_noise --episodes 8
    mecanum-deploy-sim --command 0.3 0 0.5 --seconds 5 --latency 2 --noise-scale 1

The episodes are mecanum-eval's: the scenario's seeded command sequences and robots
(``configs/eval/default.toml``; JAX prepares them, as it does for mecanum-eval, before
the loop starts), so the figures are comparable episode for episode: ``ss v``, ``ss ωz``
(steady-state error against the nearest feasible twist of the true robot) and the rest
of mecanum-eval's table, each pooled figure with a 95% bootstrap interval over the
episodes. Sensors are exact unless the scenario or ``--noise-scale`` / ``--latency`` add
noise and delay. Nothing in the loop imports JAX: the controller sees only readings.
Exit codes: 2 bad input, or a disk that is full or read-only (one line naming the path;
nothing is left behind), 130 interrupted.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

import numpy as np
import tyro
from rich.console import Console
from rich.table import Table

from mecanum_jax import atomic
from mecanum_jax._checks import require_platform
from mecanum_jax.config import ConfigError
from mecanum_jax.deploy.loop import Controller
from mecanum_jax.deploy.plant import Plant, SensorChannel
from mecanum_jax.deploy.policy import ExportError
from mecanum_jax.evaluation import metrics
from mecanum_jax.evaluation.traces import Trace, summarize, trace_parts
from train.cli import eval_output
from train.cli.deploy_episodes import Episodes, check_reach, episodes
from train.cli.paths import check_output, resolve_model
from train.loop.progress import print_error, report_console

if TYPE_CHECKING:
    from train.config import TrainConfig

console = Console(stderr=True)
DEFAULT_MODEL = "models/o_rectangle"


@dataclasses.dataclass
class DeploySimArgs:
    """Run an exported policy's NumPy control loop against the robot in C MuJoCo."""

    model: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="MODEL")] = DEFAULT_MODEL
    """A model directory: config.json (the task) and policy.npz (and
    policy.onnx for --backend onnx), as mecanum-export --model writes it."""
    backend: Literal["numpy", "onnx"] = "numpy"
    """The policy's runtime: the NumPy module, or the ONNX graph in onnxruntime."""
    fidelity: Literal["fast", "reference"] = "fast"
    """The robot model: fast (the one the policy was trained and is evaluated on) or
    reference (10 passive rollers per wheel, 1 ms steps)."""
    scenarios: str = "default"
    """Scenario file: a name in configs/eval/ or a path to a .toml file."""
    scenario: str | None = None
    """The scenario whose episodes (robots, commands, sensors) are played (default:
    nominal)."""
    episodes: int | None = None
    """Override the scenario's number of episodes."""
    seconds: float | None = None
    """Override the episode length (with --command: its length, default 5 s)."""
    command: Annotated[tuple[float, ...], tyro.conf.arg(metavar="VX VY WZ")] = ()
    """A constant command (vx m/s, vy m/s, ωz rad/s) instead of the scenario's; the
    nominal robot."""
    noise_scale: float | None = None
    """Sensor noise: this multiple of the task's [env.noise] (default: the scenario's)."""
    latency: int | None = None
    """Sensor latency, control periods (default: the scenario's)."""
    seed: int = 0
    """Seed of the sensor noise."""
    settle_s: float = 0.5
    """Steady-state error counts control steps at least this long after a command change."""
    bootstrap: int = 2000
    """Bootstrap resamples of the intervals."""
    out: str | None = None
    """Write the figures as JSON here (never overwritten)."""


def _check(args: DeploySimArgs) -> None:
    for name in ("episodes", "latency"):
        v = getattr(args, name)
        if v is not None and not (
            isinstance(v, int) and 0 <= v <= 4096 and v >= (name == "episodes")
        ):
            raise ConfigError(
                f"--{name} = {v}: must be an integer in [{int(name == 'episodes')}, 4096]"
            )
    if args.seconds is not None and not 0 < args.seconds <= 600:
        raise ConfigError(f"--seconds = {args.seconds}: must be in (0, 600]")
    if args.noise_scale is not None and not (
        np.isfinite(args.noise_scale) and args.noise_scale >= 0
    ):
        raise ConfigError(f"--noise-scale = {args.noise_scale}: must be finite and >= 0")
    if args.command and (len(args.command) != 3 or not all(np.isfinite(args.command))):
        raise ConfigError(f"--command = {list(args.command)}: expected 3 finite numbers VX VY WZ")
    if args.command and args.scenario is not None:
        raise ConfigError(
            f"--scenario = {args.scenario!r}: not with --command (a constant command)"
        )
    if not (np.isfinite(args.settle_s) and args.settle_s >= 0):
        raise ConfigError(f"--settle-s = {args.settle_s}: must be >= 0")
    if args.bootstrap < 100:
        raise ConfigError(f"--bootstrap = {args.bootstrap}: must be >= 100")
    args.model = resolve_model(args.model)  # models/o_rectangle: the packaged one if need be


def load_model(args: DeploySimArgs) -> tuple[TrainConfig, Controller]:
    """The model directory's task config and a controller on the chosen backend."""
    from train.store import inputs

    model = Path(args.model)
    if not model.is_dir():
        what = "not a directory" if model.exists() else "no such directory"
        raise ConfigError(f"model = {args.model!r}: {what}")
    suffix = "onnx" if args.backend == "onnx" else "npz"
    for name in ("config.json", f"policy.{suffix}"):
        if not (model / name).is_file():
            raise ConfigError(
                f"model = {args.model!r}: no {name} (a model directory from "
                "`mecanum-export RUN DIR --model`"
                + (
                    ", with `mecanum-export DIR DIR/policy.onnx --format onnx`)"
                    if suffix == "onnx"
                    else ")"
                )
            )
    cfg = inputs.load_saved_config(model)  # the robot: the model's copy, if it has one
    controller = Controller.load(model / f"policy.{suffix}")
    if controller.policy.meta.get("robot") not in (None, cfg.env.description().robot.name):
        raise ConfigError(
            f"model = {args.model!r}: policy for robot {controller.policy.meta['robot']!r}, "
            f"config.json for {cfg.env.description().robot.name!r}"
        )
    return cfg, controller


def played(args: DeploySimArgs, cfg: TrainConfig) -> Episodes:
    """The episodes ``args`` ask for (:func:`train.cli.deploy_episodes.episodes`)."""
    return episodes(
        cfg,
        scenarios=args.scenarios,
        scenario=args.scenario,
        count=args.episodes,
        seconds=args.seconds,
        command=args.command,
        latency=args.latency,
        noise_scale=args.noise_scale,
    )


def play(plant: Plant, controller: Controller, eps: Episodes, seed: int = 0) -> Trace[np.ndarray]:
    """Every episode through the control loop, one after another: a :class:`Trace` as
    mecanum-eval records it (twist, pose, torques at the end of each control period)."""
    E, T, _ = eps.commands.shape
    n = plant.n_wheels
    out = {k: np.zeros((E, T, 3)) for k in ("twist", "pose")}
    out |= {k: np.zeros((E, T)) for k in ("energy_j", "saturated", "unstable")}
    out |= {k: np.zeros((E, T, n)) for k in ("wheel_torque", "wheel_rate")}
    start = np.zeros((E, 3))
    for e in range(E):
        m = plant.reset(eps.params[e])
        channel = SensorChannel(eps.noise_std[e], int(eps.latency[e]), seed=seed * 100_003 + e)
        reading = channel.reset(m)
        controller.reset()
        start[e] = m.pose
        for t in range(T):
            setpoints, _ = controller.step(eps.commands[e, t], *reading)
            m = plant.step(setpoints, eps.control_dt)
            reading = channel.read(m)
            out["twist"][e, t], out["pose"][e, t] = m.twist, m.pose
            out["wheel_torque"][e, t], out["wheel_rate"][e, t] = m.wheel_torque, m.wheel_rate
            power = np.sum(np.abs(m.wheel_torque * m.wheel_rate))
            out["energy_j"][e, t] = power * eps.control_dt
            limit = plant.params.torque_limit
            out["saturated"][e, t] = np.mean(np.abs(m.wheel_torque) >= 0.99 * limit)
            out["unstable"][e, t] = plant.unstable
    return Trace(
        command=eps.commands, target=eps.targets, start=start, qpos=np.zeros((E, T, 0)), **out
    )


TABLE = tuple(column for column in eval_output.TABLE if column[1] != "flicker")
"""mecanum-eval's table columns, less flicker (the loop's trace records no actions)."""
INTERVALS = ("rmse_lin", "rmse_wz", "ss_lin", "ss_wz")


def report(trace: Trace[np.ndarray], eps: Episodes, args: DeploySimArgs) -> dict[str, Any]:
    """mecanum-eval's summary of the rehearsal, 95% bootstrap intervals over the episodes
    of the tracking figures, and the per-episode steady-state errors."""
    mcfg = metrics.MetricConfig(settle_s=args.settle_s)
    dt = eps.control_dt
    parts = trace_parts(trace, eps.jacobian, dt, mcfg)
    summary = summarize(trace, dt, eps.scripted, eps.jacobian, mcfg, parts)
    per_episode = {}
    for key in ("ss_lin", "ss_wz"):
        p = parts[key]
        with np.errstate(divide="ignore", invalid="ignore"):
            per_episode[key] = np.sqrt(np.where(p.den > 0, p.num / p.den, np.nan)).tolist()
    return {
        "model": args.model,
        "backend": args.backend,
        "fidelity": args.fidelity,
        "scenario": eps.description,
        "episodes": int(eps.commands.shape[0]),
        "seconds": round(eps.commands.shape[1] * dt, 6),
        "latency": eps.latency.tolist(),
        "noise_std": eps.noise_std[0].tolist() if len(eps.noise_std) else [],
        "summary": summary,
        "interval95": {  # none from a single episode
            k: metrics.bootstrap_interval(parts[k], args.bootstrap)
            if len(trace.command) > 1
            else None
            for k in INTERVALS
        },
        "per_episode": per_episode,
    }


def table(result: dict[str, Any]) -> Table:
    """The figures in mecanum-eval's columns; the tracking ones with their interval."""
    t = Table(
        title=f"mecanum-deploy-sim {result['model']}: {result['backend']} loop, "
        f"{result['fidelity']} model, {_count(result['episodes'], 'episode')}",
        caption=result["scenario"],
        min_width=88,
    )
    t.add_column("metric")
    t.add_column("value", justify="right")
    t.add_column("95% interval", justify="right")
    for label, key, fmt in TABLE:
        v = result["summary"].get(key)
        ci = result["interval95"].get(key)
        span = "" if ci is None else f"[{fmt.format(ci[0])}, {fmt.format(ci[1])}]"
        t.add_row(label, "-" if v is None else fmt.format(v), span)
    unstable = result["summary"].get("unstable") or 0
    t.add_row("unstable", f"{unstable:.0f}", "")
    return t


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


def _error(err: BaseException) -> None:
    print_error(console, err)


def main(argv: list[str] | None = None) -> int:
    """``mecanum-deploy-sim``: see the module docstring."""
    argv = sys.argv[1:] if argv is None else argv
    args = tyro.cli(DeploySimArgs, args=argv, prog="mecanum-deploy-sim")
    t0 = time.time()
    stamp = time.strftime("%Y%m%d-%H%M%S")
    try:
        require_platform()  # JAX_PLATFORMS names a backend that exists (mecanum_jax._checks)
        _check(args)
        name = Path(args.model).name
        out = check_output(args.out or f"runs/deploy-sim-{name}-{stamp}.json", "--out")
        cfg, controller = load_model(args)
        check_reach(args.command, controller.spec.command_scale)
        eps = played(args, cfg)
        plant = Plant(dataclasses.replace(cfg.env, physics_impl="jax").description(), args.fidelity)
    except (ConfigError, ExportError, OSError) as err:
        _error(err)
        return 2
    except ImportError as err:  # onnxruntime for --backend onnx
        _error(ConfigError(f"--backend = {args.backend!r}: {err}"))
        return 2
    console.log(
        f"{eps.description}: {_count(eps.commands.shape[0], 'episode')} of {eps.commands.shape[1]} "
        f"control steps, {args.backend} loop, {args.fidelity} model in C MuJoCo "
        f"({round(eps.control_dt / plant.dt)} physics steps of {plant.dt * 1e3:g} ms per period)"
    )
    try:
        t1 = time.time()
        trace = play(plant, controller, eps, args.seed)
    except KeyboardInterrupt:
        console.print("[yellow]interrupted[/]: nothing written")
        return 130
    result = report(trace, eps, args)
    result["wall_s"] = {"prepare": round(t1 - t0, 2), "loop": round(time.time() - t1, 2)}
    report_console(120).print(table(result))
    try:
        atomic.write_json(out, result, indent=1)  # whole or not at all
    except OSError as err:
        _error(atomic.explain(err, out))
        return 2
    console.log(f"figures: {out} ({time.time() - t0:.0f} s)")
    return 0


__all__ = ["DeploySimArgs", "load_model", "main", "play", "played", "report"]


if __name__ == "__main__":
    sys.exit(main())
