"""The verdict per parameter (jaxcal._fit._verdicts) against closed forms of a linear-Gaussian
posterior ``C = (G + Λ)⁻¹``."""

import numpy as np
import pytest

from jaxcal._fit._diagnostics import Uncertainty
from jaxcal._fit._verdicts import DATA, HELD, PRIOR, UNDETERMINED, parameter_verdicts


@pytest.mark.parametrize("g, lam", [(3.0, 1.0), (1.0, 3.0), (0.2, 5.0), (1e6, 1.0)])
def test_one_parameter_prior_share_is_its_precision_share(g, lam):
    """One parameter: the prior's share of the posterior variance is λ/(g + λ), held by the prior
    exactly when the prior's precision exceeds the data's; expected (nothing more poses would
    change) when ten times the data would still leave it to the prior (λ > 10 g)."""
    v = parameter_verdicts(["x", "y"], ["x"], [[1.0 / (g + lam)]], None, [[lam]])
    assert v.prior_share["x"] == pytest.approx(lam / (g + lam), rel=1e-12)
    assert v.verdict == {"x": PRIOR if lam > g else DATA, "y": HELD}
    assert (v.expected == ("x",)) == (lam > 10 * g)


def test_parallel_axes_and_an_extra_that_trades_with_a_prior_parameter():
    """d2, d3 seen only as their sum (parallel axes), d1 seen only together with an extra a without
    a prior (a draw wire's anchor_z), b seen alone: the prior holds d2, d3 (each half unseen), d1 and
    a (a's whole uncertainty is d1's prior), whatever the data's precision; b is the data's."""
    s, g = 2.0, 1e4
    names = ["d2", "d3", "d1", "a", "b"]
    J = np.array([[1.0, 1.0, 0, 0, 0], [0, 0, 1.0, 1.0, 0], [0, 0, 0, 0, 1.0]])
    G = g * J.T @ J
    P = np.diag([1 / s**2] * 3 + [0.0, 1 / s**2])
    C = np.linalg.inv(G + P)
    unseen = np.array([[1.0, -1.0, 0, 0, 0], [0, 0, 1.0, -1.0, 0]]).T
    v = parameter_verdicts(names, names, C, unseen, P)
    assert v.by_prior == ("d2", "d3", "d1", "a") and v.determined == ("b",)
    assert set(v.expected) == {"d2", "d3", "d1", "a"} and v.fixable == ()
    assert v.prior_share["a"] == pytest.approx(1.0, abs=1e-3) and np.sqrt(C[3, 3]) == pytest.approx(s, rel=1e-3)
    # a's σ with the robot's parameters known (d1 at its value): the data's alone, 1/√g, d1 + a
    # being seen with information g; the others keep theirs, the given ones 0
    sd = np.sqrt(np.diag(C))
    unc = Uncertainty(tuple(names), ("mm",) * 5, sd, C, 1.0, 3.0, 3)
    given = unc.given_std(["d2", "d3", "d1", "b"])
    assert given[3] == pytest.approx(1 / np.sqrt(g), rel=1e-6) and given[3] < 0.01 * sd[3]
    assert np.array_equal(given[[0, 1, 2, 4]], np.zeros(4))
    assert unc.given_std([]) == pytest.approx(sd, rel=1e-9)
    # without a prior every free parameter is the data's (or undetermined), the rest held
    w = parameter_verdicts(names + ["c"], ["b", "d2"], np.diag([1 / g, np.inf]), None, None, [1 / g, np.inf])
    assert w.verdict == {"d2": UNDETERMINED, "d3": HELD, "d1": HELD, "a": HELD, "b": DATA, "c": HELD}


def test_weakly_seen_parameter_is_fixable_and_survives_renaming_and_the_file():
    """A direction the data see at a third of the prior's precision: held by the prior, but ten
    times the data would determine it, so it is the poses' fault (fixable), not expected."""
    lam, g = 1.0, 1.0 / 3.0
    v = parameter_verdicts(["p", "q"], ["p", "q"], np.diag([1 / (g + lam), 1 / (100 * lam)]), None,
                           np.diag([lam, lam]))
    assert v.by_prior == ("p",) and v.fixable == ("p",) and v.expected == () and v.mark("p") == "†"
    assert v.mark("q") == "" and v.mark("unknown") == "*"
    assert type(v).from_dict(v.to_dict()) == v
    assert v.renamed({"p@b": "p"}).verdict == {"p@b": PRIOR}
