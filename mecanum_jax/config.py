"""Typed configuration: frozen dataclasses loaded from TOML with strict validation.

Every config in ``configs/`` (robot descriptions now, run and scenario configs later) is
read through :func:`from_mapping`, which

- rejects unknown keys, naming the key, where it is, and the keys that are allowed;
- rejects missing required keys;
- checks each value's type (``bool`` is not accepted as a number, ``int`` is accepted
  where a ``float`` is expected), recursing into nested dataclasses and tuples of them.

Errors are :class:`ConfigError` and always name the dotted path of the field and the
offending value, e.g. ``geometry.wheel_radius = 'big': expected a number``.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.resources
import math
import tomllib
import types
import typing
import weakref
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any, Concatenate, Literal, ParamSpec, TypeVar, get_args, get_origin

T = TypeVar("T")
S = TypeVar("S")
P = ParamSpec("P")


class ConfigError(ValueError):
    """A configuration file or mapping is invalid. The message names field and value."""


def _join(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


def _convert(value: object, tp: Any, where: str) -> object:
    origin = get_origin(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        options = get_args(tp)
        if value is None and type(None) in options:
            return None
        errors = []
        for option in options:
            if option is type(None):
                continue
            try:
                return _convert(value, option, where)
            except ConfigError as err:
                errors.append(str(err))
        raise ConfigError(
            errors[0] if len(errors) == 1 else f"{where} = {value!r}: " + "; ".join(errors)
        )
    value = python_number(value)
    if origin is Literal:
        allowed = get_args(tp)
        if value not in allowed:
            raise ConfigError(f"{where} = {value!r}: expected one of {list(allowed)}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where} = {value!r}: expected true or false")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where} = {value!r}: expected an integer")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where} = {value!r}: expected a number")
        if not math.isfinite(value):
            raise ConfigError(f"{where} = {value!r}: expected a finite number")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where} = {value!r}: expected a string")
        return value
    if origin is tuple:
        args = get_args(tp)
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{where} = {value!r}: expected a list")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(v, args[0], f"{where}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(f"{where} = {value!r}: expected a list of {len(args)} items")
        return tuple(
            _convert(v, a, f"{where}[{i}]")
            for i, (v, a) in enumerate(zip(value, args, strict=True))
        )
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        return from_mapping(tp, value, where)
    raise TypeError(f"{where}: unsupported config field type {tp!r}")  # a bug in the schema


def python_number(value: object) -> object:
    """A NumPy or JAX scalar (a concrete 0-d array of bool, integer or float dtype) as the
    Python ``bool``/``int``/``float`` it holds; any other value unchanged. So
    ``np.float32(0.05)``, ``jnp.float32(0.05)`` and ``np.int64(3)`` pass wherever a number
    does. A traced scalar (inside ``jit``) has no value yet and comes back unchanged."""
    if isinstance(value, bool | int | float) or getattr(value, "shape", None) != ():
        return value
    kind = getattr(getattr(value, "dtype", None), "kind", None)
    convert = {"b": bool, "i": int, "u": int, "f": float}.get(kind)  # type: ignore[arg-type]
    if convert is None:
        return value
    try:
        return convert(value)
    except Exception:  # a tracer: no concrete value to convert
        return value


def invalid(path: str, value: object, why: str) -> ConfigError:
    """The error for a well-typed value out of its range: ``path = value: why``."""
    return ConfigError(f"{path} = {value!r}: {why}")


def require(
    section: object, where: str, names: Iterable[str], ok: Callable[[Any], bool], why: str
) -> None:
    """Raise :func:`invalid` for the first field of ``section`` among ``names`` failing ``ok``.

    ``where`` is the dotted path of ``section`` (e.g. ``"env.noise"``).
    """
    for name in names:
        value = getattr(section, name)
        if not ok(value):
            raise invalid(f"{where}.{name}", value, why)


def validated_once(validate: Callable[Concatenate[S, P], S]) -> Callable[Concatenate[S, P], S]:
    """A frozen config's ``validate(self, ...) -> self``, run once per object: an object
    that passed is returned at once on later calls (frozen, it cannot have changed), so the
    layers a config passes through may each ask for it. A copy (``dataclasses.replace``, a
    config read again) is another object, checked anew."""
    passed: weakref.WeakValueDictionary[int, S] = weakref.WeakValueDictionary()

    @functools.wraps(validate)
    def once(self: S, *args: P.args, **kwargs: P.kwargs) -> S:
        if passed.get(id(self)) is not self:
            validate(self, *args, **kwargs)
            passed[id(self)] = self
        return self

    return once


def _short(value: object, limit: int = 80) -> str:
    """A value for an error message, cut at ``limit``; a long table named by its keys."""
    text = repr(value)
    if len(text) > limit and isinstance(value, Mapping):
        text = f"a table of keys {sorted(value)}"
    return text if len(text) <= limit else text[: limit - 3] + "..."


def from_mapping(cls: type[T], data: object, where: str = "") -> T:
    """Build the frozen dataclass ``cls`` from a mapping, validating every key.

    Args:
      cls: a dataclass type whose fields are annotated with supported types (``bool``,
        ``int``, ``float``, ``str``, ``Literal``, ``X | None``, ``tuple[X, ...]``, nested
        dataclasses).
      data: the mapping, e.g. one table of a parsed TOML file.
      where: the dotted path of ``data`` in its file, used in error messages.
    """
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where or 'config'} = {data!r}: expected a table of keys")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}  # type: ignore[arg-type]
    unknown = sorted(set(data) - set(fields))
    if unknown:
        key = unknown[0]
        raise ConfigError(
            f"{_join(where, key)} = {_short(data[key])}: unknown key; "
            f"expected keys of {where or cls.__name__}: {sorted(fields)}"
        )
    kwargs = {}
    for name, field in fields.items():
        path = _join(where, name)
        if name not in data:
            no_default = (
                field.default is dataclasses.MISSING
                and field.default_factory is dataclasses.MISSING
            )
            if no_default:
                raise ConfigError(f"{path}: missing required key")
            continue
        kwargs[name] = _convert(data[name], hints[name], path)
    return cls(**kwargs)


def find_config(value: str | Path, folder: Path, field: str, what: str) -> Path:
    """The file a config setting names: a path (``value`` has a suffix such as ``.toml``
    or holds a ``/``) or the name of a built-in file ``folder/<value>.toml``.

    Errors name ``field`` and ``value``; for a name, they list the built-in ones (``what``
    says what they are, e.g. ``"built-in description"``).
    """
    text = str(value)
    if Path(text).suffix or "/" in text:
        if not Path(text).is_file():
            raise ConfigError(f"{field} = {text!r}: no such file")
        return Path(text)
    path = folder / f"{text}.toml"
    if not path.is_file():
        known = sorted(p.stem for p in folder.glob("*.toml"))
        raise ConfigError(f"{field} = {text!r}: no such {what}; known: {known}")
    return path


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file, turning I/O and syntax errors into :class:`ConfigError`."""
    return parse_toml(read_config_bytes(path), path)


