"""A plan's poses and motion checked for self-collision by MuJoCo, independently of skincal.

    python3 collision_check.py PLAN_DIR URDF DESCRIPTIONS
        Loads URDF in MuJoCo (its package://example-robot-data/robots/ meshes taken from the
        folder DESCRIPTIONS; links kept as bodies, visual geometry dropped, meshes collided as
        their convex hulls, as MuJoCo does), then sets every row of PLAN_DIR/trajectory.csv (the
        planned motion) and every training pose of plan.json, and runs MuJoCo's collision
        detection. A contact (MuJoCo reports geoms that overlap) between two links fails the
        check unless plan.json's collision check lists the pair as not checked (adjacent links,
        pairs the SRDF disables) or as touching at the rest pose, where it fails only if the
        links overlap deeper than at rest by more than the slack allowed (5 mm, and 2 mm on the paths
        between poses) and 1 mm for
        the two engines' difference. Prints the number of poses checked and the deepest
        overlap of each kind of pair.

Needs the packages of tests/python/requirements.txt (`cargo xtask test` installs them).
"""

import csv
import json
import os
import re
import sys

import mujoco

# skincal's slack for pairs that touch at rest and its grace on paths between poses, m.
SLACK = 0.005 + 0.002
TOLERANCE = 0.001


def fail(message):
    print("FAIL: " + message)
    sys.exit(1)


def load(urdf, descriptions):
    with open(urdf) as f:
        text = f.read()
    text = text.replace(
        "package://example-robot-data/robots/", os.path.abspath(descriptions) + "/"
    ).replace('filename="file://', 'filename="')
    # MuJoCo needs mass on every moving link; a description without inertials gets a small one.
    text = re.sub(
        r"<link name=\"([^\"]+)\"\s*/>",
        r'<link name="\1"><inertial><mass value="0.01"/><inertia ixx="1e-5" ixy="0" ixz="0" '
        r'iyy="1e-5" iyz="0" izz="1e-5"/></inertial></link>',
        text,
    )
    block = (
        '<mujoco><compiler fusestatic="false" discardvisual="true" strippath="false" '
        'balanceinertia="true" boundmass="1e-4" boundinertia="1e-8"/></mujoco>'
    )
    text = re.sub(r"(<robot[^>]*>)", r"\1" + block, text, count=1)
    return mujoco.MjModel.from_xml_string(text)


def check(plan_dir, urdf, descriptions):
    with open(os.path.join(plan_dir, "plan.json")) as f:
        plan = json.load(f)
    collision = plan.get("collision")
    if collision is None:
        fail("plan.json has no collision check: was the plan made with the URDF?")
    not_checked = {frozenset(p) for p in collision["not_checked"]}
    at_rest = {frozenset((a, b)): d for a, b, d in collision["touching_at_rest"]}
    model = load(urdf, descriptions)
    data = mujoco.MjData(model)
    dofs = [d["name"] for d in plan["dofs"]]
    address = {}
    for name in dofs:
        joint = model.joint(name)
        address[name] = joint.qposadr[0]
    poses = []
    with open(os.path.join(plan_dir, "trajectory.csv")) as f:
        rows = csv.reader(f)
        header = next(rows)[1:]
        if header != dofs:
            fail(f"trajectory.csv's columns {header} are not the plan's DoFs")
        poses.extend([float(v) for v in r[1:]] for r in rows)
    training = [p["to"] for p in plan["phases"] if p["part"] == "training" and p["action"] == "transfer"]
    poses.extend(training)
    deepest = {"checked": 0.0, "touching at rest": 0.0}
    for q in poses:
        data.qpos[:] = 0
        for name, value in zip(dofs, q):
            data.qpos[address[name]] = value
        mujoco.mj_forward(model, data)
        for c in data.contact[: data.ncon]:
            a = model.body(model.geom_bodyid[c.geom1]).name
            b = model.body(model.geom_bodyid[c.geom2]).name
            pair = frozenset((a, b))
            if pair in not_checked or a == b:
                continue
            if pair in at_rest:
                deepest["touching at rest"] = min(deepest["touching at rest"], c.dist - at_rest[pair])
                if c.dist < at_rest[pair] - SLACK - TOLERANCE:
                    fail(f"{a} and {b} overlap {-c.dist * 1e3:.1f} mm, at rest {-at_rest[pair] * 1e3:.1f} mm")
                continue
            deepest["checked"] = min(deepest["checked"], c.dist)
            if c.dist < -TOLERANCE:
                fail(f"{a} and {b} overlap {-c.dist * 1e3:.1f} mm at a planned pose")
    print(
        f"{len(poses)} poses ({len(training)} training poses), {model.ngeom} geoms: deepest overlap "
        f"of checked pairs {-deepest['checked'] * 1e3:.2f} mm, of pairs touching at rest "
        f"{-deepest['touching at rest'] * 1e3:.2f} mm beyond their rest overlap"
    )


if __name__ == "__main__":
    if len(sys.argv) == 4:
        check(*sys.argv[1:])
    else:
        print(__doc__)
        sys.exit(2)
