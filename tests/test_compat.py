"""The jax.device_put_replicated compatibility shim (mecanum_jax.compat)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mecanum_jax import compat


def test_importing_the_library_leaves_jax_untouched(fresh_imports):
    """``import mecanum_jax`` (and its physics, task and evaluation modules) changes no
    attribute of the ``jax`` module; only the trainer installs the shim (in a fresh
    interpreter: ``fresh_imports`` in conftest.py)."""
    proc, findings = fresh_imports
    assert proc.returncode == 0, proc.stderr
    assert findings["changed"] == []
    assert findings["shim"]


def test_installed_when_missing():
    # importing the trainer installed it (jax >= 0.10 lacks it) or jax still has its own
    fn = jax.device_put_replicated
    assert callable(fn)
    if not compat.has_native_device_put_replicated():
        assert fn is compat.device_put_replicated


def test_replicates_a_pytree_onto_each_device():
    devices = jax.local_devices()
    assert len(devices) == 2  # tests/conftest.py forces two host devices
    tree = {"w": jnp.arange(6.0).reshape(2, 3), "step": jnp.int32(7), "key": jax.random.PRNGKey(3)}
    out = compat.device_put_replicated(tree, devices)
    assert out["w"].shape == (2, 2, 3)
    assert out["step"].shape == (2,)
    np.testing.assert_array_equal(out["w"][1], tree["w"])
    np.testing.assert_array_equal(out["key"][0], tree["key"])
    for k, shard in enumerate(sorted(out["w"].addressable_shards, key=lambda s: s.index[0].start)):
        assert shard.device == devices[k]
        np.testing.assert_array_equal(shard.data[0], tree["w"])


def test_pmap_consumes_the_replicated_value():
    devices = jax.local_devices()
    rep = compat.device_put_replicated(jnp.array([1.0, 2.0]), devices)
    out = jax.pmap(lambda x: x * 2 + jax.lax.axis_index("i"), axis_name="i")(rep)
    np.testing.assert_array_equal(out, [[2.0, 4.0], [3.0, 5.0]])


def test_rejects_no_devices():
    with pytest.raises(ValueError, match="devices = \\[\\]"):
        compat.device_put_replicated(jnp.zeros(2), [])


def test_does_not_replace_a_native_implementation(monkeypatch):
    sentinel = object()

    def native(x, devices):
        return sentinel

    monkeypatch.setattr(jax, "device_put_replicated", native, raising=False)
    assert compat.has_native_device_put_replicated()
    assert compat.install() is False
    assert jax.device_put_replicated is native


def test_brax_pmap_helper_works():
    from brax.training import pmap as brax_pmap

    out = brax_pmap.bcast_local_devices(jnp.ones(3), 2)
    assert out.shape == (2, 3)
