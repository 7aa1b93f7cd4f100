"""Evaluation scenarios: named, seeded sets of episodes, read from TOML (``configs/eval/``).

A scenario fixes everything an episode depends on — the robot's physics, the sensors, the
command sequence, the seed — so two policies evaluated on it face *the same* episodes
(paired comparison). It turns into an :class:`~mecanum_jax.evaluation.episodes.EpisodeBatch`
(:mod:`mecanum_jax.evaluation.episodes`): plain arrays that one compiled rollout
(:mod:`mecanum_jax.evaluation.rollout`) plays for any scenario of the same size.

File format (every key optional except the scenario tables themselves)::

    [defaults]               # for every scenario
    episodes = 32            # robots simulated side by side
    seconds = 10.0           # episode length
    seed = 7                 # evaluation seed (its rng stream never meets training's)
    randomization = { friction = [0.98, 1.02] }  # under every scenario's own (below)

    [scenarios.slippery]
    description = "a slippery floor"
    episodes = 16            # overrides [defaults]

    [scenarios.slippery.commands]
    kind = "random"          # random | sequence | six_modes | singular_pass
    p_beyond = 0.0           # random: keys of the task's [env.commands], overriding it
    # sequence = [[vx, vy, wz, seconds], ...], units = "reach" (fraction of each axis'
    #   largest feasible speed, within [-2, 2]) or "si" (m/s, rad/s, within twice the
    #   playing robot's reach); zero command after the last segment
    # six_modes / singular_pass: speed (fraction of the reach in each direction),
    #   segment_s, pause_s

    [scenarios.slippery.randomization]   # keys of [env.randomization]; missing = nominal
    friction = [0.12, 0.2]

    [scenarios.slippery.noise]           # keys of [env.noise]; no table = no sensor noise
    scale = 1.0

A ``[defaults]`` randomization sits under each scenario's own table, key by key. The
shipped files draw every floor within 2% of the nominal friction this way: a controller
that ignores the sensors (``analytic``) otherwise plays one trajectory in every episode of
a scripted scenario on the nominal robot, and since the contacts are chaotic that one
draw, not the spread, would be what the others are compared with (docs/evaluation.md).

``six_modes`` plays seed 000's six motion modes one after another (each at ``speed`` of
the reach in its direction, with a pause after each); ``singular_pass`` drives out and
back along each singular direction of the layout (seed 003: two wheels are only
dragged), so the command sequence is closed and the final pose error measures drift.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import Any, Literal

from mecanum_jax.config import (
    CONFIG_DIR,
    ConfigError,
    find_config,
    from_mapping,
    invalid,
    load_toml,
    require,
)
from mecanum_jax.task import CommandConfig, EnvConfig, NoiseConfig, RandomizationConfig

EVAL_DIR = CONFIG_DIR / "eval"
# Domain tags of evaluation rng streams: scenario files, and the trainer's periodic
# evaluation (training uses others; see train.learner.ppo), so no two ever replay each other.
SCENARIO_STREAM = 0x5CE7
TASK_STREAM = 0x7A5C
_NAME = re.compile(r"^[a-z][a-z0-9_]*$")
MAX_REACH = 2.0
"""The most a played command asks on any axis, in multiples of the robot's reach there
(units = "reach" in the file; "si" and mecanum-deploy-sim's --command once the robot is
known)."""
CommandKind = Literal["random", "sequence", "six_modes", "singular_pass"]


@dataclasses.dataclass(frozen=True)
class Defaults:
    episodes: int = 32
    seconds: float = 10.0
    seed: int = 7


_DEFAULT_KEYS = [f.name for f in dataclasses.fields(Defaults)]


@dataclasses.dataclass(frozen=True)
class ScenarioCommands:
    """How a scenario commands the robot (see the module docstring)."""

    kind: CommandKind = "random"
    sequence: tuple[tuple[float, float, float, float], ...] = ()
    units: Literal["reach", "si"] = "reach"
    speed: float = 0.5
    segment_s: float = 1.2
    pause_s: float = 0.3


@dataclasses.dataclass(frozen=True)
class Scenario:
    """One named scenario. ``mix`` and ``randomization`` hold the file's keys (overrides
    of the task's command mix, and of the nominal robot)."""

    name: str
    description: str
    episodes: int
    seconds: float
    seed: int
    commands: ScenarioCommands
    mix: dict[str, Any]
    randomization: dict[str, Any]
    noise: NoiseConfig
    truncate: bool = False  # cut a scripted sequence at ``seconds`` (set by an override)
    stream: int = SCENARIO_STREAM  # rng domain of its episodes (see episodes.scenario_key)

    @property
    def scripted(self) -> bool:
        """Whether the commands are a fixed sequence (so the intended path is known)."""
        return self.commands.kind != "random"

    def randomization_config(self, nominal_friction: float) -> RandomizationConfig:
        """The scenario's physics as a :class:`RandomizationConfig`: nominal where unset
        (as ranges pinned to the nominal values, so every scenario samples alike)."""
        return from_mapping(
            RandomizationConfig,
            {**_fixed_nominal(nominal_friction), **self.randomization},
            f"scenarios.{self.name}.randomization",
        )

    def command_config(self, task: CommandConfig) -> CommandConfig:
        """The task's command mix with this scenario's overrides."""
        return dataclasses.replace(task, **self.mix)


