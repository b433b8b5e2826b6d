"""Residual and jacfwd-Jacobian evaluation time for the draw-wire model (issue 2 benchmark).

HSR-JR680, distance to a fixed anchor, all 24 DH deviations free, n = 2 000 / 20 000 /
200 000 samples, float64 and float32; median of repeated calls after jit compilation.
Target on the project's 2-core CPU: Jacobian for 2 000 samples × 24 parameters in ≤ 5 ms.

Generic chains (issue 11): the same robot as a :class:`jaxcal.SerialChain` (``chain_from_dh``),
its per-joint errors (offset, dx, dy, dz, drx, dry: 36 columns) against the DH kernel's 24, and
the chain with 24 columns (offset, dx, dy, drx) for a per-column comparison, for the draw-wire
and the position model; DH and chain timed alternately in the same process. Target: chain
Jacobian ≤ 1.5× the DH one.

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


def _write(lines: list[str], stem: str) -> None:
    """Print the table and write it to ``results/<stem>_<platform>.md``."""
    out = pathlib.Path(__file__).parent / "results" / f"{stem}_{jax.devices()[0].platform}.md"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def chain_rows():
    """DH kernel vs generic-chain kernel, identification Jacobian (``Problem.jacobian``), float64."""
    robot = jaxcal.robots.hsr_jr680()
    chain = jaxcal.chain_from_dh(robot)
    jac_fn = jax.jit(lambda p, x: p.jacobian(x))
    same = [f"{g}_{j + 1}" for g in ("offset", "dx", "dy", "drx") for j in range(6)]
    rows = []
    for kind, meas, ns in (("cable", CableLength(jnp.asarray([1600.0, 0.0, 0.0])), (2_000, 20_000)),
                           ("position", jaxcal.Position(), (2_000,))):
        for n in ns:
            q = jaxcal._models._robot.sample_joint_angles(jax.random.PRNGKey(0), robot, n)
            y = meas.predict(robot, None, q)
            s_dh = ParameterSpace.for_robot(robot, measurement=meas)
            s_36 = ParameterSpace.for_robot(chain, measurement=meas)
            s_24 = ParameterSpace.from_names(s_36.layout, same)
            # what calibrate() differentiates: each model's identifiable subset (QR with pivoting)
            i_dh = jaxcal.identifiability(robot, meas, q, s_dh).space
            i_ch = jaxcal.identifiability(chain, meas, q, s_36).space
            probs = {"dh": Problem(robot, meas, q, y, s_dh), "chain36": Problem(chain, meas, q, y, s_36),
                     "chain24": Problem(chain, meas, q, y, s_24), "dh_id": Problem(robot, meas, q, y, i_dh),
                     "chain_id": Problem(chain, meas, q, y, i_ch)}
            times = {k: [] for k in probs}
            for _ in range(5):  # alternate, so background load hits all alike
                for k, pr in probs.items():
                    x = jnp.zeros(pr.space.n_free)
                    times[k].append(median_time(jac_fn, pr, x, repeats=20 if n <= 2_000 else 10))
            t = {k: float(min(v)) * 1e3 for k, v in times.items()}
            rows.append((kind, n, s_dh.n_free, t["dh"], s_36.n_free, t["chain36"], t["chain24"],
                         i_dh.n_free, t["dh_id"], i_ch.n_free, t["chain_id"]))
            print(rows[-1], flush=True)
    lines = [
        "# Jacobian timing: DH kernel vs generic serial chain (HSR-JR680, float64)",
        "",
        f"Machine: {machine()}.",
        "`Problem.jacobian` (`jax.jacfwd` of the residual vector) after `jax.jit`; best of 5 alternating",
        "medians. The chain is `chain_from_dh(hsr_jr680())` (identical FK); its default free errors per joint",
        "are offset, dx, dy, dz, drx, dry (36 columns), or offset, dx, dy, drx (24, as many as the DH kernel).",
        "*Identifiable*: each model's identifiable subset (`jaxcal.identifiability`, the columns `calibrate`",
        "and LM differentiate).",
        "",
        "| measurement | samples | DH: columns | DH / ms | chain: columns | chain / ms | ratio | chain, 24 columns / ms "
        "| ratio | identifiable: DH cols / ms | chain cols / ms | ratio |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    lines += [f"| {k} | {n:,} | {pd} | {d:.3f} | {pc} | {c36:.3f} | {c36 / d:.2f} | {c24:.3f} | {c24 / d:.2f} "
              f"| {idd} / {tdd:.3f} | {idc} / {tdc:.3f} | {tdc / tdd:.2f} |"
              for k, n, pd, d, pc, c36, c24, idd, tdd, idc, tdc in rows]
    _write(lines, "kinematics_chain")


def main():
    robot = jaxcal.robots.hsr_jr680()
    meas = CableLength(jnp.asarray([1600.0, 0.0, 0.0]))
    space = ParameterSpace.for_robot(robot)
    rows = []
    res_fn = jax.jit(lambda p, x: p.residual(x))
    jac_fn = jax.jit(lambda p, x: p.jacobian(x))
    for n in (2_000, 20_000, 200_000):
        q = jaxcal._models._robot.sample_joint_angles(jax.random.PRNGKey(0), robot, n)
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
    _write(lines, "kinematics")


if __name__ == "__main__":
    if "--chain" not in sys.argv:
        main()
    chain_rows()
