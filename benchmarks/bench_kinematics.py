"""Residual and jacfwd-Jacobian evaluation time for the draw-wire model (issue 2 benchmark).

HSR-JR680, distance to a fixed anchor, all 24 DH deviations free, n = 2 000 / 20 000 /
200 000 samples, float64 and float32; median of repeated calls after jit compilation.
Target on the project's 2-core CPU: Jacobian for 2 000 samples × 24 parameters in ≤ 5 ms.

Run:  python benchmarks/bench_kinematics.py   (writes benchmarks/results/kinematics_<platform>.md)
"""

from __future__ import annotations

import pathlib

import jax
import jax.numpy as jnp
from _common import machine, median_time

import jaxcal
from jaxcal import CableLength, ParameterSpace, Problem

jaxcal.enable_x64()


def main():
    robot = jaxcal.robots.hsr_jr680()
    meas = CableLength(jnp.asarray([1600.0, 0.0, 0.0]))
    space = ParameterSpace.for_robot(robot)
    rows = []
    res_fn = jax.jit(lambda p, x: p.residual(x))
    jac_fn = jax.jit(lambda p, x: p.jacobian(x))
    for n in (2_000, 20_000, 200_000):
        q = jaxcal._simulate.sample_joint_angles(jax.random.PRNGKey(0), robot, n)
        for dtype in (jnp.float64, jnp.float32):
            qd = q.astype(dtype)
            y = meas.predict(robot, None, qd)
            prob = Problem(robot, meas, qd, y, space)
            x = jnp.zeros(space.n_free, dtype)
            reps = 50 if n <= 20_000 else 10
            t_r = median_time(res_fn, prob, x, repeats=reps)
            t_j = median_time(jac_fn, prob, x, repeats=reps)
            rows.append((n, jnp.dtype(dtype).name, t_r * 1e3, t_j * 1e3))
            print(rows[-1], flush=True)
    lines = [
        "# Residual and Jacobian timing (draw-wire model, HSR-JR680, 24 free DH deviations)",
        "",
        f"Machine: {machine()}.",
        "Median of repeated calls after `jax.jit` compilation; Jacobian = `jax.jacfwd` of the",
        "flat residual vector (structure-of-arrays FK). Target: ≤ 5 ms for 2 000 × 24 on 2 CPU cores.",
        "",
        "| samples | dtype | residuals / ms | jacfwd Jacobian / ms |",
        "|---:|---|---:|---:|",
    ]
    lines += [f"| {n:,} | {dt} | {r:.3f} | {j:.3f} |" for n, dt, r, j in rows]
    plat = jax.devices()[0].platform
    out = pathlib.Path(__file__).parent / "results" / f"kinematics_{plat}.md"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