JUDGE_COMMANDS = CommandConfig(
    p_zero=0.1, p_translation=0.3, resample_min_s=1.0, resample_max_s=4.0
)
"""The command mix every drawn scenario starts from, whatever the training recipe's: the
judge does not move when a recipe (or the defaults, which are the shipped recipe) does."""


def _fixed_nominal(friction: float) -> dict[str, Any]:
    """Randomization ranges that pin every parameter to its nominal value: the floor's
    ``friction``, scale factors 1, everything else (spreads, payload, latency) 0."""
    ones = {"friction": friction, "radius_scale": 1.0, "torque_scale": 1.0, "gain_scale": 1.0}
    out: dict[str, Any] = {"enabled": True}
    for f in dataclasses.fields(RandomizationConfig):
        default = getattr(RandomizationConfig(), f.name)
        if isinstance(default, tuple):
            out[f.name] = tuple(type(x)(ones.get(f.name, 0)) for x in default)
        elif not isinstance(default, bool):
            out[f.name] = type(default)(0)
    return out


_SCENARIO_KEYS = (
    "description",
    "episodes",
    "seconds",
    "seed",
    "commands",
    "randomization",
    "noise",
)


def _check_keys(table: object, where: str, allowed: list[str]) -> dict[str, Any]:
    if not isinstance(table, dict):
        raise ConfigError(f"{where} = {table!r}: expected a table of keys")
    for key in table:
        if key not in allowed:
            raise ConfigError(
                f"{where}.{key} = {table[key]!r}: unknown key; expected keys of {where}: "
                f"{sorted(allowed)}"
            )
    return table


_RANDOMIZATION_KEYS = [
    f.name for f in dataclasses.fields(RandomizationConfig) if f.name != "enabled"
]


