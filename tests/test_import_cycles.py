"""No import cycles in mecanum_jax/ and train/: the module graph, read from the source,
is acyclic.

Every import counts: at module level, inside functions and under ``TYPE_CHECKING``.
Relative imports are resolved, and ``from pkg import name`` is an import of the module
``pkg.name`` where there is one, else of the package ``pkg`` (its ``__init__.py``). A
package's ``__init__.py`` importing its own modules is no cycle by itself; a module that
imports its package's ``__init__.py`` back is.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("mecanum_jax", "train")


def find_modules(root: Path, packages: tuple[str, ...]) -> dict[str, Path]:
    """Dotted module name -> file, for every ``.py`` file under the packages."""
    found = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join(parts)] = path
    return found


def _known(name: str, modules: dict[str, Path]) -> str | None:
    """``name`` or its longest prefix that is one of ``modules`` (``from a.b import f``
    with ``f`` no module: ``a.b``)."""
    parts = name.split(".")
    for end in range(len(parts), 0, -1):
        candidate = ".".join(parts[:end])
        if candidate in modules:
            return candidate
    return None


def imports_of(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The modules among ``modules`` that module ``name`` (file ``path``) imports."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [_known(a.name, modules) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join([*up, *([node.module] if node.module else [])])
            targets = [
                f"{base}.{a.name}" if f"{base}.{a.name}" in modules else _known(base, modules)
                for a in node.names
            ]
        else:
            continue
        out.update(t for t in targets if t is not None and t != name)
    return out


def import_graph(root: Path, packages: tuple[str, ...]) -> dict[str, set[str]]:
    modules = find_modules(root, packages)
    return {name: imports_of(name, path, modules) for name, path in modules.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle as ``[a, b, ..., a]`` (a depth-first search from each module in order),
    or ``None``."""
    done: set[str] = set()
    stack: list[str] = []
    on_stack: set[str] = set()

    def visit(node: str) -> list[str] | None:
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(graph.get(node, ())):
            if nxt in on_stack:
                return [*stack[stack.index(nxt) :], nxt]
            if nxt not in done:
                cycle = visit(nxt)
                if cycle:
                    return cycle
        stack.pop()
        on_stack.discard(node)
        done.add(node)
        return None

    for start in sorted(graph):
        if start not in done:
            cycle = visit(start)
            if cycle:
                return cycle
    return None


def test_no_import_cycles():
    cycle = find_cycle(import_graph(ROOT, PACKAGES))
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def test_the_graph_sees_every_kind_of_import():
    """The graph above is the real one: type-only imports, ``from pkg import module`` and
    imports inside functions are all in it (else the test could pass by seeing nothing)."""
    graph = import_graph(ROOT, PACKAGES)
    assert len(graph) > 50
    # under TYPE_CHECKING
    assert "mecanum_jax.task.env" in graph["train.learner.losses"]
    # from mecanum_jax.task import commands as cmds
    assert "mecanum_jax.task.commands" in graph["mecanum_jax.task.env"]
    # inside restore_policy
    assert {"train.learner.state", "train.config_loading"} <= graph["train.learner.policy"]
    # from mecanum_jax.task import REFERENCES, MecanumEnv: the package's __init__.py
    assert "mecanum_jax.task" in graph["train.cli.eval_target"]


def _write(root: Path, files: dict[str, str]) -> None:
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def test_the_check_finds_a_cycle(tmp_path):
    """A tiny package whose cycle runs through a relative import, a type-only import and
    ``from pkg import module``: it is found and named; with one link cut, there is none."""
    _write(
        tmp_path,
        {
            "pkg/__init__.py": "from pkg.a import A\n",
            "pkg/a.py": "from . import b\nA = 1\n",
            "pkg/b.py": (
                "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pkg.sub.c import C\n"
            ),
            "pkg/sub/__init__.py": "",
            "pkg/sub/c.py": "import json\n\ndef f():\n    from ..a import A\n    return A\n",
        },
    )
    graph = import_graph(tmp_path, ("pkg",))
    assert find_cycle(graph) == ["pkg.a", "pkg.b", "pkg.sub.c", "pkg.a"]
    (tmp_path / "pkg/sub/c.py").write_text("import json\n")
    assert find_cycle(import_graph(tmp_path, ("pkg",))) is None


def test_a_module_importing_its_own_package_init_is_a_cycle(tmp_path):
    """``__init__.py`` re-exporting a module is fine; that module importing the package's
    ``__init__.py`` back is the cycle."""
    _write(
        tmp_path,
        {
            "pkg/__init__.py": "from pkg.env import Env\nX = 1\n",
            "pkg/env.py": "class Env: ...\n",
        },
    )
    assert find_cycle(import_graph(tmp_path, ("pkg",))) is None
    (tmp_path / "pkg/env.py").write_text("from pkg import X\n")
    assert find_cycle(import_graph(tmp_path, ("pkg",))) == ["pkg", "pkg.env", "pkg"]
