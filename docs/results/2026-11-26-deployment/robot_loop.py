import time

import numpy as np
from mecanum_loop import Controller

for path in ("policy.npz", "policy.onnx"):
    ctrl = Controller.load(path)
    ctrl.reset()  # robot at rest
    command = [0.3, 0.0, 0.5]  # vx, vy m/s, ωz rad/s
    wheel_rate, gyro_z, accel = np.zeros(4), 0.0, [0.0, 0.0, 9.81]  # newest readings
    t0 = time.perf_counter()
    for _ in range(500):  # 10 s of 50 Hz ticks, sensors frozen at rest
        setpoints, action = ctrl.step(command, wheel_rate, gyro_z, accel)
    tick_us = (time.perf_counter() - t0) / 500 * 1e6
    print(f"{ctrl.backend}: setpoints {np.round(setpoints, 2)} rad/s, action {np.round(action, 3)}")
    print(
        f"  feedback integral {ctrl.values['feedback_integral']:.3f} rad/s,"
        f" {tick_us:.0f} µs per tick"
    )
