"""The fleet fitted jointly: :func:`calibrate_fleet_jointly` estimates a robot model's population and
every unit's deviations together, each unit shrunk toward the fleet.

The normal hierarchical model of :meth:`jaxcal.Prior.from_fleet`: unit ``k``'s robot deviations
``x_k ~ N(μ, Σ)``, its data ``y_k`` a nonlinear function of ``x_k`` plus noise. ``from_fleet``
learns ``(μ, Σ)`` from results that were calibrated one by one under a generic prior, each unit's
data information linearised at *its own* estimate — a unit whose data see a direction poorly is
linearised where the generic prior put it. The joint fit removes that last approximation
by alternating, until the population mean stops moving:

* every unit calibrated under the members' prior ``N(μ, Σ)`` (maximum a posteriori: the unit
  shrunk toward the fleet mean as far as its own data leave it uncertain), all units in one
  :func:`jaxcal.calibrate_many` call (one batched compiled program);
* ``(μ, Σ)`` learned again from these results (expectation–maximisation; each unit's prior —
  now ``N(μ, Σ)`` — divided out, its data information re-linearised at its shrunk estimate).

At the fixed point the units' results are the posterior modes of the joint model and the
population its empirical-Bayes estimate, with their uncertainties (``population.mean_std``,
``spread_std``; each unit's ``uncertainty``).
"""

from __future__ import annotations

from typing import NamedTuple

from .._fit._objective import Prior, resolve_objective, resolve_prior
from ._fleet import FleetSummary, calibrate_many

__all__ = ["calibrate_fleet_jointly", "JointFleetResult"]


class JointFleetResult(NamedTuple):
    """What :func:`calibrate_fleet_jointly` returns.

    Attributes:
        results: one :class:`~jaxcal.CalibrationResult` per unit, calibrated under the members'
            prior ``N(μ, Σ)`` of the last round (each unit shrunk toward the fleet mean); ``None``
            for a unit that failed.
        prior: the robot model's prior for a *new* unit, ``N(μ, Σ + M)`` (``M``: the uncertainty of
            ``μ``), learned from ``results``; its ``population`` is :attr:`population`.
        population: the :class:`~jaxcal.FleetPopulation` (mean, spread and their σ; rad, mm).
        summary: the last round's :class:`~jaxcal.FleetSummary`.
        rounds: refits under a learned prior (after the first fit under ``base``).
        shifts: per round, the largest move of the population mean in units of its σ
            (``max |Δμ| / mean_std``); the last one ≤ ``tol`` when converged.
        converged: the mean moved by at most ``tol`` of its σ in the last round.
    """

    results: list
    prior: Prior
    population: object
    summary: FleetSummary
    rounds: int
    shifts: tuple
    converged: bool


def calibrate_fleet_jointly(robot, measurement, datasets, method="lm", *, base: Prior | str | None = None,
                            initial=None, max_rounds: int = 5, tol: float = 0.05, objective: str | None = "measured",
                            **kwargs) -> JointFleetResult:
    """Fit a robot model's population and every unit's deviations together (empirical Bayes with
    each unit's data re-linearised at its shrunk estimate).

    The model is :meth:`jaxcal.Prior.from_fleet`'s: unit ``k``'s deviations ``x_k ~ N(μ, Σ)``.
    ``from_fleet`` linearises each unit's data at its own estimate under a generic prior; this
    function alternates, until the population mean moves by at most ``tol`` of its σ: every unit
    calibrated under the members' prior ``N(μ, Σ)`` (each shrunk toward the fleet mean as far as
    its data leave it uncertain; all units in one :func:`jaxcal.calibrate_many` call), then
    ``(μ, Σ)`` learned again from these results (expectation–maximisation, each unit's prior
    divided out). At the fixed point the units' results are the posterior modes of the joint model
    and the population its empirical-Bayes estimate.

    Args:
        robot, measurement, datasets, method: as :func:`jaxcal.calibrate_many` (≥ 3 units of one
            robot model).
        base: the generic prior the first fit runs under and the hyper-prior of the mean
            (:meth:`jaxcal.Prior.from_fleet`'s ``base``; default ``Prior()``: 0.5°, 2 mm); a
            prior given by ``objective`` counts as ``base`` when ``base`` is ``None``.
        initial: the units' results under ``base`` when at hand (one per dataset, e.g. a fleet's
            ``calibrate_many(...).results`` with ``prior=base``): the first fit is skipped.
        max_rounds: at most this many refits under the learned members' prior.
        tol: stop when the population mean moves by at most ``tol`` of its own σ
            (``population.mean_std``) in a round.
        objective: as :func:`jaxcal.calibrate` (default ``"measured"``: the default prior and the
            Huber loss; the learned prior replaces the prior, the loss stays).
        **kwargs: every other keyword of :func:`jaxcal.calibrate_many` (``names``, ``noise_std``,
            ``chunk_size``, ``extras``, the method's settings, ...), the same in every round.

    Returns:
        :class:`JointFleetResult` ``(results, prior, population, summary, rounds, shifts,
        converged)``.
    """
    from .._fit._prior import fleet_prior

    if "prior" in kwargs:
        raise TypeError("calibrate_fleet_jointly takes base=, not prior= (the rounds' prior is the learned one)")
    if max_rounds < 1:
        raise ValueError(f"max_rounds must be at least 1, got {max_rounds!r}")
    datasets = list(datasets)
    preset, loss = resolve_objective(objective, None, kwargs.pop("loss", None))
    base = resolve_prior(base) if base is not None else resolve_prior(preset)
    base = Prior() if base is None else base
    kw = dict(kwargs, loss=loss)
    if initial is None:
        fleet = calibrate_many(robot, measurement, datasets, method, prior=base, **kw)
        results, summary = fleet.results, fleet.summary
    else:
        results, summary = list(initial), None
        if len(results) != len(datasets):
            raise ValueError(f"{len(results)} initial results for {len(datasets)} datasets")
    noise = base.noise_std

    def learn(results, members):
        ok = [r for r in results if r is not None]
        return fleet_prior(ok, base, noise_std=noise, members=members)

    members = learn(results, True)
    shifts = []
    converged = False
    for _ in range(max_rounds):
        fleet = calibrate_many(robot, measurement, datasets, method, prior=members, **kw)
        results, summary = fleet.results, fleet.summary
        new = learn(results, True)
        old, pop = dict(zip(members.population.names, members.population.mean)), new.population
        shifts.append(max(abs(m - old.get(n, 0.0)) / s for n, m, s in zip(pop.names, pop.mean, pop.mean_std)))
        members = new
        if shifts[-1] <= tol:
            converged = True
            break
    prior = learn(results, False)
    return JointFleetResult(results, prior, prior.population, summary, len(shifts), tuple(shifts), converged)
