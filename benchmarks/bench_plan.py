"""Measurement planning on the paper's set-up: how many well-chosen poses match 2 000 random ones?

Set-up: HSR-JR680 (Table I), draw-wire sensor with the default anchor (reach/2, 0, 0), σ = 0.5 mm,
the 19 identifiable DH deviations. Candidates: ``--candidates`` (20 000) joint configurations
uniform over the joint limits whose nominal tool point is above the base plane and within the
wire window [0.05, 1.2]·reach (``jaxcal.candidate_poses``, key 0). Test poses: 2 000 more from
key 1. Predictions: ``jaxcal.predicted_accuracy`` (linearised covariance σ²(JᵀJ)⁻¹, no prior, as
``calibrate``'s default). Simulations: per seed a "true" robot drawn with the paper's Table V
magnitudes (0.2°, 0.6 mm), readings with σ = 0.5 mm at the planned poses and at the test poses,
``jaxcal.calibrate(..., "lm")``; the same seeds (truths and noise keys) for every pose set.

Reported:
1. selection time, 100 of 20 000 (after compilation; median of 5), and reproducibility;
2. the reference: 2 000 random poses, predicted and simulated test RMSE; the target = 1.05 ×;
3. the smallest number of selected poses (greedy D + DETMAX exchange; and I-optimal) whose
   predicted test RMSE reaches the target, checked by simulation;
4. greedy vs greedy+exchange vs the convex relaxation (multiplicative-weights D-optimal design,
   rounded to the largest weights) vs random at the same number of poses: O1, O3, test RMSE;
5. the curve of predicted (and simulated) test RMSE vs number of poses, selected vs random.

Writes ``benchmarks/results/plan_cpu.md`` and ``plan_curve.png`` (or ``--out``).
Run: ``python benchmarks/bench_plan.py [--seeds 20 --candidates 20000]``.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import time

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

from _common import machine  # noqa: E402

import jaxcal  # noqa: E402
from jaxcal import _plan  # noqa: E402
from jaxcal._simulation._simulate import default_anchor  # noqa: E402

SIGMA = 0.5


def simulated(robot, meas, q, q_test, seeds):
    """Mean and std of the simulated test RMSE over ``seeds`` LM calibrations from poses ``q``."""
    out = _plan.simulated_test_rmse(robot, meas, q, q_test, SIGMA, seeds, seed=10_000)
    return float(np.mean(out)), float(np.std(out))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--candidates", type=int, default=20000)
    ap.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results"))
    args = ap.parse_args()
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t_all = time.perf_counter()

    robot = jaxcal.robots.hsr_jr680()
    meas = jaxcal.CableLength(default_anchor(robot))
    cand = np.asarray(jaxcal.candidate_poses(jax.random.key(0), robot, meas, args.candidates))
    q_test = jaxcal.candidate_poses(jax.random.key(1), robot, meas, 2000)
    pred = lambda q: jaxcal.predicted_accuracy(robot, meas, q, SIGMA, q_test=q_test).test_rmse  # noqa: E731
    lines = [f"# Measurement planning (issue 12), {time.strftime('%Y-%m-%d')}", "",
             f"Machine: {machine()} (this project's 2-core CPU, no GPU; shared with other jobs while measured).",
             "", "HSR-JR680, draw-wire, anchor (reach/2, 0, 0), σ = 0.5 mm, 19 identifiable DH deviations; "
             f"{args.candidates} candidates (key 0), 2 000 test poses (key 1); simulations: {args.seeds} seeds, "
             "truths drawn with the paper's Table V magnitudes, `calibrate(..., \"lm\")`. See the script's "
             "docstring.", ""]

    # 1. selection time
    times = {}
    for label, kw in (("greedy D", dict(exchange=False)), ("greedy D + exchange", dict(exchange=True))):
        jaxcal.select_poses(robot, meas, cand, 100, **kw)  # compile
        ts = []
        for _ in range(5):
            t = time.perf_counter()
            s = jaxcal.select_poses(robot, meas, cand, 100, **kw)
            ts.append(time.perf_counter() - t)
        times[label] = (float(np.median(ts)), s.n_exchanges)
    _plan.relaxed_design(robot, meas, cand, 100)
    t = time.perf_counter()
    _plan.relaxed_design(robot, meas, cand, 100)
    times["relaxation (500 multiplicative steps)"] = (time.perf_counter() - t, 0)
    c2 = np.asarray(jaxcal.candidate_poses(jax.random.key(0), robot, meas, args.candidates))
    same = np.array_equal(jaxcal.select_poses(robot, meas, c2, 100).index, s.index)
    load = os.getloadavg()[0]
    lines += [f"## 1. Selection time: 100 of {args.candidates:,} candidates (after compilation, median of 5)",
              "", "Whole call: identifiable subset (pivoted QR) and Jacobians of all candidates (`jacfwd` on the "
              "batch), then the selection. 1-minute load average while timing: "
              f"{load:.1f} on 2 cores (> 2: other jobs were running and the times are inflated).",
              "", "| selection | time / s | exchange iterations |", "|---|---|---|"]
    lines += [f"| {k} | {v:.3f} | {n} |" for k, (v, n) in times.items()]
    lines += ["", f"Reproducible from the seed: candidates regenerated from key 0 give the identical selection: "
              f"**{same}**.", ""]
    print("\n".join(lines[-8:]))

    # 2. reference: 2 000 random poses
    perm = np.asarray(jax.random.permutation(jax.random.key(2), cand.shape[0]))
    q2000 = cand[perm[:2000]]
    ref_pred = pred(q2000)
    ref_sim, ref_sd = simulated(robot, meas, q2000, q_test, args.seeds)
    target = 1.05 * ref_sim
    lines += ["## 2. Reference: 2 000 random poses", "",
              f"Predicted test RMSE {ref_pred:.4f} mm; simulated mean {ref_sim:.4f} ± {ref_sd:.4f} mm "
              f"({100 * (ref_sim / ref_pred - 1):+.2f} %). Target (within 5 % of the simulated 2 000-pose RMSE): "
              f"**{target:.4f} mm**.", ""]
    print("\n".join(lines[-3:]))

    # 3. poses needed
    lines += ["## 3. Poses needed to reach the target", "",
              "Smallest n (step 5) whose predicted test RMSE ≤ target, then checked by simulation at that n.", "",
              "| selection | poses needed | predicted / mm | simulated mean ± std / mm | simulated vs predicted |",
              "|---|---|---|---|---|"]
    needed = {}
    for label, kw in (("D-optimal, greedy + exchange", dict(criterion="D")),
                      ("I-optimal, greedy + exchange", dict(criterion="I")),
                      ("D-optimal, greedy only", dict(criterion="D", exchange=False))):
        curve = jaxcal.accuracy_curve(robot, meas, cand, list(range(60, 401, 10)), SIGMA, q_test=q_test,
                                      criterion=kw["criterion"])
        lo = curve.poses_needed(target) or 400
        n_found = None
        for n in range(max(lo - 30, 25), 401, 5):
            sel = jaxcal.select_poses(robot, meas, cand, n, **kw)
            p = pred(sel.q)
            if p <= target:
                n_found = n
                break
        if n_found is None:
            lines.append(f"| {label} | > 400 | | | |")
            continue
        m, sd = simulated(robot, meas, sel.q, q_test, args.seeds)
        needed[label] = (n_found, sel)
        lines.append(f"| {label} | **{n_found}** | {p:.4f} | {m:.4f} ± {sd:.4f} | {100 * (m / p - 1):+.2f} % |")
        print(lines[-1])
    rnd_curve = jaxcal.accuracy_curve(robot, meas, cand, list(range(60, 2001, 10)), SIGMA, q_test=q_test, key=jax.random.key(2))
    n_rnd = next((int(n) for n, r in zip(rnd_curve.n, rnd_curve.random) if r <= target), None)
    m_rnd, sd_rnd = simulated(robot, meas, cand[perm[:n_rnd]], q_test, args.seeds) if n_rnd else (np.nan, np.nan)
    p_rnd = pred(cand[perm[:n_rnd]]) if n_rnd else np.nan
    lines.append(f"| random (first n of one permutation) | {n_rnd} | {p_rnd:.4f} | {m_rnd:.4f} ± {sd_rnd:.4f} | "
                 f"{100 * (m_rnd / p_rnd - 1):+.2f} % |")
    lines.append("")
    print(lines[-2])

    # 4. comparison at equal n
    for part, n in zip("ab", (100, needed.get("D-optimal, greedy + exchange", (150,))[0])):
        rows = {
            "random": cand[perm[:n]],
            "greedy D": jaxcal.select_poses(robot, meas, cand, n, exchange=False).q,
            "greedy D + DETMAX exchange": jaxcal.select_poses(robot, meas, cand, n).q,
            "relaxation (top-n weights)": jaxcal.relaxed_design(robot, meas, cand, n)[0].q,
            "relaxation + DETMAX exchange": jaxcal.relaxed_design(robot, meas, cand, n, exchange=True)[0].q,
            "greedy A + exchange": jaxcal.select_poses(robot, meas, cand, n, criterion="A").q,
            "greedy E (first order) + exchange": jaxcal.select_poses(robot, meas, cand, n, criterion="E").q,
            "greedy I + exchange": jaxcal.select_poses(robot, meas, cand, n, criterion="I").q,
        }
        ref = jaxcal.select_poses(robot, meas, cand, 10, exchange=False)  # the candidates' scales
        lines += [f"## 4{part}. Selections of {n} poses compared", "",
                  "O1/O3 with the candidates' column scales (comparable across rows); test RMSE predicted and "
                  f"simulated ({args.seeds} seeds, the same truths and noise keys for every row).", "",
                  "| selection | O1 | O3 | predicted test RMSE / mm | simulated mean ± std / mm |", "|---|---|---|---|---|"]
        for label, q in rows.items():
            ind = _plan.indices_from_jacobian(_plan.planning_jacobian(robot, meas, q, ref.space), ref.scale)
            m, sd = simulated(robot, meas, q, q_test, args.seeds)
            lines.append(f"| {label} | {ind.o1:.4f} | {ind.o3:.3f} | {pred(q):.4f} | {m:.4f} ± {sd:.4f} |")
            print(lines[-1])
        lines.append("")
    _, w, bound = jaxcal.relaxed_design(robot, meas, cand, 100)
    lines += [f"Relaxation: 500 multiplicative steps, D-efficiency of the weights ≥ {bound:.4f} (Kiefer–Wolfowitz "
              f"bound); {int(np.sum(w > 1e-3 / len(w)))} candidates keep weight > 0.1 % of uniform, "
              f"{int(np.sum(np.cumsum(np.sort(w)[::-1]) < 0.99)) + 1} carry 99 % of it.", ""]

    # 5. the curve
    ns = [25, 30, 40, 50, 70, 100, 150, 200, 300, 500, 1000, 2000]
    curve = jaxcal.accuracy_curve(robot, meas, cand, ns, SIGMA, q_test=q_test, key=jax.random.key(2))
    sim_ns = [30, 50, 100, 200, 500]
    greedy = jaxcal.select_poses(robot, meas, cand, max(ns), exchange=False)
    sim_sel = np.full(len(ns), np.nan)
    sim_rnd = np.full(len(ns), np.nan)
    for i, n in enumerate(ns):
        if n in sim_ns:
            sim_sel[i] = simulated(robot, meas, greedy.q[:n], q_test, args.seeds)[0]
            sim_rnd[i] = simulated(robot, meas, cand[perm[:n]], q_test, args.seeds)[0]
    curve = _plan.AccuracyCurve(curve.n, curve.selected, curve.random, "D", SIGMA, sim_sel, sim_rnd)
    fig = curve.plot(target_rmse=target)
    fig.savefig(out / "plan_curve.png", dpi=110)
    lines += ["## 5. Test RMSE vs number of poses (greedy D prefixes vs random prefixes)", "",
              "![curve](plan_curve.png)", "",
              "| n | D-optimal predicted | D-optimal simulated | random predicted | random simulated |",
              "|---|---|---|---|---|"]
    fmt = lambda v: "" if np.isnan(v) else f"{v:.4f}"  # noqa: E731
    for i, n in enumerate(ns):
        lines.append(f"| {n} | {curve.selected[i]:.4f} | {fmt(sim_sel[i])} | {curve.random[i]:.4f} | {fmt(sim_rnd[i])} |")
    lines += ["", f"Total benchmark time {time.perf_counter() - t_all:.0f} s."]
    (out / "plan_cpu.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines[-18:]))
    print("wrote", out / "plan_cpu.md")


if __name__ == "__main__":
    main()
