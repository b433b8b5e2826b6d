"""``jaxcal export``.
"""

from __future__ import annotations

import pathlib

from ._common import _Usage


def _cmd_export(args) -> int:
    from .._calibration._io import load_result
    from .._models._urdf import export_urdf

    if not args.out and not args.dh_out:
        raise _Usage("export: give --out FILE.urdf and/or --dh-out FILE.csv")
    src = pathlib.Path(args.result)
    if not src.exists():
        raise _Usage(f"result file {args.result!r} not found")
    res = load_result(src)
    if args.out:
        export_urdf(res.robot, res.deviations, args.out)
        print(f"wrote {args.out} (calibrated {res.robot.name}, {res.robot.dof} joints)")
    if args.dh_out:
        branches = getattr(res.robot, "branches", None)
        if branches is not None:
            raise _Usage(f"--dh-out: this result's robot {res.robot.name!r} is a kinematic tree (branches "
                         f"{', '.join(b for b, _parent, _joints in branches)}): DH tables per branch are not written "
                         "yet (each calibrated joint origin is a general 6-parameter transform, which DH rows hold only "
                         "after re-choosing the joint frames); use --out FILE.urdf, which holds every corrected origin")
        if res.robot.dh_rows_deg() is None:
            raise _Usage("--dh-out: this result's robot is a generic chain, not a DH table; use --out FILE.urdf")
        from .._calibration._io import save_robot_csv

        save_robot_csv(_calibrated_dh_robot(res.robot, res.deviations), args.dh_out)
        print(f"wrote {args.dh_out} (calibrated DH table)")
    return 0


def _calibrated_dh_robot(robot, dev):
    """The DH robot with the calibrated table (nominal + deviations) and tool point."""
    import jax.numpy as jnp

    from .._models._chain import _dev_get
    from .._models._robot import DHRobot

    vals = []
    for g in ("alpha", "a", "d", "theta", "beta"):
        v = jnp.asarray(getattr(robot, g))
        dv = _dev_get(dev, g)
        vals.append(v if dv is None else v + jnp.asarray(dv))
    tool = jnp.asarray(robot.tool)
    if _dev_get(dev, "tool") is not None:
        tool = tool + jnp.asarray(_dev_get(dev, "tool"))
    return DHRobot(*vals, robot.q_min, robot.q_max, tool, convention=robot.convention,
                   beta_joints=robot.beta_joints, name=robot.name)
