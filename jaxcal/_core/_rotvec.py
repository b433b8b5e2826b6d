"""Rotation vectors and rotation matrices in NumPy, for host-side code: pose files, the
closed-form starts of the sensors' extras, a camera's pose fit (no device program per call)."""

from __future__ import annotations

import numpy as np

__all__ = ["rotvec_to_matrix", "matrix_to_rotvec"]


def rotvec_to_matrix(w) -> np.ndarray:
    """``[..., 3, 3]`` rotation matrices of rotation vectors ``w`` ``[..., 3]`` (rad; Rodrigues),
    in NumPy: host-side callers (pose files, closed-form starts, a camera's pose fit) run no
    device program per call."""
    w = np.asarray(w, np.float64)
    th = np.linalg.norm(w, axis=-1, keepdims=True)
    k = np.where(th > 0, w / np.where(th > 0, th, 1.0), 0.0)
    K = np.zeros(w.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -k[..., 2], k[..., 1], -k[..., 0]
    K = K - np.swapaxes(K, -1, -2)
    th = th[..., None]
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * (K @ K)


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """``[..., 3]`` rotation vectors (rad) of rotation matrices ``R`` ``[..., 3, 3]``, in NumPy
    (the inverse of :func:`rotvec_to_matrix` for angles in ``[0, π)``)."""
    c = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1.0, 1.0)
    th = np.arccos(c)
    v = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    s = np.sin(th)
    small = s < 1e-9
    factor = np.where(small, 0.5, th / (2 * np.where(small, 1.0, s)))
    return v * factor[..., None]
