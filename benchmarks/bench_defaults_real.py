"""Do the measured-data defaults lose? (issue 35: "defaults that do not lose")

The defaults for measured data (``jaxcal.MEASURED_DEFAULTS``: the default prior toward nominal +
the Huber loss) against the alternatives {least squares, Huber} × {no prior, default prior}, on
held-out data of every set the project holds or simulates:

* **draw-wire** — ``jaxcal.simulate_messy`` (HSR-JR680, narrow coverage, anchor and cable offset
  estimated, 2 gross rows in the training split); held out: the random test split and ``far``
  (poses over the whole joint limits).
* **7-axis tracker** — a simulated laser-tracker set of a 7-axis arm (:func:`tracker_7axis`: a
  7R DH chain of the KUKA LBR iiwa 14's geometry, tracker frame estimated, joint 1 spanning 1.5°,
  one gross 22 mm reading, nominal off by 0.3° / 1.5 mm (σ of the drawn deviations), σ = 0.08 mm,
  unmodelled compliance and gear error); held out: the random test split and another session
  (other poses, joint 1 20° away; the tracker frame registered again on it). Two variants: the
  gross reading in the training split, and in the test split (then the test RMSE is also given
  without that row: one 22 mm reading among 80 makes the RMSE ~2.5 mm whatever the fit); and a
  stress variant whose residuals are mostly unmodelled error (compliance ×40: held-out RMSE
  ~2.5 mm at σ = 0.08 mm, a heavy-tailed residual: its MAD scale is a third of its RMS).
* **TIAGo (real)** — FIGAROH's Qualisys file (``tests/data/figaroh_tiago``) through the TIAGo
  URDF, contiguous 5-fold held-out postures pooled, with and without its gross row; only with
  ``--tiago`` and the URDF (``bench_figaroh.tiago_urdf_text``: several minutes on 2 cores).

For each set and held-out part: the mean RMSE over seeds of each objective, and the ratio of the
defaults' RMSE to the best objective's (mean and worst over seeds).

Run: ``python benchmarks/bench_defaults_real.py [--seeds 3] [--tiago]``. Writes
``benchmarks/results/defaults_vs_alternatives_cpu.md`` (or ``--out``).
"""

from __future__ import annotations

import argparse
import dataclasses
import pathlib
import time
import warnings

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

from _common import machine  # noqa: E402

import jaxcal  # noqa: E402
from jaxcal._models._robot import sample_joint_angles  # noqa: E402
from jaxcal._simulation._messy import _quantize, actual_joint_angles, default_compliance  # noqa: E402

OBJECTIVES = {
    "least squares": dict(prior=None, loss="linear"),
    "Huber": dict(prior=None, loss="huber"),
    "prior + least squares": dict(prior="default", loss="linear"),
    "defaults (prior + Huber)": dict(prior="default", loss="huber"),
}
DEFAULTS = "defaults (prior + Huber)"
HEAVY = "7-axis tracker, unmodelled error ×13 (compliance ×40; gross row in train)"


def iiwa_like() -> jaxcal.DHRobot:
    """A 7R DH chain of the KUKA LBR iiwa 14's geometry (standard DH, mm), tracker target 60 mm
    beyond the flange."""
    return jaxcal.DHRobot.from_degrees(
        alpha_deg=[-90, 90, 90, -90, -90, 90, 0], a_mm=[0] * 7, d_mm=[360, 0, 420, 0, 400, 0, 126],
        theta_deg=[0] * 7, q_min_deg=[-170, -120, -170, -120, -170, -120, -175],
        q_max_deg=[170, 120, 170, 120, 170, 120, 175], tool_mm=(0, 0, 60), name="7R (iiwa-like)")


#: visited joint ranges (deg) of the training session (joint 1 near-still) and of the other session
RANGES_A = ((-0.75, 0.75), (-10, 50), (-40, 40), (-100, -30), (-40, 40), (-60, 40), (-60, 60))
RANGES_B = ((20, 21.5), (0, 60), (-60, 20), (-90, -20), (-20, 60), (-40, 60), (-90, 30))


