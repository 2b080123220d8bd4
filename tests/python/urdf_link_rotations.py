"""Forward kinematics of a URDF, written here from the URDF specification alone (numpy and the
standard library's XML parser), for checking the SU frames that skincal merges into a URDF.

    python3 urdf_link_rotations.py ROBOT.urdf POSES.json

POSES.json: {"joints": [names], "links": [names], "poses": [[rad per joint], ...]}. Prints
{"parents": {link: parent link}, "rotations": [[3×3 row-major per link] per pose]}, each link's
rotation in the root link's frame; joints not listed stay at 0.
"""

import json
import sys
import xml.etree.ElementTree as ET

import numpy as np


def rpy_matrix(r, p, y):
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def axis_angle(axis, angle):
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def floats(text, default):
    return [float(x) for x in text.split()] if text else default


def main():
    robot = ET.parse(sys.argv[1]).getroot()
    with open(sys.argv[2]) as f:
        request = json.load(f)
    joints = {}
    for j in robot.findall("joint"):
        origin = j.find("origin")
        xyz = floats(origin.get("xyz") if origin is not None else None, [0, 0, 0])
        rpy = floats(origin.get("rpy") if origin is not None else None, [0, 0, 0])
        axis = j.find("axis")
        joints[j.find("child").get("link")] = {
            "name": j.get("name"),
            "type": j.get("type"),
            "parent": j.find("parent").get("link"),
            "rotation": rpy_matrix(*rpy),
            "axis": floats(axis.get("xyz") if axis is not None else None, [1, 0, 0]),
        }
    column = {name: i for i, name in enumerate(request["joints"])}

    def rotation(link, q):
        if link not in joints:
            return np.eye(3)
        j = joints[link]
        r = rotation(j["parent"], q) @ j["rotation"]
        if j["type"] in ("revolute", "continuous") and j["name"] in column:
            r = r @ axis_angle(j["axis"], q[column[j["name"]]])
        return r

    out = {
        "parents": {link: joints[link]["parent"] for link in request["links"] if link in joints},
        "rotations": [
            [rotation(link, q).reshape(-1).tolist() for link in request["links"]]
            for q in request["poses"]
        ],
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