def parse_scenario(
    name: str, table: object, defaults: Defaults, base_randomization: dict[str, Any] | None = None
) -> Scenario:
    """One ``[scenarios.<name>]`` table, validated (errors name the field and value);
    ``base_randomization`` (the file's ``[defaults]`` one) lies under the table's own."""
    where = f"scenarios.{name}"
    if not _NAME.match(name):
        raise invalid(where, name, "scenario names are lower_snake_case (used in file names)")
    table = _check_keys(table, where, list(_SCENARIO_KEYS))
    description = table.get("description", "")
    if not isinstance(description, str):
        raise invalid(f"{where}.description", description, "expected a string")
    top = from_mapping(
        Defaults,
        {k: table.get(k, getattr(defaults, k)) for k in ("episodes", "seconds", "seed")},
        where,
    )
    require(top, where, ("episodes",), lambda v: 1 <= v <= 4096, "must be in [1, 4096]")
    require(top, where, ("seconds",), lambda v: 0 < v <= 600, "must be in (0, 600]")
    mix_keys = [f.name for f in dataclasses.fields(CommandConfig)]
    cmd_keys = [f.name for f in dataclasses.fields(ScenarioCommands)]
    cmd_table = _check_keys(table.get("commands", {}), f"{where}.commands", cmd_keys + mix_keys)
    commands = from_mapping(
        ScenarioCommands,
        {k: v for k, v in cmd_table.items() if k in cmd_keys},
        f"{where}.commands",
    )
    mix = {k: v for k, v in cmd_table.items() if k in mix_keys}
    rand = _check_keys(
        table.get("randomization", {}), f"{where}.randomization", _RANDOMIZATION_KEYS
    )
    rand = {**(base_randomization or {}), **rand}
    noise = (
        from_mapping(NoiseConfig, table["noise"], f"{where}.noise")
        if "noise" in table
        else NoiseConfig(scale=0.0)
    )
    scenario = Scenario(
        name=name,
        description=description,
        episodes=top.episodes,
        seconds=top.seconds,
        seed=top.seed,
        commands=commands,
        mix=mix,
        randomization=dict(rand),
        noise=noise,
    )
    _validate_commands(scenario, where)
    # value checks shared with the training config (ranges ordered, > 0, ...)
    EnvConfig(
        commands=scenario.command_config(JUDGE_COMMANDS),
        randomization=scenario.randomization_config(1.0),
        noise=noise,
    ).validate(where)
    return scenario


def _validate_commands(s: Scenario, where: str) -> None:
    c, w = s.commands, f"{where}.commands"
    if c.kind == "sequence":
        if not c.sequence:
            raise invalid(f"{w}.sequence", [], 'kind = "sequence" needs at least one segment')
        for i, seg in enumerate(c.sequence):
            if seg[3] <= 0:
                raise invalid(f"{w}.sequence[{i}]", list(seg), "a segment lasts > 0 seconds")
            if c.units == "reach" and max(abs(x) for x in seg[:3]) > MAX_REACH:
                raise invalid(
                    f"{w}.sequence[{i}]",
                    list(seg),
                    f'units = "reach": components in [-{MAX_REACH:g}, {MAX_REACH:g}]',
                )
        total = sum(seg[3] for seg in c.sequence)
        if total > s.seconds + 1e-9:
            raise invalid(f"{w}.sequence", f"{total} s", f"longer than the episode ({s.seconds} s)")
    elif c.sequence:
        raise invalid(
            f"{w}.sequence", list(c.sequence), f'only for kind = "sequence", not {c.kind!r}'
        )
    if c.kind != "random" and s.mix:
        key = sorted(s.mix)[0]
        raise invalid(f"{w}.{key}", s.mix[key], 'command-mix keys only apply to kind = "random"')
    require(
        c,
        w,
        ("speed",),
        lambda v: 0 < v <= MAX_REACH,
        f"must be in (0, {MAX_REACH:g}] (fraction of reach)",
    )
    require(c, w, ("segment_s",), lambda v: v > 0, "must be > 0")
    require(c, w, ("pause_s",), lambda v: v >= 0, "must be >= 0")


