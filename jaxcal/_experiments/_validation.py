"""Choosing the prior strength by cross-validation, with workspace-region folds.

A random train/test split only asks how well a calibration interpolates between measured poses.
Real calibrations are used where nobody measured, so jaxcal also validates by **workspace
region**: train on the poses with joint ``j`` below its median, test on those
above (and the reverse), for joints 1–3. Unregularised fits on narrow data win the random folds
by a hair and lose the region folds clearly; :func:`cross_validate_prior` measures that
trade-off for a range of prior strengths and picks the strength with the lowest mean held-out
RMSE over all folds (random and region alike).
"""

from __future__ import annotations

import dataclasses
import warnings

import jax
import numpy as np

from .._datasets._dataset import Dataset
from .._fit._objective import Prior
from .._simulation._messy import region_folds

__all__ = ["PriorCV", "cross_validate_prior", "random_folds"]


def random_folds(data: Dataset, k: int, key) -> list[tuple[Dataset, Dataset]]:
    """``k`` random folds ``(train, test)`` from a ``jax.random`` key (each sample tested once)."""
    if k < 2:
        raise ValueError(f"k must be >= 2, got {k}")
    perm = np.asarray(jax.random.permutation(key, data.n))
    parts = np.array_split(perm, k)
    return [(data.subset(np.sort(np.concatenate(parts[:i] + parts[i + 1:]))), data.subset(np.sort(parts[i])))
            for i in range(k)]


