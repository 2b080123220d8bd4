"""An exported model.urdf loaded by MuJoCo: one body per SU, where skincal's kinematics puts it.

    python3 mujoco_model.py check MODEL_URDF FRAMES_JSON
        FRAMES_JSON: {"dofs": [...], "poses": [[rad per DoF], ...], "sus": {name: [[x, y, z] per
        pose]}}, the SU positions skincal computes. Loads MODEL_URDF with MuJoCo's own URDF
        reader, sets each pose by joint name, and compares every SU body's position (m, in the
        root link's frame) with skincal's. Prints the largest difference.

Needs the packages of tests/python/requirements.txt (`cargo xtask test` installs them).
"""

import json
import sys

import mujoco
import numpy as np


def fail(message):
    print("FAIL: " + message)
    sys.exit(1)


def check(urdf, frames_path):
    with open(frames_path) as f:
        frames = json.load(f)
    model = mujoco.MjModel.from_xml_path(urdf)
    data = mujoco.MjData(model)
    bodies = {model.body(i).name for i in range(model.nbody)}
    missing = [s for s in frames["sus"] if s not in bodies]
    if missing:
        fail(f"{len(missing)} SUs have no body in MuJoCo's model (e.g. {missing[:3]}): fused away?")
    address = [model.joint(name).qposadr[0] for name in frames["dofs"]]
    worst = 0.0
    for k, q in enumerate(frames["poses"]):
        data.qpos[:] = 0
        data.qpos[address] = q
        mujoco.mj_kinematics(model, data)
        for su, positions in frames["sus"].items():
            worst = max(worst, float(np.max(np.abs(data.body(su).xpos - positions[k]))))
    if worst > 1e-9:
        fail(f"an SU body is {worst:.3e} m from where skincal puts it")
    print(f"{len(frames['sus'])} SU bodies at {len(frames['poses'])} poses: largest difference {worst:.2e} m")


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "check":
        check(sys.argv[2], sys.argv[3])
    else:
        print(__doc__)
        sys.exit(2)
