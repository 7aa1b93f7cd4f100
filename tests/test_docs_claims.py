"""The manual's claims about the shipped recipe match the recipe: every ``name = value``
that docs/training.md's table "Why the settings are what they are" gives is what
``--config gpu`` resolves to (a bare name is the one setting of that name); and its pages
keep their length."""

import re
import tomllib
from pathlib import Path

import pytest

from train.config_loading import load_train_config

DOCS = Path(__file__).resolve().parent.parent / "docs"
CLAIM = re.compile(r"`([a-z_][a-z_.]*) = ([^`]+)`")


def _leaves(tree, prefix=""):
    for key, value in tree.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict):
            yield from _leaves(value, f"{path}.")
        else:
            yield path, value


def _claims(text):
    table = text.split("## Why the settings are what they are", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in table.splitlines() if line.startswith("| ")]
    return [m.groups() for row in rows for m in CLAIM.finditer(row)]


def _setting(leaves, name):
    """The value of the setting ``name``: a full path, or the one leaf ending in it."""
    if name in leaves:
        return leaves[name]
    found = [path for path in leaves if path.endswith(f".{name}")]
    assert len(found) == 1, f"`{name}` names {found or 'no setting'} of the gpu config"
    return leaves[found[0]]


def test_the_training_manuals_recipe_table_is_the_gpu_config():
    leaves = dict(_leaves(load_train_config("gpu").to_dict()))
    claims = _claims((DOCS / "training.md").read_text())
    assert len(claims) >= 10  # the table is there and read
    wrong = []
    for name, text in claims:
        claimed = tomllib.loads(f"v = {text}")["v"]
        actual = _setting(leaves, name)
        if actual != (pytest.approx(claimed) if isinstance(claimed, float) else claimed):
            wrong.append(f"`{name} = {text}`: the gpu config has {actual!r}")
    assert not wrong, wrong


def test_a_wrong_claim_is_caught():
    """The check can fail: a claim the config contradicts, and one that names nothing."""
    leaves = dict(_leaves(load_train_config("gpu").to_dict()))
    ((name, text),) = _claims("## Why the settings are what they are\n| `env.path_tau = 9` | x |")
    assert _setting(leaves, name) != tomllib.loads(f"v = {text}")["v"]
    with pytest.raises(AssertionError, match="no setting"):
        _setting(leaves, "no_such_setting")


@pytest.mark.parametrize(("page", "most"), [("docs/controller.md", 250), ("README.md", 200)])
def test_the_manual_pages_stay_within_their_length(page, most):
    """The controller's page and the README stay a manual, not a notebook: a finding goes
    into the reasoning or one row of Levers tried, and a page over its length is cut."""
    lines = (DOCS.parent / page).read_text().splitlines()
    assert len(lines) <= most, f"{page}: {len(lines)} lines (at most {most})"
