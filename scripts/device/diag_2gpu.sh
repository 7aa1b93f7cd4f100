python3 -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site .whl/*.whl 2>&1 | grep -v "already exists"; export PYTHONPATH=/tmp/site:$PWD XLA_PYTHON_CLIENT_PREALLOCATE=false PYTHONUNBUFFERED=1; unset MUJOCO_GL
python3 -X faulthandler -c "
import jax, jax.numpy as jnp
try:
    print('zero-size pmap', jax.pmap(lambda x: x)(jnp.zeros((2, 0))).shape)
except Exception as e: print('zero-size pmap error', e)
" 2>&1 | tail -2
python3 -X faulthandler -c "
import jax, jax.numpy as jnp
print(jax.devices())
print(jax.pmap(lambda x: x*2)(jnp.arange(2.)))
print(jax.pmap(lambda x: jax.lax.psum(x, 'i'), axis_name='i')(jnp.arange(2.)))
" 2>&1 | grep -v -i warp | tail -5
python3 -X faulthandler -m train.bench --config tiny --epochs 2 --variant 2gpu 2>&1 | grep -v -i warp | grep -v '^\s*"' | grep -v "^Extension" | tail -25
