# the documented commands, from the repository root, on the 2-core CPU (2026-11-26), for the
# policy shipped last that day (the spin anchor); console scripts stand for these modules. Outputs go to
# runs/ and the logs beside this file: bash docs/results/2026-11-26-deployment/commands.sh
set -e
D=docs/results/2026-11-26-deployment
export GLIBC_TUNABLES=glibc.malloc.hugetlb=1 JAX_PLATFORMS=cpu
P=.venv/bin/python
mkdir -p runs/robot
rm -rf runs/eval-nominal runs/eval-sensor-noise runs/robot/policy.npz runs/robot/policy.onnx $D/deploy-*.json  # deploy_sim never overwrites
$P -m train.export models/o_rectangle runs/robot/policy.npz > $D/export_npz.txt 2>&1
$P -m train.export models/o_rectangle runs/robot/policy.onnx --format onnx > $D/export_onnx.txt 2>&1
cp docs/results/2026-11-25-deployment/robot_loop.py runs/robot/  # the same loop as that day
(cd runs/robot && ../../.venv/bin/python robot_loop.py) > $D/loop_demo.txt 2>&1
$P -m train.evaluate models/o_rectangle --only nominal --physics-impl jax --no-plots --out runs/eval-nominal > $D/eval_nominal.txt 2>&1
cp runs/eval-nominal/report.json $D/eval_nominal_report.json
$P -m train.deploy_sim --out $D/deploy-nominal.json > $D/deploy_nominal.txt 2>&1
$P -m train.deploy_sim --backend onnx --out $D/deploy-nominal-onnx.json > $D/deploy_nominal_onnx.txt 2>&1
$P -m train.deploy_sim --command 0.3 0 0.5 --seconds 5 --latency 2 --noise-scale 1 --out $D/deploy-command.json > $D/deploy_command.txt 2>&1
$P -m train.deploy_sim --command 0.3 0 0.5 --seconds 5 --out $D/deploy-command-exact.json > $D/deploy_command_exact.txt 2>&1
$P -m train.evaluate models/o_rectangle --only sensor_noise --references analytic --no-plots --out runs/eval-sensor-noise > $D/eval_sensor_noise.txt 2>&1
cp runs/eval-sensor-noise/report.json $D/eval_sensor_noise_report.json
$P -m train.deploy_sim --scenario sensor_noise --out $D/deploy-sensor-noise.json > $D/deploy_sensor_noise.txt 2>&1
