# the documented commands, from the repository root, on the 2-core CPU (2026-11-25);
# console scripts stand for these modules; outputs beside this file
export GLIBC_TUNABLES=glibc.malloc.hugetlb=1 JAX_PLATFORMS=cpu
P=.venv/bin/python
$P -m train.export models/o_rectangle runs/robot/policy.npz > export_npz.txt 2>&1
$P -m train.export models/o_rectangle runs/robot/policy.onnx --format onnx > export_onnx.txt 2>&1
cp docs/results/2026-11-25-deployment/robot_loop.py runs/robot/
(cd runs/robot && ../../.venv/bin/python robot_loop.py) > loop_demo.txt 2>&1
$P -m train.evaluate models/o_rectangle --only nominal --physics-impl jax --no-plots --out runs/eval-nominal > eval_nominal.txt 2>&1
$P -m train.deploy_sim --out runs/deploy-nominal.json > deploy_nominal.txt 2>&1
$P -m train.deploy_sim --backend onnx --out runs/deploy-nominal-onnx.json > deploy_nominal_onnx.txt 2>&1
$P -m train.deploy_sim --fidelity reference --out runs/deploy-nominal-reference.json > deploy_nominal_reference.txt 2>&1
$P -m train.deploy_sim --command 0.3 0 0.5 --seconds 5 --latency 2 --noise-scale 1 --out runs/deploy-command.json > deploy_command.txt 2>&1
$P -m train.deploy_sim --command 0.3 0 0.5 --seconds 5 --out runs/deploy-command-exact.json > deploy_command_exact.txt 2>&1
$P -m train.evaluate models/o_rectangle --only sensor_noise --references analytic --no-plots --out runs/eval-sensor-noise > eval_sensor_noise.txt 2>&1
$P -m train.deploy_sim --scenario sensor_noise --out runs/deploy-sensor-noise.json > deploy_sensor_noise.txt 2>&1
$P -m mecanum_jax.deploy.ros2 o_rectangle --to-ros > ros2.txt 2>&1
