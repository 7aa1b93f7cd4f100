"""A probe at play time: ``mecanum-eval`` of a trained policy with fields of its task's
``[env]`` changed (what it was not trained with), e.g. a wider deadband on the network's action::

    python scripts/play_probe.py residual_deadband=0.01 -- models/o_rectangle \
        --scenarios tuning --only tuning_weave --no-plots --out /tmp/probe

Each ``FIELD=VALUE`` (a float, an int or true/false) replaces ``env.FIELD``, or a field of
one of its sections (``feedback.margin=0.05``), of every config read, the checkpoint's and
its config.json alike (``mecanum-eval`` refuses the two when they differ), and on top of a
model's own ``played_with``; the references play the same changed task. A probe says
whether a lever is worth training, never what a trained policy would do.
"""

from __future__ import annotations

import dataclasses
import sys
from typing import Any

import mecanum_jax.task.config as task_config
import train.config_loading as config_loading
from mecanum_jax.config import ConfigError
from mecanum_jax.task.config import EnvConfig


def _value(text: str) -> Any:
    if text.lower() in ("true", "false"):
        return text.lower() == "true"
    return int(text) if text.lstrip("-").isdigit() else float(text)


def _changed(env: EnvConfig, changes: dict[str, Any]) -> EnvConfig:
    """``env`` with ``changes`` (``FIELD`` or ``SECTION.FIELD``: value), validated."""
    for name, value in changes.items():
        section, dot, field = name.rpartition(".")
        if dot:
            part = dataclasses.replace(getattr(env, section), **{field: value})
            env = dataclasses.replace(env, **{section: part})
        else:
            env = dataclasses.replace(env, **{field: value})
    return env.validate("env")


def main(argv: list[str]) -> int:
    if "--" not in argv:
        print(__doc__, file=sys.stderr)
        return 2
    cut = argv.index("--")
    defaults = EnvConfig()
    fields = set()
    for f in dataclasses.fields(EnvConfig):
        value = getattr(defaults, f.name)
        if isinstance(value, (float, int, bool)):
            fields.add(f.name)
        elif dataclasses.is_dataclass(value):  # a section: its scalar fields
            fields |= {
                f"{f.name}.{g.name}"
                for g in dataclasses.fields(value)
                if isinstance(getattr(value, g.name), (float, int, bool))
            }
    env_changes: dict[str, Any] = {}
    for item in argv[:cut]:
        name, eq, text = item.partition("=")
        if not eq or name not in fields:
            print(
                f"error: {item!r}: expected FIELD=VALUE, FIELD one of env's {sorted(fields)}",
                file=sys.stderr,
            )
            return 2
        try:
            env_changes[name] = _value(text)
        except ValueError:
            print(f"error: env.{name} = {text!r}: expected a number or true/false", file=sys.stderr)
            return 2
    try:
        _changed(defaults, env_changes)
    except ConfigError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    parse = config_loading.parse_train_config

    def changed(data: Any, source: str, validate: bool = True) -> Any:
        cfg = parse(data, source, validate)
        return dataclasses.replace(cfg, env=_changed(cfg.env, env_changes))

    config_loading.parse_train_config = changed
    played = task_config.played_with

    def played_then_changed(env: EnvConfig, changes: object, where: str) -> EnvConfig:
        # a model's own play-time fields (provenance.json) come after its checkpoint's
        # config: the probe's changes go on top of them too
        return _changed(played(env, changes, where), env_changes)

    task_config.played_with = played_then_changed
    from train.cli import evaluate

    return evaluate.main(argv[cut + 1 :])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
