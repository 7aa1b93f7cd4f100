# the documented commands, from the repository root; console scripts stand for these modules
export PYTHONPATH=/work/wt-deploy GLIBC_TUNABLES=glibc.malloc.hugetlb=1 JAX_PLATFORMS=cpu JAX_COMPILATION_CACHE_DIR=/tmp/jaxcache
P=/work/main/.venv/bin/python
cd /work/wt-deploy
rm -rf runs/robot runs/deploy-*.json runs/eval-nominal runs/eval-sensor-noise
EXPORT='import sys; from train.evaluate import export_main; sys.exit(export_main(sys.argv[1:]))'
$P -c "$EXPORT" models/o_rectangle runs/robot/policy.npz > /tmp/final/export_npz.txt 2>&1
$P -c "$EXPORT" models/o_rectangle runs/robot/policy.onnx --format onnx > /tmp/final/export_onnx.txt 2>&1
cp /tmp/dd/robot/robot_loop.py runs/robot/
(cd runs/robot && $P robot_loop.py > /tmp/final/loop_demo.txt 2>&1)
$P -m train.evaluate models/o_rectangle --only nominal --references analytic --no-plots --out runs/eval-nominal > /tmp/final/eval_nominal.txt 2>&1
$P -m train.deploy_sim --out runs/deploy-nominal.json > /tmp/final/deploy_nominal.txt 2>&1
$P -m train.deploy_sim --backend onnx --out runs/deploy-nominal-onnx.json > /tmp/final/deploy_nominal_onnx.txt 2>&1
$P -m train.deploy_sim --fidelity reference --out runs/deploy-nominal-reference.json > /tmp/final/deploy_nominal_reference.txt 2>&1
$P -m train.deploy_sim --command 0.3 0 0.5 --seconds 5 --latency 2 --noise-scale 1 --out runs/deploy-command.json > /tmp/final/deploy_command.txt 2>&1
$P -m train.evaluate models/o_rectangle --only sensor_noise --references analytic --no-plots --out runs/eval-sensor-noise > /tmp/final/eval_sensor_noise.txt 2>&1
$P -m train.deploy_sim --scenario sensor_noise --out runs/deploy-sensor-noise.json > /tmp/final/deploy_sensor_noise.txt 2>&1
$P -m mecanum_jax.deploy.ros2 o_rectangle --to-ros > /tmp/final/ros2.txt 2>&1
$P -m train.deploy_sim --command 0.3 0 0.5 --seconds 5 --out runs/deploy-command-exact.json > /tmp/final/deploy_command_exact.txt 2>&1
echo done > /tmp/final/ALLDONE
