"""Robot models: our batched kinematics (ccl_cli.learn.robots) against Pinocchio and yourdfpy.

One JSON object per line:

* {"measure": "accuracy", "robot", "other", "postures", "max_abs_position_m", "max_abs_rotation",
  "max_abs_jacobian"}: the same URDF (``LWR4.urdf()``, ``PANDA.urdf()``: published DH tables) at
  random postures within the joint limits; Jacobians in the base frame at the frame origin
  (Pinocchio's LOCAL_WORLD_ALIGNED). yourdfpy has no Jacobian.
* {"measure": "speed", "library", "what": "fk" | "fk+jacobian", "postures_timed", "s_per_1e6"}:
  ours vectorised over all postures at once; Pinocchio one posture per call in a Python loop
  (it has no batched kinematics in Python: its parallel API covers ABA/RNEA only); yourdfpy
  one ``update_cfg`` + ``get_transform`` per posture. Loops are timed on fewer postures and
  scaled to 10⁶.
* {"measure": "parse", "library", "s"}: reading the URDF text into a model.
* {"measure": "import", "module", "s"}: ``import`` in a fresh interpreter after NumPy's (fastest of 9).

Timings are the fastest of ``--repeats`` runs (the least disturbed on a shared machine).

Each library runs from the interpreter given (scratch virtual environments):

    PYTHONPATH=. /path/to/venv_with_pin/bin/python benchmarks/bench_robots.py --with pin
    PYTHONPATH=. /path/to/venv_with_yourdfpy/bin/python benchmarks/bench_robots.py --with yourdfpy
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from functools import partial
from pathlib import Path

import numpy as np

from ccl_cli.learn.robots import LWR4, PANDA, DHRobot, parse_urdf

ROBOTS = {"lwr4+": LWR4, "panda": PANDA}


def postures(robot: DHRobot, n: int, seed: int = 0) -> np.ndarray:
    lim = np.asarray(robot.limits)
    return np.random.default_rng(seed).uniform(lim[:, 0], lim[:, 1], (n, len(lim)))


def emit(**row: object) -> None:
    print(json.dumps(row), flush=True)


def timed(fn, *args, repeats: int = 1) -> tuple[float, object]:  # noqa: ANN001
    """The fastest of ``repeats`` calls (seconds) and the last result: on a shared machine the
    minimum is the least disturbed figure."""
    best, out = float("inf"), None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn(*args)
        best = min(best, time.perf_counter() - t)
    return best, out


def pin_model(text: str, frame: str):  # noqa: ANN201
    import pinocchio as pin

    model = pin.buildModelFromXML(text)
    return pin, model, model.createData(), model.getFrameId(frame)


def pin_fk(text: str, frame: str, Q: np.ndarray, jacobian: bool
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    pin, model, data, fid = pin_model(text, frame)
    P, R = np.empty((len(Q), 3)), np.empty((len(Q), 3, 3))
    J = np.empty((len(Q), 6, Q.shape[1])) if jacobian else None
    frame = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    for i, q in enumerate(Q):  # one posture per call: Pinocchio's Python API is per configuration
        if jacobian:
            J[i] = pin.computeFrameJacobian(model, data, q, fid, frame)
            pin.updateFramePlacement(model, data, fid)
        else:
            pin.forwardKinematics(model, data, q)
            pin.updateFramePlacement(model, data, fid)
        M = data.oMf[fid]
        P[i], R[i] = M.translation, M.rotation
    return P, R, J


def yourdfpy_fk(path: str, frame: str, names: list[str], Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    import yourdfpy

    urdf = yourdfpy.URDF.load(path, build_scene_graph=True, load_meshes=False)
    P, R = np.empty((len(Q), 3)), np.empty((len(Q), 3, 3))
    for i, q in enumerate(Q):
        urdf.update_cfg(dict(zip(names, q, strict=True)))
        T = urdf.get_transform(frame, "base")
        P[i], R[i] = T[:3, 3], T[:3, :3]
    return P, R


def import_seconds(module: str, repeats: int = 9) -> float:
    """Fastest ``import numpy; import module`` minus fastest ``import numpy``, runs interleaved."""
    def run(code: str) -> float:
        t = time.perf_counter()
        subprocess.run([sys.executable, "-c", code], check=True, env={**os.environ})
        return time.perf_counter() - t

    base, full = [], []
    for _ in range(repeats):
        base.append(run("import numpy"))
        full.append(run(f"import numpy; import {module}"))
    return min(full) - min(base)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--with", dest="other", choices=["none", "pin", "yourdfpy"], default="none")
    ap.add_argument("--accuracy-postures", type=int, default=10_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--loop-postures", type=int, default=100_000, help="timed per-posture loop (pin)")
    args = ap.parse_args()

    emit(measure="import", module="ccl_cli.learn.robots", s=round(import_seconds("ccl_cli.learn.robots"), 4))
    big = 1_000_000
    for name, robot in ROBOTS.items():
        text, frame = robot.urdf(), robot.frame
        s, chain = timed(parse_urdf, text, frame)
        emit(measure="parse", library="ours", robot=name, s=round(s, 5))
        Q = postures(robot, big, seed=1)
        for what, fn in (("fk", chain.forward), ("fk+jacobian", chain.forward_jacobian)):
            s, _ = timed(fn, Q, repeats=args.repeats)
            emit(measure="speed", library="ours", robot=name, what=what, postures_timed=big,
                 s_per_1e6=round(s, 3))
        Qa = postures(robot, args.accuracy_postures, seed=2)
        pose, J = chain.forward_jacobian(Qa)
        if args.other == "pin":
            s, _ = timed(pin_model, text, frame)
            emit(measure="parse", library="pin", robot=name, s=round(s, 5))
            P, R, Jp = pin_fk(text, frame, Qa, jacobian=True)
            emit(measure="accuracy", robot=name, other="pin", postures=len(Qa),
                 max_abs_position_m=float(abs(P - pose.position).max()),
                 max_abs_rotation=float(abs(R - pose.rotation).max()),
                 max_abs_jacobian=float(abs(Jp - J).max()))
            n = args.loop_postures
            for what, jac in (("fk", False), ("fk+jacobian", True)):
                s, _ = timed(pin_fk, text, frame, Q[:n], jac, repeats=args.repeats)
                emit(measure="speed", library="pin (loop)", robot=name, what=what, postures_timed=n,
                     s_per_1e6=round(s * big / n, 3))
        if args.other == "yourdfpy":
            import yourdfpy

            with tempfile.TemporaryDirectory() as tmp:
                path = str(Path(tmp) / "robot.urdf")
                Path(path).write_text(text)
                s, _ = timed(partial(yourdfpy.URDF.load, build_scene_graph=True, load_meshes=False), path)
                emit(measure="parse", library="yourdfpy", robot=name, s=round(s, 5))
                P, R = yourdfpy_fk(path, frame, chain.joint_names, Qa)
                emit(measure="accuracy", robot=name, other="yourdfpy", postures=len(Qa),
                     max_abs_position_m=float(abs(P - pose.position).max()),
                     max_abs_rotation=float(abs(R - pose.rotation).max()), max_abs_jacobian=None)
                n = min(args.loop_postures, 10_000)
                s, _ = timed(yourdfpy_fk, path, frame, chain.joint_names, Q[:n])
                emit(measure="speed", library="yourdfpy (loop)", robot=name, what="fk", postures_timed=n,
                     s_per_1e6=round(s * big / n, 3))
    if args.other != "none":
        module = {"pin": "pinocchio", "yourdfpy": "yourdfpy"}[args.other]
        emit(measure="import", module=module, s=round(import_seconds(module), 4))
    emit(measure="load", loadavg=os.getloadavg())


if __name__ == "__main__":
    main()