def read_config_bytes(path: str | Path) -> bytes:
    """A config file's bytes, turning I/O errors into :class:`ConfigError`."""
    path = Path(path)
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise ConfigError(f"config file {str(path)!r}: no such file") from None
    except IsADirectoryError:
        raise ConfigError(f"config file {str(path)!r}: is a directory, not a file") from None
    except OSError as err:
        raise ConfigError(f"config file {str(path)!r}: cannot read it ({err.strerror})") from None


def parse_toml(data: bytes, path: str | Path) -> dict[str, Any]:
    """Parse a config file's bytes (``path`` names it in errors)."""
    try:
        return tomllib.loads(data.decode("utf-8"))
    except UnicodeDecodeError:
        raise ConfigError(f"config file {str(path)!r}: not a text file (UTF-8)") from None
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"config file {str(path)!r}: invalid TOML: {err}") from None


def package_data(packaged: str, in_clone: str) -> Path:
    """A folder of data the wheel ships inside the package as ``mecanum_jax/<packaged>``
    (pyproject.toml's force-include), else the clone's ``<in_clone>`` (a checkout, or an
    editable install of one)."""
    inside = Path(str(importlib.resources.files("mecanum_jax"))) / packaged
    return inside if inside.is_dir() else Path(__file__).resolve().parent.parent / in_clone


CONFIG_DIR = package_data("configs", "configs")
"""The built-in configs: robots, run configs, scenarios."""
