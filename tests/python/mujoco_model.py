"""An exported model.urdf loaded by MuJoCo: one body per SU, where skincal's kinematics puts it.

    python3 mujoco_model.py check MODEL_URDF FRAMES_JSON
        FRAMES_JSON: {"dofs": [...], "poses": [[rad per DoF], ...], "sus": {name: [[x, y, z] per
        pose]}}, the SU positions skincal computes. Loads MODEL_URDF with MuJoCo's own URDF
        reader, sets each pose by joint name, and compares every SU body's position (m, in the
        root link's frame) with skincal's. Prints the largest difference.

    python3 mujoco_model.py merged URDF SUS
        URDF: a robot's own URDF with skincal's SU frames merged into it (`export-urdf --into`),
        loaded by MuJoCo as it is (meshes and all). SUS: how many SU frames were merged (links
        mounted by a fixed joint `<su>_mount`). At 5 seeded poses within the joints' limits,
        every SU body's position in MuJoCo is compared with the forward kinematics written here
        from the URDF specification.

Needs the packages of tests/python/requirements.txt (`cargo xtask test` installs them).
"""

import json
import os
import sys
import xml.etree.ElementTree as ET

import mujoco
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from urdf_link_rotations import axis_angle, floats, rpy_matrix  # noqa: E402


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


def merged(urdf, count):
    robot = ET.parse(urdf).getroot()
    joints = {}
    for j in robot.findall("joint"):
        origin = j.find("origin")
        transform = np.eye(4)
        transform[:3, 3] = floats(origin.get("xyz") if origin is not None else None, [0, 0, 0])
        transform[:3, :3] = rpy_matrix(
            *floats(origin.get("rpy") if origin is not None else None, [0, 0, 0])
        )
        axis = j.find("axis")
        limit = j.find("limit")
        joints[j.find("child").get("link")] = {
            "name": j.get("name"),
            "type": j.get("type"),
            "parent": j.find("parent").get("link"),
            "origin": transform,
            "axis": floats(axis.get("xyz") if axis is not None else None, [1, 0, 0]),
            "limits": (
                float(limit.get("lower", -np.pi)) if limit is not None else -np.pi,
                float(limit.get("upper", np.pi)) if limit is not None else np.pi,
            ),
        }
    sus = [link for link, j in joints.items() if j["name"] == link + "_mount" and j["type"] == "fixed"]
    if len(sus) != count:
        fail(f"{len(sus)} SU links mounted in {urdf}, expected {count}")
    model = mujoco.MjModel.from_xml_path(urdf)
    data = mujoco.MjData(model)
    bodies = {model.body(i).name for i in range(model.nbody)}
    missing = [s for s in sus if s not in bodies]
    if missing:
        fail(f"{len(missing)} SUs have no body in MuJoCo's model (e.g. {missing[:3]}): fused away?")
    moving = [
        j for j in joints.values() if j["type"] in ("revolute", "continuous") and j["name"] in
        {model.joint(i).name for i in range(model.njnt)}
    ]
    rng = np.random.default_rng(7)
    worst = 0.0
    for _ in range(5):
        q = {j["name"]: rng.uniform(*j["limits"]) for j in moving}

        def frame(link):
            if link not in joints:
                return np.eye(4)
            j = joints[link]
            motion = np.eye(4)
            if j["name"] in q:
                motion[:3, :3] = axis_angle(j["axis"], q[j["name"]])
            return frame(j["parent"]) @ j["origin"] @ motion

        data.qpos[:] = 0
        for name, value in q.items():
            data.qpos[model.joint(name).qposadr[0]] = value
        mujoco.mj_kinematics(model, data)
        for su in sus:
            # MuJoCo's world frame is the root link's (a URDF's root is fixed to the world).
            expected = frame(su)[:3, 3]
            worst = max(worst, float(np.max(np.abs(data.body(su).xpos - expected))))
    if worst > 1e-9:
        fail(f"an SU body is {worst:.3e} m from where the URDF puts it")
    print(f"{len(sus)} SU bodies of {model.nbody} in MuJoCo, {model.nmesh} meshes: largest difference {worst:.2e} m")


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "check":
        check(sys.argv[2], sys.argv[3])
    elif len(sys.argv) == 4 and sys.argv[1] == "merged":
        merged(sys.argv[2], int(sys.argv[3]))
    else:
        print(__doc__)
        sys.exit(2)