@dataclasses.dataclass(frozen=True)
class ScenarioSet:
    """The scenarios of one file, in file order."""

    source: str
    scenarios: tuple[Scenario, ...]

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.scenarios]

    def select(
        self,
        names: list[str] | tuple[str, ...] = (),
        episodes: int | None = None,
        seconds: float | None = None,
    ) -> ScenarioSet:
        """A subset by name (in the given order), optionally with fewer episodes or seconds."""
        by_name = {s.name: s for s in self.scenarios}
        unknown = [n for n in names if n not in by_name]
        if unknown:
            raise ConfigError(
                f"scenario {unknown[0]!r}: not in {self.source}; available: {self.names}"
            )
        chosen = [by_name[n] for n in names] if names else list(self.scenarios)
        if episodes is not None and not 1 <= episodes <= 4096:
            raise invalid("episodes", episodes, "must be in [1, 4096]")
        if seconds is not None and not 0 < seconds <= 600:
            raise invalid("seconds", seconds, "must be in (0, 600]")
        out = []
        for s in chosen:
            changes: dict[str, Any] = {}
            if episodes is not None:
                changes["episodes"] = episodes
            if seconds is not None:
                changes["seconds"] = seconds
                changes["truncate"] = True
            out.append(dataclasses.replace(s, **changes))
        return ScenarioSet(self.source, tuple(out))


def task_scenarios(task: EnvConfig, episodes: int, seconds: float, seed: int) -> ScenarioSet:
    """The training task's own held-out scenarios, built from its config: ``randomized``
    (its robots, floors, sensors and command mix) and ``nominal`` (the nominal robot, no
    sensor noise or latency, the same command mix). Their episodes come from a stream of
    their own (:data:`TASK_STREAM`): whatever ``seed``, they never replay a scenario
    file's."""
    r = task.randomization
    rand = {f.name: getattr(r, f.name) for f in dataclasses.fields(r)} if r.enabled else {}
    randomized = Scenario(
        name="randomized",
        description="the training distribution",
        episodes=episodes,
        seconds=seconds,
        seed=seed,
        commands=ScenarioCommands(),
        mix={},
        randomization=rand,
        noise=task.noise,
        stream=TASK_STREAM,
    )
    nominal = dataclasses.replace(
        randomized,
        name="nominal",
        description="the nominal robot, no sensor noise or latency",
        randomization={},
        noise=dataclasses.replace(task.noise, scale=0.0),
    )
    return ScenarioSet("the training task", (randomized, nominal))


def load_scenarios(
    path_or_name: str | Path = "default", _seen: tuple[Path, ...] = ()
) -> ScenarioSet:
    """A scenario file: a path, or the name of one in ``configs/eval/`` (``default``).
    ``include = ["paths", ...]`` appends the scenarios of other files (names or paths),
    each under its own ``[defaults]``, after the file's own."""
    path = find_config(path_or_name, EVAL_DIR, "scenarios", "scenario file")
    data = load_toml(path)
    _check_keys(data, f"{path}", ["defaults", "include", "scenarios"])
    top = dict(_check_keys(data.get("defaults", {}), "defaults", [*_DEFAULT_KEYS, "randomization"]))
    base = _check_keys(top.pop("randomization", {}), "defaults.randomization", _RANDOMIZATION_KEYS)
    defaults = from_mapping(Defaults, top, "defaults")
    tables = data.get("scenarios")
    if not isinstance(tables, dict) or not tables:
        raise ConfigError(f"{path}: scenarios: expected at least one [scenarios.<name>] table")
    scenarios = [parse_scenario(name, t, defaults, base) for name, t in tables.items()]
    include = data.get("include", [])
    if not isinstance(include, list) or not all(isinstance(x, str) for x in include):
        raise ConfigError(f"{path}: include = {include!r}: expected a list of file names")
    for other in include:
        found = find_config(other, EVAL_DIR, "scenarios", "scenario file")
        if found in (*_seen, path):
            raise ConfigError(f"{path}: include = {include!r}: {other!r} includes itself")
        for sc in load_scenarios(found, (*_seen, path)).scenarios:
            if sc.name in {s.name for s in scenarios}:
                raise ConfigError(f"{path}: include {other!r}: scenario {sc.name!r} twice")
            scenarios.append(sc)
    return ScenarioSet(str(path), tuple(scenarios))


__all__ = [
    "JUDGE_COMMANDS",
    "MAX_REACH",
    "Scenario",
    "ScenarioCommands",
    "ScenarioSet",
    "load_scenarios",
    "parse_scenario",
    "task_scenarios",
]