def tracker_7axis(seed: int, n: int = 400, *, compliance_scale: float = 3.0, gross_in_test: bool = False):
    """``(experiment, other_session)``: a simulated laser-tracker set of a 7-axis arm with joint 1
    near-still (1.5° span) and one 22 mm gross reading (training split, or with ``gross_in_test``
    the test split), and another session of the same robot and tracker (other poses)."""
    robot = iiwa_like()
    comp = np.asarray(default_compliance(robot)) * compliance_scale
    ex = jaxcal.simulate_messy(
        jax.random.key(seed), robot, measurement="position", n_samples=n, noise_std=0.08, angle_std_deg=0.3,
        length_std_mm=1.5, joint_ranges_deg=RANGES_A, n_outliers=0 if gross_in_test else 1, outlier_mm=(22, 22),
        far_samples=0, compliance_deg_per_knm=comp, gear_error_deg=0.02, quantization_deg=0.001)
    if gross_in_test:
        y = np.asarray(ex.test.y).copy()
        y[0, seed % 3] += 22.0
        ex = dataclasses.replace(ex, test=dataclasses.replace(ex.test, y=jnp.asarray(y)))
    s = ex.settings
    k_q, k_noise = jax.random.split(jax.random.key(10_000 + seed))
    q = np.asarray(sample_joint_angles(k_q, robot, 4 * n, ranges=tuple(np.deg2rad(np.asarray(RANGES_B)).T),
                                       dtype=np.float64))
    qa = actual_joint_angles(robot, q, gear_error_deg=s["gear_error_deg"], gear_phase_rad=np.asarray(s["gear_phase_rad"]),
                             compliance_deg_per_knm=np.asarray(s["compliance_deg_per_knm"]))
    y = np.asarray(ex.measurement.predict(robot, ex.true_deviations, qa))
    keep = np.flatnonzero(y[:, 2] > 0)[: n // 2]
    y = y[keep] + 0.08 * np.asarray(jax.random.normal(k_noise, y[keep].shape))
    other = jaxcal.Dataset(jnp.asarray(_quantize(q[keep], 0.001)), jnp.asarray(y), "position",
                           {"split": "other session"})
    return ex, other


def _fit(robot, measurement, train, extras, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return jaxcal.calibrate(robot, measurement, train, "lm", extras=extras, **kw)


def run_drawwire(seed: int, n: int) -> dict:
    ex = jaxcal.simulate_messy(jax.random.key(seed), n_samples=n, far_samples=300)
    out = {}
    for name, kw in OBJECTIVES.items():
        r = _fit(ex.robot, ex.measurement, ex.train, ("anchor", "cable_offset"), **kw)
        out[name] = {"test split": r.evaluate(ex.test).rmse, "far (whole limits)": r.evaluate(ex.far).rmse}
    return out


def run_tracker(seed: int, n: int, gross_in_test: bool, compliance_scale: float = 3.0) -> dict:
    ex, other = tracker_7axis(seed, n, gross_in_test=gross_in_test, compliance_scale=compliance_scale)
    out = {}
    for name, kw in OBJECTIVES.items():
        r = _fit(ex.robot, ex.measurement, ex.train, ("base",), **kw)
        row = {"test split": r.evaluate(ex.test).rmse}
        if gross_in_test:
            row["test split without the gross row"] = r.evaluate(ex.test.subset(jnp.arange(1, ex.test.n))).rmse
        row["other session (frame registered)"] = jaxcal.evaluate_result(r, other, extras="register").rmse
        out[name] = row
    return out


def run_tiago(folds: int = 5) -> dict | None:
    import bench_figaroh as bf

    text = bf.tiago_urdf_text()
    if text is None:
        return None
    chain = bf.tiago_chain(text)
    q, y, _ = bf.load_figaroh_markers()
    m = jaxcal.Markers(np.zeros((y.shape[1], 3)))
    out = {}
    for name, kw in OBJECTIVES.items():
        res = bf.held_out(chain, m, q, y, folds, **kw)
        raw, clean = bf.pooled(res, "after")
        out[name] = {f"{folds}-fold held-out postures": raw, f"{folds}-fold held out, without the gross row": clean}
        print(f"tiago {name}: {raw:.3f} / {clean:.3f}", flush=True)
    return out


def table(sets: dict) -> list[str]:
    """``sets``: {set name: [per-seed {objective: {held-out part: rmse}}]} → Markdown rows."""
    lines = ["| data set | held out | " + " | ".join(f"{o} / mm" for o in OBJECTIVES)
             + " | defaults ÷ best: mean (worst) |", "|---|---|" + "---:|" * (len(OBJECTIVES) + 1)]
    for set_name, runs in sets.items():
        for part in runs[0][DEFAULTS] if runs else ():
            vals = np.array([[r[o][part] for o in OBJECTIVES] for r in runs])  # [seeds, objectives]
            ratio = vals[:, list(OBJECTIVES).index(DEFAULTS)] / vals.min(axis=1)
            lines.append(f"| {set_name} | {part} | " + " | ".join(f"{v:.4f}" for v in vals.mean(axis=0))
                         + f" | {ratio.mean():.3f} ({ratio.max():.3f}) |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--tracker-samples", type=int, default=400)
    ap.add_argument("--drawwire-samples", type=int, default=600)
    ap.add_argument("--tiago", action="store_true", help="also FIGAROH's TIAGo file (needs the URDF; slow)")
    ap.add_argument("--out", default=str(pathlib.Path(__file__).parent / "results" / "defaults_vs_alternatives_cpu.md"))
    args = ap.parse_args()
    t0 = time.perf_counter()
    sets = {"draw-wire (simulated, 2 gross rows in train)": [], "7-axis tracker (simulated, gross row in train)": [],
            "7-axis tracker (simulated, gross row in the test split)": [], HEAVY: []}
    for seed in range(args.seeds):
        sets["draw-wire (simulated, 2 gross rows in train)"].append(run_drawwire(seed, args.drawwire_samples))
        sets["7-axis tracker (simulated, gross row in train)"].append(run_tracker(seed, args.tracker_samples, False))
        sets["7-axis tracker (simulated, gross row in the test split)"].append(
            run_tracker(seed, args.tracker_samples, True))
        sets[HEAVY].append(run_tracker(seed, args.tracker_samples, False, compliance_scale=40.0))
        print(f"seed {seed} done ({time.perf_counter() - t0:.0f} s)", flush=True)
    if args.tiago:
        tiago = run_tiago()
        if tiago is not None:
            sets["TIAGo (real, FIGAROH Qualisys file, 3 markers)"] = [tiago]
    lines = [
        "# Measured-data defaults vs the alternatives, on held-out data",
        "",
        f"`python benchmarks/bench_defaults_real.py --seeds {args.seeds}{' --tiago' if args.tiago else ''}`; "
        f"{machine()}; {time.perf_counter() - t0:.0f} s.",
        "",
        "LM; RMSE (mm) on held-out data, mean over seeds "
        f"0–{args.seeds - 1} (the TIAGo file: one run); the last column: the defaults' RMSE over the best of the "
        "four objectives, mean and worst over seeds. Draw-wire: `simulate_messy` (HSR-JR680, "
        f"{args.drawwire_samples} rows, anchor and cable offset estimated). 7-axis tracker: `tracker_7axis` in this "
        f"script ({args.tracker_samples} rows, 7R iiwa-like chain, tracker frame estimated, joint 1 spanning 1.5°, "
        "one 22 mm gross reading, nominal off by 0.3° / 1.5 mm, σ = 0.08 mm, unmodelled compliance and gear "
        "error; the other session: other poses with joint 1 20° away, tracker frame registered again).",
        "",
        *table(sets),
    ]
    out = pathlib.Path(args.out)
    out.write_text("\n".join(lines) + "\n", encoding="utf-8")
    print("\n".join(lines))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
