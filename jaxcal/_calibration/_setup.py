"""The sensor extras a calibration of measured data estimates by default, per kind of data.

:func:`jaxcal.calibrate` estimates the extras it is given (``extras=``); a data file of a given
kind cannot do without some: a distance bar or contact data never fix the tool point, a
draw-wire file without a known anchor needs the anchor and the wire's zero offset, marker data
need the motion-capture frame. :func:`measured_extras` adds those to the ones asked for and says
why in one note each (``jaxcal calibrate`` prints the notes).
"""

from __future__ import annotations

__all__ = ["measured_extras"]


def measured_extras(kind: str, estimate=(), *, anchor_known: bool = True, sessions: bool = False,
                    sphere: bool = False, estimate_radius: bool = False,
                    radius_mm: float | None = None) -> tuple[set[str], list[str]]:
    """``(extras, notes)``: the extras to estimate for ``kind`` data (``"cable"``, ``"position"``,
    ``"pose"``, ``"markers"``, ``"camera"``, ``"plane"``, ``"point"``, ``"distance"``) — those in
    ``estimate`` (names as ``jaxcal calibrate --estimate`` takes them: ``anchor``, ``offset``,
    ``tool``, ``base``) and the ones the data need — and one note per default added.

    Args:
        kind: the data's measurement kind.
        estimate: the extras asked for (already checked against ``kind``).
        anchor_known: cable data: the anchor is known (given, or the file's ``anchor_mm`` line);
            otherwise the anchor and the cable offset are estimated.
        sessions: marker data of several sessions (every session frame is estimated anyway).
        sphere, estimate_radius, radius_mm: point data as spheres (a ball touching fixed
            spheres): the radius estimated, or known (``radius_mm``); only for the notes.
    """
    from .._sensors._contact import length_reference_note

    estimate = set(estimate)
    notes: list[str] = []
    if kind == "distance" and "tool" not in estimate:
        estimate.add("tool")
        notes.append("distance data: the tool point is estimated (from its nominal value); distances never see "
                     "the robot's base frame (d_1, theta_1 and the base's position and orientation stay at "
                     "nominal or are set by the prior)")
    if sphere:
        notes.append("point data as spheres: residual = distance to the centre minus the radius, "
                     + ("radius unknown: estimated per point (sphere fit to the data, then the joint fit)"
                        if estimate_radius else f"radius {radius_mm:g} mm (known)"))
    if kind in ("plane", "point") and "tool" not in estimate:
        estimate.add("tool")
        notes.append(f"{kind} data: the {kind}s and the tool point are estimated "
                     "(closed-form start from the data, then the joint fit); "
                     + length_reference_note(kind, known_radius=sphere and not estimate_radius))
    if kind == "cable" and not anchor_known:
        # nothing known about the anchor: estimate it (and the cable offset) from the data
        estimate |= {"anchor", "offset"}
        notes.append("no --anchor given and none in the file: the anchor and the cable offset are estimated "
                     "from the data (multilateration on the nominal robot, then the joint fit)")
    if kind == "markers" and "base" not in estimate and not sessions:  # sessions: every frame is estimated
        estimate.add("base")
        notes.append("marker data: the motion-capture frame (base extras) and the marker positions on the flange "
                     "are estimated (closed-form Kabsch start from the data, then the joint fit)")
    return estimate, notes
