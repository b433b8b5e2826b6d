"""A plain NumPy transcription of a combined residual over a kinematic tree (issue 51, speed row).

What the CTU multirobot-calibration toolbox gives MATLAB's ``lsqnonlin`` (finite-difference
Jacobian): the whitened residual of every block written in vectorised array code. Here the same
for the blocks of ``benchmarks/bench_multiarm.py``'s speed row (self-contact, plane contact, tip
to tip cameras on :func:`jaxcal.robots.dual_arm_ma1400`), float64, written from the maths of the
models' docstrings, not by calling jaxcal's kernels: jaxcal is read only once, at set-up, for
the numbers a user has anyway (the tree's joint origins and tips, the sensors' nominal geometry,
the data, each block's σ, which parameters are free and where they start).

Kinematics (``jaxcal/_models/_chain.py``'s error model), per joint ``j`` with parent ``p(j)``::

    T_j = T_p(j) · Tr(t_o + [dx, dy, dz]) · R_o · Rx(drx) · Ry(dry) · Rz(q_j + offset)     (revolute)
    T_j = T_p(j) · Tr(t_o + [dx, dy, dz]) · R_o · Rx(drx) · Ry(dry) · Rz(drz) · Tz(q_j + offset)

(``T_-1 = I``, the base frame), every joint once however many tips it moves; tip ``k`` on joint
``j``: ``F_k = T_j · Tr(t_f + tip_translation) · R_f · Rx·Ry·Rz(tip_rotation)``, its tool point
``F_k · (tool_k + Δtool_k)`` (``tool`` for the default tip, ``tool@<tip>`` for another where the
parameters have it). Blocks, each over its σ:

* self-contact: ``‖p_a − p_b‖ − y`` (mm);
* planes: ``n_k·p − d_k`` with ``n_k = exp([u e_u + v e_v]×)·n0_k``, ``d_k = d0_k + plane_d`` (mm);
* camera, tip to tip: ``p = R_Xᵀ(R_Aᵀ(P_B + R_B·w − P_A) − t_X)``, ``w = R_T·b + t_T`` with
  ``R = exp(δr)·R₀``, ``t = t₀ + δt`` for the hand-eye ``X`` and the target ``T``; OpenCV's
  radial-tangential projection; ``predicted − measured`` (px), 0 where a corner is NaN.

The output is every block's own entries, block after block, row-major (what
``Combined.residual`` holds without its padding: ``Combined.residual_entries``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["NumpyTreeResidual"]


def _rxyz(a: float, b: float, c: float) -> np.ndarray:
    """``Rx(a)·Ry(b)·Rz(c)`` ``[3, 3]``."""
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]])
    ry = np.array([[cb, 0.0, sb], [0.0, 1.0, 0.0], [-sb, 0.0, cb]])
    rz = np.array([[cc, -sc, 0.0], [sc, cc, 0.0], [0.0, 0.0, 1.0]])
    return rx @ ry @ rz


def _rodrigues(w: np.ndarray) -> np.ndarray:
    """``exp([w]×)`` ``[..., 3, 3]`` of rotation vectors ``w`` ``[..., 3]`` (rad); the series
    below θ² = 1e-8 (exact at 0)."""
    w = np.asarray(w, np.float64)
    t2 = np.sum(w * w, axis=-1)[..., None, None]
    small = t2 < 1e-8
    t2s = np.where(small, 1.0, t2)
    th = np.sqrt(t2s)
    a = np.where(small, 1.0 - t2 / 6.0, np.sin(th) / th)
    b = np.where(small, 0.5 - t2 / 24.0, (1.0 - np.cos(th)) / t2s)
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    o = np.zeros_like(x)
    K = np.stack([np.stack([o, -z, y], -1), np.stack([z, o, -x], -1), np.stack([-y, x, o], -1)], -2)
    return np.eye(3) + a * K + b * (K @ K)


class NumpyTreeResidual:
    """``r(x)``: the whitened combined residual ``[M]`` of the free parameters ``x`` ``[p]``.

    Args:
        tree: the :class:`jaxcal.KinematicTree` (its arrays are read once).
        comb, q, y: :func:`jaxcal._sensors._blocks.combine`'s model and stacked data (the
            blocks' models, rows, σ and the parameter names each block reads).
        space, start: which entries are free (the order of ``x``) and the values of the others.

    Raises:
        NotImplementedError: a block kind, camera mount or tree feature not transcribed here.
    """

    def __init__(self, tree, comb, q, y, space, start):
        if tree.nongeometric is not None:
            raise NotImplementedError("joint-space (harmonic) errors are not transcribed")
        if comb.pad:
            raise NotImplementedError("padded combined models are not transcribed")
        f = lambda a: np.array(a, np.float64)  # noqa: E731
        self.R_o, self.t_o = f(tree.origin_R), f(tree.origin_t)
        self.flange_R, self.flange_t, self.tools = f(tree.flange_R), f(tree.flange_t), f(tree.tools)
        self.parents, self.tip_parents, self.tips = tree.parents, tree.tip_parents, tree.tips
        self.prismatic = tuple(t == "prismatic" for t in tree.joint_types)
        self.tip_groups = [(f"tip_translation@{t}", f"tip_rotation@{t}") if len(self.tips) > 1
                           else ("tip_translation", "tip_rotation") for t in self.tips]
        self.tool_groups = ["tool"] + [f"tool@{t}" for t in self.tips[1:]]
        # the parameter vector: every entry's start value, the free ones replaced by x
        layout = space.layout
        self.flat0 = np.concatenate([f(start.values[g.name]).reshape(-1) for g in layout.groups])
        self.free = np.asarray(space.free_index)
        self.slices = {g.name: (layout.slice(g.name), g.shape) for g in layout.groups}
        self.q = f(q)
        self.blocks = []
        s = 0
        for b, (m, n) in enumerate(zip(comb.models, comb.counts)):
            names = dict(comb.views[b][1])  # the block's own group names → the combined ones
            rows = slice(s, s + n)
            yb = f(y[rows, : comb.widths[b]])
            sigma = float(np.asarray(comb.sigma)[b])
            if m.kind == "self_contact":
                spec = ("contact", [self.tips.index(t) for t in m.tips], yb[:, 0])
            elif m.kind == "plane":
                k = np.clip(np.round(yb[:, 0]).astype(int), 0, len(m.labels) - 1)
                spec = ("plane", self._tip(m.tip), k, f(m.normals), f(m.offsets), f(m.basis_u), f(m.basis_v),
                        [f"plane@{lab}" for lab in m.labels])
            elif m.kind == "camera" and m.mount == "tip_to_tip":
                uv = yb.reshape(n, -1, 2)
                frames = (f(m.handeye_rotation), f(m.handeye_translation), f(m.target_rotation),
                          f(m.target_translation))
                groups = [names[g] for g in ("handeye_rotation", "handeye_translation", "target_rotation",
                                             "target_translation")]
                spec = ("camera", self._tip(m.tip), self._tip(m.target_tip), f(m.points), f(m.intrinsics), frames,
                        groups, names.get("intrinsics"), np.isfinite(uv), np.where(np.isfinite(uv), uv, 0.0))
            else:
                raise NotImplementedError(f"block {comb.names[b]!r}: {m.kind} "
                                          f"{getattr(m, 'mount', '')} is not transcribed")
            self.blocks.append((rows, sigma, spec))
            s += n

    def _tip(self, tip) -> int:
        return 0 if tip is None else self.tips.index(tip)

    def params(self, x) -> dict:
        """``{group: value}`` of every group at the free entries ``x``."""
        flat = self.flat0.copy()
        flat[self.free] = x
        return {g: flat[sl].reshape(shape) for g, (sl, shape) in self.slices.items()}

    def joint_frames(self, P: dict, q: np.ndarray) -> list:
        """``(R [n, 3, 3], p [n, 3])`` of every joint frame in the base frame (mm)."""
        n = q.shape[0]
        dt = np.stack([P["dx"], P["dy"], P["dz"]], axis=1)
        out = []
        for j, parent in enumerate(self.parents):
            M = self.R_o[j] @ _rxyz(P["drx"][j], P["dry"][j], P["drz"][j] if self.prismatic[j] else 0.0)
            t = self.t_o[j] + dt[j]
            if parent < 0:
                R, p = np.tile(M, (n, 1, 1)), np.tile(t, (n, 1))
            else:  # a constant on the right: one [3n, 3] × [3, 3] product
                Rp, pp = out[parent]
                R, p = (Rp.reshape(-1, 3) @ M).reshape(n, 3, 3), pp + (Rp.reshape(-1, 3) @ t).reshape(n, 3)
            qj = q[:, j] + P["offset"][j]
            if self.prismatic[j]:
                p = p + R[:, :, 2] * qj[:, None]
            else:  # R·Rz(q): the first two columns turn
                c, s = np.cos(qj)[:, None], np.sin(qj)[:, None]
                X, Y = R[:, :, 0].copy(), R[:, :, 1].copy()
                R[:, :, 0] = c * X + s * Y
                R[:, :, 1] = c * Y - s * X
            out.append((R, p))
        return out

    def tip_frame(self, P: dict, frames: list, k: int):
        """``(R [n, 3, 3], p [n, 3])`` of tip ``k``'s link frame (mm)."""
        gt, gr = self.tip_groups[k]
        F = self.flange_R[k] @ _rxyz(*P[gr])
        R, p = frames[self.tip_parents[k]]
        n = R.shape[0]
        Rf = R.reshape(-1, 3)
        return (Rf @ F).reshape(n, 3, 3), p + (Rf @ (self.flange_t[k] + P[gt])).reshape(n, 3)

    def tool_point(self, P: dict, tip_frame, k: int) -> np.ndarray:
        """Tip ``k``'s tool point ``[n, 3]`` in the base frame (mm)."""
        R, p = tip_frame
        g = self.tool_groups[k]
        return p + (R.reshape(-1, 3) @ (self.tools[k] + (P[g] if g in P else 0.0))).reshape(p.shape)

    def __call__(self, x) -> np.ndarray:
        P = self.params(np.asarray(x, np.float64))
        frames = self.joint_frames(P, self.q)  # every row, every joint: one pass over the tree
        tips = [self.tip_frame(P, frames, k) for k in range(len(self.tips))]
        out = []
        for rows, sigma, spec in self.blocks:
            kind = spec[0]
            if kind == "contact":
                (a, b), d = spec[1], spec[2]
                pa = self.tool_point(P, tips[a], a)[rows]
                pb = self.tool_point(P, tips[b], b)[rows]
                r = np.sqrt(np.sum((pa - pb) ** 2, axis=1)) - d
            elif kind == "plane":
                _, k, lab, n0, d0, eu, ev, groups = spec
                dev = np.stack([P[g] for g in groups])  # [K, 3]: u, v, d
                n = np.einsum("kij,kj->ki", _rodrigues(dev[:, :1] * eu + dev[:, 1:2] * ev), n0)
                p = self.tool_point(P, tips[k], k)[rows]
                r = np.sum(n[lab] * p, axis=1) - (d0 + dev[:, 2])[lab]
            else:
                _, ka, kb, pts, k0, (RX0, tX0, RT0, tT0), groups, g_k, seen, uv = spec
                RX, tX = _rodrigues(P[groups[0]]) @ RX0, tX0 + P[groups[1]]
                RT, tT = _rodrigues(P[groups[2]]) @ RT0, tT0 + P[groups[3]]
                k = k0 + (P[g_k] if g_k is not None else 0.0)
                RA, PA = (v[rows] for v in tips[ka])
                RB, PB = (v[rows] for v in tips[kb])
                RAt = np.swapaxes(RA, 1, 2)
                A = RX.T @ RAt @ RB  # target frame → camera frame, per image [n, 3, 3]
                a = (RAt @ (PB - PA)[:, :, None])[:, :, 0] - tX
                a = a @ RX  # R_Xᵀ·a per row
                w = pts @ RT.T + tT  # [N, 3] in tip B's link frame
                pc = np.einsum("nij,kj->nki", A, w) + a[:, None, :]  # [n, N, 3] camera frame
                xn, yn = pc[..., 0] / pc[..., 2], pc[..., 1] / pc[..., 2]
                fx, fy, cx, cy, k1, k2, p1, p2, k3 = k
                r2 = xn * xn + yn * yn
                radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
                xd = xn * radial + 2 * p1 * xn * yn + p2 * (r2 + 2 * xn * xn)
                yd = yn * radial + p1 * (r2 + 2 * yn * yn) + 2 * p2 * xn * yn
                r = np.where(seen, np.stack([fx * xd + cx, fy * yd + cy], -1) - uv, 0.0).reshape(-1)
            out.append(r.reshape(-1) / sigma)
        return np.concatenate(out)