@dataclasses.dataclass(frozen=True)
class PriorCV:
    """Result of :func:`cross_validate_prior`.

    Attributes:
        strengths: ``[S]`` prior strengths (0 = no prior; ``s`` divides every σ of the base prior).
        random_rmse, region_rmse: ``[S]`` mean held-out RMSE (mm) over the random folds and over
            the workspace-region folds (extrapolation).
        train_rmse: ``[S]`` training RMSE (mm) of the fit on all the data.
        max_angle_deg, max_length_mm: ``[S]`` largest |Δ| of a DH angle (wrapped, °) and length
            (mm) in the fit on all the data.
        best: the chosen strength (lowest mean held-out RMSE over all folds).
        base: the base :class:`Prior`.
    """

    strengths: np.ndarray
    random_rmse: np.ndarray
    region_rmse: np.ndarray
    train_rmse: np.ndarray
    max_angle_deg: np.ndarray
    max_length_mm: np.ndarray
    best: float
    base: Prior

    def prior(self, strength: float | None = None) -> Prior | None:
        """The prior at ``strength`` (default: the chosen one); ``None`` for strength 0."""
        s = self.best if strength is None else strength
        return None if s == 0 else self.base.scaled(s)

    def table(self) -> str:
        """A Markdown table of the trade-off."""
        lines = ["| prior strength | σ angle / ° | σ length / mm | train RMSE / mm | random-fold RMSE / mm | "
                 "region-fold (extrapolation) RMSE / mm | max abs Δ angle / ° | max abs Δ length / mm |",
                 "|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for i, s in enumerate(self.strengths):
            sa = "—" if s == 0 else f"{self.base.angle_deg / s:.3g}"
            sl = "—" if s == 0 else f"{self.base.length_mm / s:.3g}"
            mark = " **(chosen)**" if s == self.best else ""
            lines.append(f"| {'none' if s == 0 else f'{s:g}'}{mark} | {sa} | {sl} | {self.train_rmse[i]:.4f} | "
                         f"{self.random_rmse[i]:.4f} | {self.region_rmse[i]:.4f} | {self.max_angle_deg[i]:.3g} | "
                         f"{self.max_length_mm[i]:.3g} |")
        return "\n".join(lines)

    def plot(self, ax=None):
        """Held-out RMSE (random and region folds) and max |Δ| against the prior strength."""
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots(figsize=(6.4, 4.0))
        x = np.where(self.strengths == 0, np.min(self.strengths[self.strengths > 0], initial=1.0) / 4, self.strengths)
        ax.plot(x, self.random_rmse, "o-", label="random folds (interpolation)")
        ax.plot(x, self.region_rmse, "s-", label="workspace-region folds (extrapolation)")
        ax.plot(x, self.train_rmse, "^:", label="training fit")
        ax.axvline(x[list(self.strengths).index(self.best)], color="0.6", ls="--", lw=1, label="chosen")
        ax.set_xscale("log")
        ax.set_xlabel("prior strength (leftmost point: no prior)")
        ax.set_ylabel("RMSE / mm")
        ax2 = ax.twinx()
        ax2.plot(x, self.max_length_mm, "x--", color="C3", label="max |Δ length| (right axis)")
        ax2.set_ylabel("max |Δ length| / mm", color="C3")
        ax2.set_yscale("log")
        h1, l1 = ax.get_legend_handles_labels()
        h2, l2 = ax2.get_legend_handles_labels()
        ax.legend(h1 + h2, l1 + l2, fontsize=8, loc="upper right")
        ax.set_title("Prior strength: fit, interpolation and extrapolation")
        return ax


def _max_dev(res) -> tuple[float, float]:
    """Largest |robot deviation|: (degrees, mm)."""
    from .._fit._diagnostics import robot_deviations

    ang, length = 0.0, 0.0
    for _, v, u in robot_deviations(res.space.names, res.space.units, np.asarray(res.deviations.ravel(), np.float64)):
        if u == "deg":
            ang = max(ang, abs(v))
        else:
            length = max(length, abs(v))
    return ang, length


def cross_validate_prior(
    robot,
    measurement,
    data: Dataset,
    *,
    strengths=(0.0, 0.25, 0.5, 1.0, 2.0, 4.0),
    base: Prior | None = None,
    method="lm",
    k: int = 5,
    region_joints=(1, 2, 3),
    key=None,
    progress: bool = False,
    **calibrate_kwargs,
) -> PriorCV:
    """Held-out accuracy of calibrations with priors of several strengths.

    Args:
        robot, measurement, data: as for :func:`jaxcal.calibrate` (``data`` a :class:`Dataset`).
        strengths: multipliers of the base prior's precision (``0`` = no prior).
        base: the prior whose σ are divided by each strength (default :class:`Prior` ()).
        method: calibration method (default ``"lm"``).
        k: random folds; ``region_joints``: joints whose median splits the workspace (both
            directions each; :func:`jaxcal.region_folds`).
        key: ``jax.random`` key of the random folds (default ``key(0)``).
        **calibrate_kwargs: passed to every :func:`jaxcal.calibrate` (e.g. ``extras=``, ``loss=``).

    Returns:
        :class:`PriorCV` (table, plot, chosen strength).
    """
    from .._calibration._calibrate import calibrate

    base = Prior() if base is None else base
    key = jax.random.key(0) if key is None else key
    folds_random = random_folds(data, k, key)
    folds_region = region_folds(data, region_joints)
    strengths = np.asarray(sorted(float(s) for s in strengths))
    if np.any(strengths < 0):
        raise ValueError("prior strengths must be >= 0")
    rnd, reg, train, mang, mlen = [], [], [], [], []
    for s in strengths:
        prior = None if s == 0 else base.scaled(s)

        def fit(ds):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                return calibrate(robot, measurement, ds, method, prior=prior, **calibrate_kwargs)

        rnd.append(np.mean([fit(tr).evaluate(te).rmse for tr, te in folds_random]))
        reg.append(np.mean([fit(tr).evaluate(te).rmse for tr, te in folds_region]))
        full = fit(data)
        train.append(full.train_metrics.rmse)
        a, length = _max_dev(full)
        mang.append(a)
        mlen.append(length)
        if progress:
            print(f"prior strength {s:g}: random {rnd[-1]:.4f} mm, region {reg[-1]:.4f} mm, max |Δ| {a:.3g}° / "
                  f"{length:.3g} mm", flush=True)
    n_r, n_g = len(folds_random), len(folds_region)
    score = (np.asarray(rnd) * n_r + np.asarray(reg) * n_g) / (n_r + n_g)
    best = float(strengths[int(np.argmin(score))])
    return PriorCV(strengths, np.asarray(rnd), np.asarray(reg), np.asarray(train), np.asarray(mang),
                   np.asarray(mlen), best, base)
