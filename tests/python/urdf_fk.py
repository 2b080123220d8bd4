"""Forward kinematics of a URDF by MuJoCo, against poses skincal computed.

    python3 urdf_fk.py ROBOT.urdf POSES.json

POSES.json: {"dofs": [names], "cases": [{"q": [rad per DoF], "links": {name: [x, y, z, qw, qx,
qy, qz]}}]} with each link's pose in the root link's frame. Loads the URDF with MuJoCo, sets the
joints and prints the largest position (m) and rotation (rad) difference over every case and link
that MuJoCo keeps as a body (it fuses links on fixed joints into their parent).

Needs the packages of tests/python/requirements.txt (`cargo xtask test` installs them).
"""

import json
import sys

import mujoco
import numpy as np


def main():
    model = mujoco.MjModel.from_xml_path(sys.argv[1])
    data = mujoco.MjData(model)
    with open(sys.argv[2]) as f:
        poses = json.load(f)
    qadr = [model.jnt_qposadr[model.joint(n).id] for n in poses["dofs"]]
    worst_position = worst_rotation = 0.0
    compared = 0
    for case in poses["cases"]:
        data.qpos[qadr] = case["q"]
        mujoco.mj_kinematics(model, data)
        for name, pose in case["links"].items():
            try:
                body = model.body(name).id
            except KeyError:
                continue
            worst_position = max(worst_position, float(np.abs(data.xpos[body] - pose[:3]).max()))
            # The angle of the rotation between the two (q and −q are the same rotation).
            relative = np.zeros(4)
            conjugate = np.array(pose[3:]) * [1.0, -1.0, -1.0, -1.0]
            mujoco.mju_mulQuat(relative, data.xquat[body], conjugate)
            angle = 2.0 * np.arctan2(np.linalg.norm(relative[1:]), abs(relative[0]))
            worst_rotation = max(worst_rotation, float(angle))
            compared += 1
    print(json.dumps({"compared": compared, "position": worst_position, "rotation": worst_rotation}))


if __name__ == "__main__":
    main()
