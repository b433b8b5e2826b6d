"""Identification-Jacobian time of each measurement model against the position model (issue 23).

HSR-JR680, n = 2 000 samples (and 20 000), float64, ``Problem.jacobian`` (``jax.jacfwd`` of the
residual with respect to the free parameters) jitted; every DH deviation (+β at the Hayati
joint) and the tool point free, plus each model's own extras: the sensor frame (position,
6), three planes (plane, 9), two pivot points (point, 6), two spheres with unknown radii
(sphere, 8), none (distance bar: two poses per row, so twice the kinematics); the camera
(eye-in-hand, a 9×6 checkerboard: 108 residual rows per image) with its hand-eye and target
pose (12; the tool point does not act on an image), at n = 2 000 images only (its 20 000-image
Jacobian is 0.7 GB). Median of repeated calls after compilation, the models timed in turn
(round robin) so that load from other processes hits them alike; ``uptime`` load average
printed with the table. Target: each model within 2× of the position model for the same robot
and sample count; the table also gives the time per residual row against the position model's.

Run:  python benchmarks/bench_sensors.py      (writes benchmarks/results/sensors_<platform>.md)
"""

from __future__ import annotations

import os
import pathlib
import time

import jax
import numpy as np
from _common import machine

import jaxcal
from jaxcal import FixedPoint, ParameterSpace, Position, Problem, simulate_contact
from jaxcal._sensors._contact import DistanceBar, default_setup
from jaxcal._simulation._simulate_sensors import simulate_camera, simulate_distance

jaxcal.enable_x64()


def _models(robot):
    p = default_setup("point", robot)
    sphere = FixedPoint(p.labels, np.asarray(p.centres), [25.0, 25.0], estimate_radius=True)
    return {"position": (Position(), {"base": True}), "plane": (default_setup("plane", robot), {}),
            "point": (p, {}), "sphere": (sphere, {}), "distance": (DistanceBar(robot.dof), {}),
            "camera": (None, {"tool": False})}


def _data(robot, name, m, n):
    if name == "camera":
        q, y, cam, _ = simulate_camera(jax.random.key(0), robot, n_views=n, noise_px=0.3)
        return q, y, cam
    if name == "distance":
        ex = simulate_distance(jax.random.key(0), robot, n_samples=n, noise_std=0.05, test_fraction=0.0)
        return ex.train.q, ex.train.y
    if name == "position":
        q = jaxcal._models._robot.sample_joint_angles(jax.random.key(0), robot, n)
        return q, m.predict(robot, None, q)
    ex = simulate_contact(jax.random.key(0), robot, m, n_samples=n, noise_std=0.05, test_fraction=0.0)
    return ex.train.q, ex.train.y


def main() -> None:
    robot = jaxcal.robots.hsr_jr680()
    jac = jax.jit(lambda p, x: p.jacobian(x))
    lines = ["# Identification Jacobian per measurement model (issue 23)", "", f"Machine: {machine()}", "",
             "| n | model | residual rows | free parameters | Jacobian / ms | × position | ns per row | "
             "× position per row |",
             "| ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for n in (2_000, 20_000):
        probs = {}
        for name, (m, flags) in _models(robot).items():
            if name == "camera":
                if n > 2_000:
                    continue
                q, y, m = _data(robot, name, m, n)
            else:
                q, y = _data(robot, name, m, n)
            space = ParameterSpace.for_robot(robot, measurement=m, **{"tool": True, **flags})
            pr = Problem(robot, m, q, y, space)
            x = pr.x0()
            jax.block_until_ready(jac(pr, x))
            probs[name] = (pr, x, space.n_free, q.shape[0] * m.size)
        times = {k: [] for k in probs}
        for _ in range(15 if n == 2_000 else 5):
            for k, (pr, x, _, _) in probs.items():
                t = time.perf_counter()
                jax.block_until_ready(jac(pr, x))
                times[k].append(time.perf_counter() - t)
        med = {k: float(np.median(v)) for k, v in times.items()}
        per_row = {k: med[k] / rows for k, (_, _, _, rows) in probs.items()}
        for k, (_, _, p, rows) in probs.items():
            lines.append(f"| {n} | {k} | {rows} | {p} | {1e3 * med[k]:.2f} | {med[k] / med['position']:.2f} | "
                         f"{1e9 * per_row[k]:.0f} | {per_row[k] / per_row['position']:.2f} |")
    load = os.getloadavg()
    lines += ["", f"Load average while measuring (1/5/15 min): {load[0]:.2f} / {load[1]:.2f} / {load[2]:.2f} "
              f"on {os.cpu_count()} cores (other processes share the machine)."]
    out = pathlib.Path(__file__).parent / "results" / f"sensors_{jax.devices()[0].platform}.md"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
