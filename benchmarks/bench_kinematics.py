"""Residual and jacfwd-Jacobian evaluation time for the draw-wire model (issue 2 benchmark).

HSR-JR680, distance to a fixed anchor, all 24 DH deviations free, n = 2 000 / 20 000 /
200 000 samples, float64 and float32; median of repeated calls after jit compilation.
Target on the project's 2-core CPU: Jacobian for 2 000 samples × 24 parameters in ≤ 5 ms.

Generic chains (issue 11): the same robot as a :class:`jaxcal.SerialChain` (``chain_from_dh``),
its per-joint errors (offset, dx, dy, dz, drx, dry: 36 columns) against the DH kernel's 24, and
the chain with 24 columns (offset, dx, dy, drx) for a per-column comparison; DH and chain timed
alternately in the same process. Target: chain Jacobian ≤ 1.5× the DH one.

Run:  python benchmarks/bench_kinematics.py [--chain]   (writes benchmarks/results/kinematics_<platform>.md,
      and with --chain only benchmarks/results/kinematics_chain_<platform>.md)
"""

from __future__ import annotations

import pathlib
import sys

import jax
import jax.numpy as jnp
from _common import machine, median_time

import jaxcal
from jaxcal import CableLength, ParameterSpace, Problem

jaxcal.enable_x64()


def chain_rows():
    """DH kernel vs generic-chain kernel, draw-wire Jacobian, float64."""
    robot = jaxcal.robots.hsr_jr680()
    chain = jaxcal.chain_from_dh(robot)
    meas = CableLength(jnp.asarray([1600.0, 0.0, 0.0]))
    space = ParameterSpace.for_robot(robot)
    jac_fn = jax.jit(lambda p, x: p.jacobian(x))
    anchor = meas.anchor

    def chain_jac(groups):
        def res(x, q, y):
            dev = {g: x[i * chain.dof:(i + 1) * chain.dof] for i, g in enumerate(groups)}
            p = chain.point_in_base(dev, q, chain.tool)
            return jnp.sqrt(sum((p[k] - anchor[k]) ** 2 for k in range(3))) - y

        return jax.jit(jax.jacfwd(res))

    full = ("offset", "dx", "dy", "dz", "drx", "dry")
    same = ("offset", "dx", "dy", "drx")
    rows = []
    for n in (2_000, 20_000):
        q = jaxcal._simulate.sample_joint_angles(jax.random.PRNGKey(0), robot, n)
        y = meas.predict(robot, None, q)
        prob = Problem(robot, meas, q, y, space)
        x = jnp.zeros(space.n_free)
        fns = {"dh": (jac_fn, (prob, x)), "chain36": (chain_jac(full), (jnp.zeros(36), q, y)),
               "chain24": (chain_jac(same), (jnp.zeros(24), q, y))}
        times = {k: [] for k in fns}
        for _ in range(5):  # alternate, so background load hits all alike
            for k, (fn, args) in fns.items():
                times[k].append(median_time(fn, *args, repeats=20 if n <= 2_000 else 10))
        t = {k: float(min(v)) * 1e3 for k, v in times.items()}
        rows.append((n, t["dh"], t["chain36"], t["chain24"]))
        print(rows[-1], flush=True)
    lines = [
        "# Jacobian timing: DH kernel vs generic serial chain (draw-wire, HSR-JR680, float64)",
        "",
        f"Machine: {machine()}.",
        "`jax.jacfwd` of the residual vector after `jax.jit`; best of 5 alternating medians. The chain is",
        "`chain_from_dh(hsr_jr680())` (identical FK); its errors per joint are offset, dx, dy, dz, drx, dry",
        "(36 columns, the default free set) or offset, dx, dy, drx (24, as many columns as the DH kernel).",
        "",
        "| samples | DH, 24 columns / ms | chain, 36 columns / ms | ratio | chain, 24 columns / ms | ratio |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    lines += [f"| {n:,} | {d:.3f} | {c36:.3f} | {c36 / d:.2f} | {c24:.3f} | {c24 / d:.2f} |" for n, d, c36, c24 in rows]
    plat = jax.devices()[0].platform
    out = pathlib.Path(__file__).parent / "results" / f"kinematics_chain_{plat}.md"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


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
    if "--chain" not in sys.argv:
        main()
    chain_rows()
