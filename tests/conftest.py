"""Shared test configuration: float64 and strict dtype promotion, robot presets as a fixture."""

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "strict")

from jaxcal import robots  # noqa: E402

ROBOT_NAMES = sorted(robots.PRESETS)


@pytest.fixture(params=ROBOT_NAMES)
def robot(request):
    """Every robot preset."""
    return robots.get_robot(request.param)


def numpy_dh_fk(alpha, a, d, theta, beta, q, convention="standard", beta_joints=(), tool=None):
    """Independent reference FK: a plain NumPy product of 4×4 matrices, one sample at a time."""

    def rz(t):
        c, s = np.cos(t), np.sin(t)
        return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])

    def rx(t):
        c, s = np.cos(t), np.sin(t)
        return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])

    def ry(t):
        c, s = np.cos(t), np.sin(t)
        return np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1.0]])

    def tr(x, y, z):
        T = np.eye(4)
        T[:3, 3] = (x, y, z)
        return T

    out = []
    for qi in np.atleast_2d(q):
        T = np.eye(4)
        for j in range(len(alpha)):
            B = ry(beta[j]) if (j + 1) in beta_joints else np.eye(4)
            if convention == "standard":
                A = rz(theta[j] + qi[j]) @ tr(0, 0, d[j]) @ tr(a[j], 0, 0) @ rx(alpha[j]) @ B
            else:
                A = rx(alpha[j]) @ B @ tr(a[j], 0, 0) @ rz(theta[j] + qi[j]) @ tr(0, 0, d[j])
            T = T @ A
        if tool is not None:
            T = T @ tr(*tool)
        out.append(T)
    return np.array(out)
