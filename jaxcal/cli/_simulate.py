"""``jaxcal simulate``.
"""

from __future__ import annotations

from ._common import _robot, _robot_and_sensor, _Usage


def _cmd_simulate(args) -> int:
    import jax

    from .._datasets._dataset import Dataset
    from .._simulation._simulate import simulate_experiment

    if args.measurement == "camera":
        return _simulate_camera(args)
    robot, measurement = _robot_and_sensor(args)
    if args.samples < 2:
        raise _Usage(f"--samples must be at least 2, got {args.samples}")
    if measurement.kind in ("plane", "point", "distance"):
        from .._simulation._simulate_sensors import save_simulated_contact

        save_simulated_contact(args, robot, measurement)
        return 0
    ex = simulate_experiment(jax.random.key(args.seed), robot, n_samples=args.samples, noise_std=args.noise_std,
                             measurement=measurement, test_fraction=0.5)
    import jax.numpy as jnp

    q = jnp.concatenate([ex.train.q, ex.test.q])
    y = jnp.concatenate([ex.train.y, ex.test.y])
    from .._datasets._dataset import mm_joints_metadata

    meta = {"source": "jaxcal simulate", "robot": robot.name, "seed": args.seed, "noise_std_mm": args.noise_std,
            **mm_joints_metadata(robot)}
    if args.measurement == "cable":
        meta["anchor_mm"] = ",".join(f"{float(v):.6g}" for v in measurement.anchor)
    Dataset(q, y, measurement.kind, meta).to_csv(args.out)
    print(f"wrote {args.samples} {measurement.kind} samples of robot {robot.name} (σ = {args.noise_std} mm, "
          f"seed {args.seed}) to {args.out}")
    return 0


def _simulate_camera(args) -> int:
    """``jaxcal simulate --measurement camera``: :func:`jaxcal.simulate_camera` (a 9×6 checkerboard of
    20 mm squares, 1280×1024 px, f = 1000 px), written with the target, intrinsics and mount lines."""
    import jax
    import numpy as np

    from .._datasets._dataset import Dataset, mm_joints_metadata
    from .._sensors._camera import Camera, checkerboard
    from .._simulation._simulate_sensors import simulate_camera

    robot = _robot(args.robot, args.base, args.tip)
    if args.anchor:
        raise _Usage("--anchor applies to --measurement cable only")
    if args.samples < 3:
        raise _Usage(f"--samples (images) must be at least 3, got {args.samples}")
    if not 0.0 <= args.missing_corners < 1.0:
        raise _Usage(f"--missing-corners must be in [0, 1), got {args.missing_corners}")
    target = "checkerboard:9x6:20"
    intr = [1000.0, 1000.0, 640.0, 512.0, -0.05, 0.02, 0.0005, -0.0003, 0.0]
    cam = Camera(checkerboard(9, 6, 20.0), intr, args.mount.replace("-", "_"), image_size=(1280, 1024))
    try:
        q, y, cam, truth = simulate_camera(jax.random.key(args.seed), robot, cam, n_views=args.samples,
                                           noise_px=args.noise_std, missing=args.missing_corners)
    except ValueError as e:
        raise _Usage(str(e)) from None
    n_masked = int(np.isnan(np.asarray(y)).any(axis=-1).sum())
    meta = {"source": "jaxcal simulate", "robot": robot.name, "seed": args.seed, "noise_std_px": args.noise_std,
            "target": target, "camera_intrinsics": ",".join(repr(v) for v in intr), "mount": cam.mount,
            "image_size_px": "1280,1024", **mm_joints_metadata(robot)}
    Dataset(q, y, "camera", meta).to_csv(args.out)
    print(f"wrote {args.samples} camera images ({cam.mount}, {cam.n_points} target points, {n_masked} corner(s) "
          f"left undetected) of robot {robot.name} (σ = {args.noise_std} px, seed {args.seed}) to {args.out}")
    return 0
