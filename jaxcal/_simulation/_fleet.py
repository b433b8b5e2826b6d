"""A simulated fleet: many units of one robot model drawn from a known population."""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._core._params import Deviations
from .._core._xla import jit
from .._models._abstract import AbstractRobot
from .._sensors._measurement import MeasurementModel, Position
from ._simulate import Experiment, draw_deviations, simulate_experiment

__all__ = ["SimulatedFleet", "simulate_fleet"]


class SimulatedFleet(NamedTuple):
    """Units of one robot model with a known population (what :func:`simulate_fleet` returns).

    Attributes:
        mean: the population mean deviations (the systematic error every unit shares; rad, mm).
        spread: the population σ of each deviation around ``mean`` (rad, mm; a :class:`Deviations`
            of standard deviations).
        units: one :class:`~jaxcal.Experiment` per unit (its ``true_deviations`` = ``mean`` + the
            unit's own draw).
    """

    mean: Deviations
    spread: Deviations
    units: list

    def z_scores(self, population) -> tuple[np.ndarray, np.ndarray]:
        """A learned population (:class:`~jaxcal.FleetPopulation`, e.g. ``prior.population``)
        against this fleet's truth in units of its stated σ: ``(z_mean, z_spread)``, each ``[k]``
        over ``population.names`` (``(learned − true) / stated σ``)."""
        names = self.mean.layout.names
        mean = dict(zip(names, np.asarray(self.mean._ravel_numpy())))
        spread = dict(zip(names, np.asarray(self.spread._ravel_numpy())))
        z_mean = [(m - mean[n]) / s for n, m, s in zip(population.names, population.mean, population.mean_std)]
        z_spread = [(m - spread[n]) / s for n, m, s in zip(population.names, population.spread, population.spread_std)]
        return np.asarray(z_mean), np.asarray(z_spread)


def simulate_fleet(key: Array, robot: AbstractRobot, *, n_units: int, n_samples: int, measurement: MeasurementModel | None
                   = None, noise_std: float = 0.05, spread_angle_deg: float = 0.02, spread_length_mm: float = 0.08,
                   mean: Deviations | None = None, test_fraction: float = 0.5, measure_key: Array | None = None,
                   shift: Deviations | None = None, **simulate) -> SimulatedFleet:
    """``n_units`` simulated units of ``robot`` from one ``jax.random`` key, all simulated in one
    vectorised program (same ``n_samples`` each).

    The population: a shared mean deviation (``mean``; default drawn by
    :func:`~jaxcal._simulation._simulate.draw_deviations` at the paper's magnitudes, 0.2°,
    0.6 mm) and independent Gaussian per-unit deviations around it, σ = ``spread_angle_deg``
    (degrees, on α, θ and β at Hayati joints) and ``spread_length_mm`` (mm, on a and d). Each
    unit is measured at its own random poses by ``measurement`` (default: a :class:`Position`
    sensor in the base frame) with Gaussian noise ``noise_std`` (mm) and split into train and
    test (``test_fraction``), as :func:`jaxcal.simulate_experiment`.

    The units (their true deviations) come from ``key``; their poses and noise from
    ``measure_key`` (default: from ``key``): the same ``key`` with another ``measure_key``
    measures the same units again (a recalibration), ``shift`` (deviations added to every
    unit's truth, e.g. ``0.1°`` on ``theta_3``) makes them drift in between. Unit ``i`` depends on
    ``i`` and the keys only: the first units of a larger fleet are the same units. ``simulate``:
    further keywords of :func:`jaxcal.simulate_experiment` (``coverage``, ``oversample``...).
    """
    if n_units < 1:
        raise ValueError(f"n_units must be at least 1, got {n_units}")
    measurement = _default_sensor() if measurement is None else measurement
    k_mean, k_units, k_data = jax.random.split(key, 3)
    k_data = k_data if measure_key is None else measure_key
    mean = draw_deviations(k_mean, robot) if mean is None else mean
    one = draw_deviations(k_mean, robot, angle_std_deg=1.0, length_std_mm=1.0)  # which entries vary
    scale = {"rad": np.radians(spread_angle_deg), "mm": spread_length_mm}
    sd = np.asarray([scale.get(u, 0.0) for u in mean.layout.units]) * (np.asarray(one._ravel_numpy()) != 0)
    spread = Deviations.unravel(sd, mean.layout)

    center = mean.ravel() if shift is None else mean.ravel() + shift.ravel()
    # unit i's keys are fold_in(key, i): the first units of a larger fleet are the same units
    ids = jnp.arange(n_units)
    fold = jax.vmap(jax.random.fold_in, in_axes=(None, 0))
    batch: Experiment = _simulate_units(fold(k_units, ids), fold(k_data, ids), center, jnp.asarray(sd), robot,
                                        measurement, mean.layout, n_samples, noise_std, test_fraction,
                                        tuple(sorted(simulate.items())))
    units = [jax.tree.map(lambda a, i=i: a[i], batch) for i in range(n_units)]
    return SimulatedFleet(mean, spread, units)


@functools.lru_cache(maxsize=1)
def _default_sensor() -> Position:
    """One :class:`Position` sensor object for every call (the compiled simulators are kept per object)."""
    return Position()


#: compiled unit simulators by (robot, sensor, sizes, settings); the robot is closed over (its
#: reach sets the workspace filter on the host), the population's values are arguments
_PROGRAMS: dict = {}


def _simulate_units(k_dev, k_sim, center, sd, robot, measurement, layout, n_samples, noise_std, test_fraction,
                    simulate) -> Experiment:
    """The units of :func:`simulate_fleet`, vectorised; one compiled program per robot object,
    sensor object, sizes and settings (kept while the robot and sensor are)."""
    key = (id(robot), id(measurement), layout, n_samples, float(noise_std), float(test_fraction), simulate)
    entry = _PROGRAMS.get(key)
    if entry is None or entry[0] is not robot or entry[1] is not measurement:

        def unit(kd, ks, center, sd):
            z = jax.random.normal(kd, center.shape, center.dtype)
            true = Deviations.unravel(center + sd * z, layout)
            return simulate_experiment(ks, robot, measurement=measurement, true_deviations=true,
                                       n_samples=n_samples, noise_std=noise_std, test_fraction=test_fraction,
                                       **dict(simulate))

        if len(_PROGRAMS) > 8:
            _PROGRAMS.clear()
        entry = _PROGRAMS[key] = (robot, measurement, jit(jax.vmap(unit, in_axes=(0, 0, None, None))))
    return entry[2](k_dev, k_sim, center, sd)
