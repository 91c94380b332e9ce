#!/usr/bin/env python3
"""Peer benchmark: fit a kinematic calibration with pybotics (public code) + SciPy.

Reads a JSON job written by `examples/ident_pybotics.rs`:
  {"mdh": [[alpha, a, theta, d], ...]   nominal MDH table (rad, mm), pybotics convention
                                         Rx(alpha) Tx(a) Rz(theta + q) Tz(d),
   "world": 4x4, "tool": 4x4            start values (robocal's closed-form nominal fit),
   "chain_mask": [bool] * 4n, "world_mask": [bool] * 6, "tool_mask": [bool] * 6,
   "train_q": [[rad] * n], "train_p": [[mm] * 3], "heldout_q": [[rad] * n],
   "check_p": [[mm] * 3]                 robocal's nominal predictions of train_q (convention check)}
and writes a JSON result to the path given as the second argument.

The fit is pybotics' own accuracy optimisation (`OptimizationHandler` + `optimize_accuracy`,
per-pose position-error norms) minimised with `scipy.optimize.least_squares`, as in
pybotics' calibration example. Usage: pybotics_fit.py JOB.json OUT.json
"""
import json
import sys
import time

import numpy as np
from scipy.optimize import least_squares

from pybotics.kinematic_chain import MDHKinematicChain
from pybotics.optimization import OptimizationHandler, compute_absolute_errors, optimize_accuracy
from pybotics.robot import Robot
from pybotics.tool import Tool


def main() -> None:
    job = json.load(open(sys.argv[1]))
    mdh = np.array(job["mdh"], dtype=float)
    robot = Robot(MDHKinematicChain.from_parameters(mdh), tool=Tool(matrix=np.array(job["tool"], dtype=float)))
    robot.world_frame = np.array(job["world"], dtype=float)
    robot.joint_limits = np.array([[-10.0] * len(mdh), [10.0] * len(mdh)])
    train_q = np.array(job["train_q"], dtype=float)
    train_p = np.array(job["train_p"], dtype=float)
    held_q = np.array(job["heldout_q"], dtype=float)
    check_p = np.array(job["check_p"], dtype=float)

    # Convention check: pybotics FK of the start model must equal robocal's prediction.
    start = np.array([robot.fk(q)[:3, 3] for q in train_q])
    check_max = float(np.max(np.linalg.norm(start - check_p, axis=1)))

    handler = OptimizationHandler(
        robot=robot,
        kinematic_chain_mask=job["chain_mask"],
        tool_mask=job["tool_mask"],
        world_mask=job["world_mask"],
    )
    x0 = handler.generate_optimization_vector()
    t0 = time.perf_counter()
    res = least_squares(
        fun=optimize_accuracy,
        x0=x0,
        args=(handler, train_q, train_p),
        method="lm",
        x_scale="jac",
    )
    fit_s = time.perf_counter() - t0
    handler.apply_optimization_vector(res.x)
    train_err = compute_absolute_errors(qs=train_q, positions=train_p, robot=handler.robot)
    held = [handler.robot.fk(q)[:3, 3].tolist() for q in held_q]
    out = {
        "fit_seconds": fit_s,
        "nfev": int(res.nfev),
        "n_params": int(len(x0)),
        "status": int(res.status),
        "message": str(res.message),
        "train_rms_mm": float(np.sqrt(np.mean(train_err**2))),
        "convention_check_max_mm": check_max,
        "heldout_pred": held,
    }
    json.dump(out, open(sys.argv[2], "w"))


if __name__ == "__main__":
    main()
