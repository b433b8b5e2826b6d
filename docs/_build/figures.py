"""The documentation's figures: committed SVGs under ``docs/figures/``, drawn here with matplotlib.

Regenerate after changing this script (and commit the SVGs with it)::

    python docs/_build/figures.py            # writes docs/figures/*.svg
    python docs/_build/figures.py --out DIR  # somewhere else (tests/test_docs.py compares the names)

The output is reproducible: a fixed ``svg.hashsalt``, no date in the metadata, text kept as text
(``svg.fonttype: none``, so the files are small and the browser's sans-serif font draws the labels).
Nothing here imports jaxcal or JAX: the schematics are side views with fixed joint angles.
``FIGURES`` lists every file written; ``tests/test_docs.py`` checks that each is in the repository
and used by a page, and that a page uses no other figure.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("svg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: E402
from matplotlib.patches import Circle, FancyArrowPatch, FancyBboxPatch, Polygon, Rectangle  # noqa: E402
from matplotlib.transforms import Bbox  # noqa: E402

FIGURES = ("dh-frames.svg", "calibrate-flow.svg", "setup-draw-wire.svg", "setup-tracker.svg",
           "setup-plane-contact.svg", "setup-fixed-point.svg", "setup-distance-bar.svg", "setup-camera.svg")

OUT = Path(__file__).resolve().parents[1] / "figures"
RC = {"svg.hashsalt": "jaxcal-docs", "svg.fonttype": "none", "font.family": "sans-serif",
      "font.size": 11, "path.simplify": True}
ARM, JOINT, SENSOR, ACCENT, GREY = "#455a64", "#ffffff", "#1565c0", "#c62828", "#9e9e9e"


def _save(fig, out: Path, name: str):
    """Write the figure cropped to what is drawn (``bbox_inches="tight"`` would keep the hidden axes' box)."""
    renderer = FigureCanvasAgg(fig).get_renderer()
    boxes = [a.get_window_extent(renderer) for ax in fig.axes for a in (*ax.patches, *ax.lines, *ax.texts)]
    box = Bbox.union(boxes).transformed(fig.dpi_scale_trans.inverted()).padded(0.2)  # the browser's font may be wider
    fig.savefig(out / name, format="svg", metadata={"Date": None, "Creator": None}, bbox_inches=box)
    plt.close(fig)


def _canvas(w=6.4, h=3.6, xlim=(-0.6, 2.6), ylim=(-0.15, 1.6)):
    fig, ax = plt.subplots(figsize=(w, h))
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    ax.set_aspect("equal")
    ax.axis("off")
    return fig, ax


def _arrow(ax, a, b, color="k", lw=1.4, style="-|>", ms=12, ls="-", z=5):
    ax.add_patch(FancyArrowPatch(a, b, arrowstyle=style, mutation_scale=ms, color=color, lw=lw, linestyle=ls,
                                 zorder=z, shrinkA=0, shrinkB=0))


# --- a planar arm (side view) ---------------------------------------------------------------

LINKS = (0.45, 0.62, 0.55, 0.12)  # base height, upper arm, forearm, wrist-to-flange (arbitrary units)


def _arm_points(q_deg, base=(0.0, 0.0)):
    """Joint positions of a planar 3-link arm on a pedestal: base, shoulder, elbow, wrist, flange."""
    q = np.radians(q_deg)
    pts = [np.array(base, float), np.array(base, float) + [0, LINKS[0]]]
    ang = np.pi / 2
    for qi, li in zip(q, LINKS[1:]):
        ang = ang + qi
        pts.append(pts[-1] + li * np.array([np.cos(ang), np.sin(ang)]))
    return pts, ang


def _arm(ax, q_deg, base=(0.0, 0.0), tool=0.1, alpha=1.0, z=3):
    """Draw the arm; return (flange point, tool-tip point, tool direction)."""
    pts, ang = _arm_points(q_deg, base)
    bx, by = base
    ax.add_patch(Rectangle((bx - 0.16, by - 0.05), 0.32, 0.07, color=ARM, alpha=alpha, zorder=z))
    xy = np.array(pts[1:])
    ax.plot([bx, bx], [by, pts[1][1]], color=ARM, lw=9, solid_capstyle="butt", alpha=alpha, zorder=z)
    ax.plot(xy[:, 0], xy[:, 1], color=ARM, lw=7, solid_capstyle="round", alpha=alpha, zorder=z)
    for p in pts[1:-1]:
        ax.add_patch(Circle(p, 0.035, fc=JOINT, ec=ARM, lw=1.5, alpha=alpha, zorder=z + 1))
    d = np.array([np.cos(ang), np.sin(ang)])
    tip = pts[-1] + tool * d
    if tool:
        ax.plot([pts[-1][0], tip[0]], [pts[-1][1], tip[1]], color="#37474f", lw=2.5, alpha=alpha, zorder=z)
    return pts[-1], tip, d


def _arm_to(ax, target, tool_deg=-90.0, tool=0.1, base=(0.0, 0.0), alpha=1.0, z=3):
    """Draw the arm with its tool tip on ``target``, the tool pointing at ``tool_deg`` (elbow up)."""
    phi = np.radians(tool_deg)
    t = np.asarray(target, float)
    w = t - (tool + LINKS[3]) * np.array([np.cos(phi), np.sin(phi)])
    s = np.array(base, float) + [0, LINKS[0]]
    r = w - s
    l1, l2 = LINKS[1], LINKS[2]
    c2 = np.clip((r @ r - l1**2 - l2**2) / (2 * l1 * l2), -1, 1)
    q2 = np.arccos(c2)  # elbow up: the forearm turns clockwise from the upper arm
    a1 = np.arctan2(r[1], r[0]) + np.arctan2(l2 * np.sin(q2), l1 + l2 * np.cos(q2))
    a2 = a1 - q2
    q = np.degrees([a1 - np.pi / 2, a2 - a1, phi - a2])
    return _arm(ax, q, base=base, tool=tool, alpha=alpha, z=z)


def _floor(ax, x0, x1, y=-0.05):
    ax.plot([x0, x1], [y, y], color="k", lw=1)
    for x in np.arange(x0, x1, 0.08):
        ax.plot([x, x - 0.05], [y, y - 0.05], color="k", lw=0.6)


def _frame(ax, o, ex, ey, length=0.16, label="", color="k", lx="x", ly="y", fs=9):
    o = np.asarray(o, float)
    for e, n in ((ex, lx), (ey, ly)):
        e = np.asarray(e, float) / np.linalg.norm(e)
        _arrow(ax, o, o + length * e, color=color, lw=1.2, ms=9)
        if n:
            ax.text(*(o + (length + 0.04) * e), n, color=color, fontsize=fs, ha="center", va="center")
    if label:
        ax.text(o[0], o[1] - 0.07, label, color=color, fontsize=fs, ha="center", va="top")


# --- (a) standard DH for one joint ------------------------------------------------------------

def dh_frames(out: Path):
    """Frames i−1 and i of the standard (Denavit–Hartenberg) convention and the four parameters."""

    def P(v):  # cabinet projection: x to the right, z up, y into the page (up and to the right)
        v = np.asarray(v, float)
        return np.array([v[0] + 0.5 * v[1], v[2] + 0.5 * v[1]])

    th, al, d, a = np.radians(70), np.radians(-40), 1.4, 2.0
    z0, x0 = np.array([0, 0, 1.0]), np.array([1.0, 0, 0])
    xi = np.array([np.cos(th), np.sin(th), 0])
    w = np.cross(xi, z0)
    zi = np.cos(al) * z0 + np.sin(al) * w
    O0, H = np.zeros(3), d * z0
    Oi = H + a * xi

    fig, ax = plt.subplots(figsize=(6.6, 5.6))
    ax.set_xlim(-1.0, 3.9)
    ax.set_ylim(-1.35, 3.9)
    ax.set_aspect("equal")
    ax.axis("off")

    def line(p, q, **kw):
        p, q = P(p), P(q)
        ax.plot([p[0], q[0]], [p[1], q[1]], **kw)

    def vec(o, v, L, color, name, off=0.2):
        _arrow(ax, P(o), P(o + L * v), color=color, lw=1.8, ms=13)
        t = P(o + (L + off) * v)
        ax.text(t[0], t[1], name, color=color, fontsize=13, ha="center", va="center")

    # joint axes (dash-dot) and the joints as cylinders on them
    line(-1.0 * z0, O0 + 2.7 * z0, color=GREY, lw=1, ls="-.")
    line(Oi - 1.2 * zi, Oi + 1.5 * zi, color=GREY, lw=1, ls="-.")
    for c, v, name in ((O0 - 0.55 * z0, z0, "joint i"), (Oi - 0.85 * zi, zi, "joint i+1")):
        p, q = P(c - 0.2 * v), P(c + 0.2 * v)
        ax.plot([p[0], q[0]], [p[1], q[1]], color=ARM, lw=16, solid_capstyle="butt", alpha=0.3)
        ax.text(p[0] + 0.2, (p[1] + q[1]) / 2, name, color=ARM, fontsize=10, ha="left", va="center")

    vec(O0, z0, 0.9, "k", "zᵢ₋₁")
    vec(O0, x0, 1.0, "k", "xᵢ₋₁", off=0.3)
    vec(Oi, zi, 1.1, SENSOR, "zᵢ")
    vec(Oi, xi, 0.8, SENSOR, "xᵢ")
    for o, n, col, dx in ((O0, "Oᵢ₋₁", "k", -0.1), (Oi, "Oᵢ", SENSOR, 0.1)):
        ax.add_patch(Circle(P(o), 0.045, color=col, zorder=6))
        t = P(o)
        ax.text(t[0] + dx, t[1] - 0.1, n, color=col, fontsize=11, ha="right" if dx < 0 else "left", va="top")

    # θ_i: about z_{i−1}, from x_{i−1} to x_i (a copy of x_i at O_{i−1})
    line(O0, O0 + 1.0 * xi, color=ACCENT, lw=1, ls="--")
    arc = np.array([P(0.75 * (np.cos(t) * x0 + np.sin(t) * np.cross(z0, x0))) for t in np.linspace(0, th, 30)])
    ax.plot(arc[:, 0], arc[:, 1], color=ACCENT, lw=1.6)
    _arrow(ax, arc[-4], arc[-1], color=ACCENT, ms=10)
    t = P(0.8 * (np.cos(th / 2) * x0 + np.sin(th / 2) * np.cross(z0, x0)))
    ax.text(t[0] + 0.08, t[1], "θᵢ", color=ACCENT, fontsize=14, ha="left", va="center")

    # d_i: along z_{i−1}, from O_{i−1} to the foot of the common normal
    s = -0.4 * x0
    line(O0 + s, H + s, color=ACCENT, lw=1.4)
    for p in (O0, H):
        line(p + s - 0.07 * x0, p + s + 0.07 * x0, color=ACCENT, lw=1.4)
        line(p, p + s, color=ACCENT, lw=0.6, ls=":")
    t = P(0.5 * H + s)
    ax.text(t[0] - 0.1, t[1], "dᵢ", color=ACCENT, fontsize=14, ha="right", va="center")

    # a_i: the common normal, along x_i, from axis z_{i−1} to axis z_i
    line(H, Oi, color="k", lw=2.4)
    ax.add_patch(Circle(P(H), 0.035, color="k", zorder=6))
    t = P(H + 0.45 * a * xi)
    ax.text(t[0] - 0.1, t[1] + 0.12, "aᵢ", color=ACCENT, fontsize=14, ha="right", va="bottom")
    ax.text(t[0], t[1] + 0.12, "  (common normal)", color="k", fontsize=9, ha="left", va="bottom")

    # α_i: about x_i, from z_{i−1} (a copy at O_i) to z_i
    line(Oi, Oi + 0.9 * z0, color=ACCENT, lw=1, ls="--")
    arc = np.array([P(Oi + 0.7 * (np.cos(t) * z0 + np.sin(t) * w)) for t in np.linspace(0, al, 30)])
    ax.plot(arc[:, 0], arc[:, 1], color=ACCENT, lw=1.6)
    _arrow(ax, arc[-4], arc[-1], color=ACCENT, ms=10)
    t = P(Oi + 0.75 * (np.cos(al / 2) * z0 + np.sin(al / 2) * w))
    ax.text(t[0] - 0.05, t[1] + 0.08, "αᵢ", color=ACCENT, fontsize=14, ha="right", va="bottom")

    ax.text(-0.95, -1.3, "ⁱ⁻¹Tᵢ = Rot(z, θᵢ) · Trans(z, dᵢ) · Trans(x, aᵢ) · Rot(x, αᵢ)", fontsize=10,
            ha="left", va="bottom")
    _save(fig, out, "dh-frames.svg")


# --- (b) sensor set-ups ------------------------------------------------------------------------

def _note(ax, x, text, color="k", y=-0.14):
    ax.text(x, y, text, color=color, fontsize=10, ha="center", va="top")


def setup_draw_wire(out: Path):
    fig, ax = _canvas(ylim=(-0.4, 1.5))
    _floor(ax, -0.5, 2.4)
    _, tip, _ = _arm_to(ax, (0.95, 0.55))
    anchor = np.array([1.9, 0.0])
    ax.add_patch(Rectangle((anchor[0] - 0.12, -0.05), 0.24, 0.14, fc="#cfd8dc", ec="k", zorder=4))
    a = anchor + [0, 0.09]
    ax.add_patch(Circle(a, 0.05, fc=SENSOR, ec="k", zorder=5))
    ax.plot([a[0], tip[0]], [a[1], tip[1]], color=SENSOR, lw=1.5, zorder=2)
    ax.add_patch(Circle(tip, 0.02, color=SENSOR, zorder=6))
    m = (a + tip) / 2
    ax.text(m[0] + 0.08, m[1] + 0.06, "wire length ℓ = ‖p(q) − anchor‖", color=SENSOR, fontsize=10, ha="left")
    ax.text(tip[0] + 0.08, tip[1] + 0.12, "wire clipped to the tool point p(q)", fontsize=10, ha="left")
    _note(ax, a[0], "draw-wire sensor (anchor fixed in the cell)", SENSOR)
    _save(fig, out, "setup-draw-wire.svg")


def setup_tracker(out: Path):
    fig, ax = _canvas(ylim=(-0.4, 1.5))
    _floor(ax, -0.5, 2.4)
    _, tip, _ = _arm_to(ax, (0.95, 0.5), tool_deg=-60)
    head = np.array([2.05, 0.8])
    for dx in (-0.15, 0.0, 0.15):  # tripod
        ax.plot([head[0], head[0] + dx], [head[1] - 0.1, -0.05], color="k", lw=1.5)
    ax.add_patch(FancyBboxPatch(head - [0.09, 0.1], 0.18, 0.2, boxstyle="round,pad=0.02", fc="#cfd8dc",
                                ec="k", zorder=4))
    ax.plot([head[0], tip[0]], [head[1], tip[1]], color=ACCENT, lw=1.4, ls="--", zorder=2)
    ax.add_patch(Circle(tip, 0.035, fc="#ffd54f", ec="k", zorder=6))
    _frame(ax, head + [0, 0.14], (1, 0), (0, 1), length=0.18, color=SENSOR, fs=9)
    ax.text(head[0], head[1] + 0.42, "laser tracker (its own frame)", fontsize=10, ha="center", color=SENSOR)
    m = 0.55 * head + 0.45 * tip
    ax.text(m[0] - 0.05, m[1] + 0.06, "line of sight", color=ACCENT, fontsize=10, ha="center", va="bottom",
            rotation=np.degrees(np.arctan2(head[1] - tip[1], head[0] - tip[0])), rotation_mode="anchor")
    ax.text(tip[0] + 0.02, tip[1] - 0.08, "reflector (SMR) on the tool", fontsize=10, ha="left", va="top")
    _note(ax, 1.0, "measured: x, y, z of the reflector in the tracker frame", ACCENT)
    _save(fig, out, "setup-tracker.svg")


def setup_plane_contact(out: Path):
    fig, ax = _canvas(ylim=(-0.4, 1.5))
    _floor(ax, -0.5, 2.4)
    ty = 0.3
    ax.add_patch(Polygon([[0.75, ty], [2.1, ty], [2.25, ty + 0.12], [0.9, ty + 0.12]], fc="#e3f2fd", ec=SENSOR,
                         zorder=1))
    for x in (0.85, 2.05):
        ax.plot([x, x], [-0.05, ty], color="k", lw=2)
    ax.add_patch(Rectangle((2.27, -0.05), 0.07, 1.3, fc="#e3f2fd", ec=SENSOR))  # a wall
    _, tip, _ = _arm_to(ax, (1.1, ty + 0.06), tool=0.13)
    ax.add_patch(Circle(tip, 0.022, color=ACCENT, zorder=6))
    _arrow(ax, (1.95, ty + 0.06), (1.95, ty + 0.4), color=SENSOR, ms=10)
    ax.text(2.0, ty + 0.33, "nₖ", color=SENSOR, fontsize=11, ha="left")
    ax.text(2.22, 1.3, "another plane (a wall)", color=SENSOR, fontsize=10, ha="right", va="bottom")
    ax.text(tip[0] + 0.1, tip[1] + 0.2, "probe touches plane k", fontsize=10, ha="left")
    _note(ax, 1.2, "each touch: nₖ · p(q) = cₖ  (planes fitted with the robot)", SENSOR)
    _save(fig, out, "setup-plane-contact.svg")


def setup_fixed_point(out: Path):
    fig, ax = _canvas(ylim=(-0.4, 1.5))
    _floor(ax, -0.5, 2.4)
    nest = np.array([1.0, 0.3])
    ax.plot([nest[0], nest[0]], [-0.05, nest[1] - 0.06], color="k", lw=3)
    ax.add_patch(Polygon([nest + [-0.07, -0.06], nest + [0.07, -0.06], nest], fc="#cfd8dc", ec="k", zorder=5))
    _arm_to(ax, nest, tool_deg=-45, tool=0.14, alpha=0.35)
    _arm_to(ax, nest, tool_deg=-100, tool=0.14)
    ax.add_patch(Circle(nest, 0.022, color=ACCENT, zorder=7))
    _note(ax, nest[0] - 0.1, "fixed point (a nest): one point,\nseveral orientations (pivoting)")
    sph = np.array([2.0, 0.3])
    ax.plot([sph[0], sph[0]], [-0.05, sph[1] - 0.12], color="k", lw=3)
    ax.add_patch(Circle(sph, 0.12, fc="#e3f2fd", ec=SENSOR, zorder=4))
    ax.add_patch(Circle(sph + 0.19 * np.array([np.cos(1.9), np.sin(1.9)]), 0.07, fc="#ffd54f", ec="k", zorder=4))
    _note(ax, sph[0] + 0.2, "or a ball on the tool\non a fixed sphere", SENSOR)
    _save(fig, out, "setup-fixed-point.svg")


def setup_distance_bar(out: Path):
    fig, ax = _canvas(ylim=(-0.4, 1.5))
    _floor(ax, -0.5, 2.4)
    a, b = np.array([0.7, 0.35]), np.array([1.25, 0.35])
    ax.plot([a[0], b[0]], [a[1], b[1]], color=SENSOR, lw=5, solid_capstyle="butt", zorder=2)
    for p in (a, b):
        ax.add_patch(Polygon([p + [-0.06, -0.06], p + [0.06, -0.06], p], fc="#cfd8dc", ec="k", zorder=5))
        ax.plot([p[0], p[0]], [-0.05, p[1] - 0.06], color="k", lw=2)
    _arm_to(ax, b, tool_deg=-55, alpha=0.35)
    _arm_to(ax, a, tool_deg=-90)
    for p, name in ((a, "pose a"), (b, "pose b")):
        ax.add_patch(Circle(p, 0.022, color=ACCENT, zorder=7))
        ax.text(p[0] + 0.06, p[1] + 0.05, name, fontsize=10, ha="left", va="bottom")
    _arrow(ax, a + [0, -0.14], b + [0, -0.14], color=SENSOR, style="<|-|>", ms=10)
    ax.text((a[0] + b[0]) / 2, a[1] - 0.18, "L", color=SENSOR, fontsize=11, ha="center", va="top")
    _note(ax, 0.95, "a bar of known length L between two nests:  ‖p(q_a) − p(q_b)‖ = L", SENSOR)
    _save(fig, out, "setup-distance-bar.svg")


def setup_camera(out: Path):
    fig, ax = _canvas(ylim=(-0.4, 1.5))
    _floor(ax, -0.5, 2.4)
    flange, lens, d = _arm_to(ax, (1.25, 0.75), tool_deg=-80, tool=0.0)
    nrm = np.array([-d[1], d[0]])
    ax.add_patch(Polygon([flange - 0.06 * nrm, flange + 0.06 * nrm, flange + 0.06 * nrm + 0.1 * d,
                          flange - 0.06 * nrm + 0.1 * d], fc="#263238", ec="k", zorder=6))
    lens = flange + 0.1 * d
    bx0, bx1, by = 1.0, 1.8, 0.0
    n = 8
    for k in range(n):
        x = bx0 + k * (bx1 - bx0) / n
        ax.add_patch(Rectangle((x, by - 0.05), (bx1 - bx0) / n, 0.04, fc="k" if k % 2 else "w", ec="k", lw=0.5,
                               zorder=4))
    ax.add_patch(Polygon([lens, [bx0, by], [bx1, by]], fc=SENSOR, alpha=0.08, zorder=1))
    for x in (bx0, bx1):
        ax.plot([lens[0], x], [lens[1], by], color=SENSOR, lw=1, ls="--", zorder=2)
    _frame(ax, (bx0, by), (1, 0), (0, 1), length=0.2, color=ACCENT, fs=9)
    ax.text(lens[0] + 0.12, lens[1] + 0.02, "camera on the flange\nhand-eye X: flange → camera", fontsize=10,
            ha="left", va="center", color=SENSOR)
    ax.text(1.55, 0.35, "image corners (px)", fontsize=10, ha="left", color=SENSOR)
    _note(ax, 1.4, "checkerboard fixed in the cell: target frame (base → target)", ACCENT)
    _save(fig, out, "setup-camera.svg")


# --- (c) the data flow of calibrate ------------------------------------------------------------

FLOW = {
    "R": ("Robot model", "DHRobot, SerialChain\nnominal geometry, joint limits, error groups"),
    "P": ("Parameters and priors", "Deviations from nominal,\nParameterSpace (free set), Prior,\nidentifiability"),
    "FK": ("", "forward kinematics of the joint angles q\n(pure, batched)"),
    "M": ("Measurement model", "CableLength, Position, Pose, Markers,\nPlaneContact, ...: what the sensor reads;\n"
          "its unknowns (extras)"),
    "RES": ("", "residual = prediction − measurement\n(+ prior rows, robust loss)"),
    "MET": ("Method", "lm, gn · adamodw, adam, any optax chain ·\nga, bso, iwoa, ekf, rbfnn ·\nstages such as adamodw>lm"),
    "OUT": ("CalibrationResult", "deviations, status, history, RMSE/MEAN/MAX,\n"
            "posterior σ, diagnostics, dh_table(),\nevaluate(new data)"),
}
EDGES = (("R", "FK"), ("P", "FK"), ("FK", "M"), ("M", "RES"), ("RES", "MET"), ("MET", "OUT"))


def calibrate_flow(out: Path):
    pos = {"R": (-2.95, 7.75), "P": (2.95, 7.75), "FK": (0, 6.2), "M": (0, 4.65), "RES": (0, 3.1), "MET": (0, 1.55),
           "OUT": (0, 0.0)}
    w, h = 5.6, 1.32
    fig, ax = plt.subplots(figsize=(8.0, 6.2))
    ax.set_xlim(-5.9, 5.9)
    ax.set_ylim(-0.75, 8.5)
    ax.set_aspect("equal")
    ax.axis("off")
    for key, (title, body) in FLOW.items():
        x, y = pos[key]
        fc = "#e3f2fd" if title else "#f5f5f5"
        ax.add_patch(FancyBboxPatch((x - w / 2, y - h / 2), w, h, boxstyle="round,pad=0.02,rounding_size=0.12",
                                    fc=fc, ec=SENSOR if title else GREY, lw=1.3))
        if title:
            ax.text(x, y + h / 2 - 0.08, title, fontsize=10.5, fontweight="bold", ha="center", va="top")
            ax.text(x, y - 0.2, body, fontsize=8.5, ha="center", va="center", linespacing=1.3)
        else:
            ax.text(x, y, body, fontsize=9, ha="center", va="center", linespacing=1.3)
    for a, b in EDGES:
        (xa, ya), (xb, yb) = pos[a], pos[b]
        start = (xa if a not in ("R", "P") else xa * 0.45, ya - h / 2 - 0.02)
        _arrow(ax, start, (xb + (0 if a not in ("R", "P") else np.sign(xa) * 1.0), yb + h / 2 + 0.03), color=ARM)
    _save(fig, out, "calibrate-flow.svg")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    with plt.rc_context(RC):
        for fn in (dh_frames, calibrate_flow, setup_draw_wire, setup_tracker, setup_plane_contact,
                   setup_fixed_point, setup_distance_bar, setup_camera):
            fn(args.out)
    print(f"wrote {len(FIGURES)} figures to {args.out}")


if __name__ == "__main__":
    main()
