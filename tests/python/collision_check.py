"""A plan's poses and motion checked for self-collision by MuJoCo, independently of skincal.

    python3 collision_check.py PLAN_DIR URDF DESCRIPTIONS
        Loads URDF in MuJoCo (its package://example-robot-data/robots/ meshes taken from the
        folder DESCRIPTIONS; links kept as bodies, visual geometry dropped, meshes collided as
        their convex hulls, as MuJoCo does; Collada meshes, which MuJoCo does not read, converted
        to STL here from the Collada specification, their <up_axis> applied), then sets every row of PLAN_DIR/trajectory.csv (the
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
import struct
import sys
import tempfile
import xml.etree.ElementTree as ET

import mujoco
import numpy as np

# skincal's slack for pairs that touch at rest and its grace on paths between poses, m.
SLACK = 0.005 + 0.002
TOLERANCE = 0.001


def fail(message):
    print("FAIL: " + message)
    sys.exit(1)


# Collada's <up_axis> as a rotation onto Z up (COLLADA 1.4.1 specification, 5-112: Y_UP is the
# default of many tools; X_UP and Y_UP are turned so that their up direction becomes +Z).
UP_AXIS = {
    "Z_UP": np.eye(3),
    "Y_UP": np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]]),
    "X_UP": np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]]),
}


def collada_to_stl(dae, stl):
    """Every triangle of the Collada file's geometries (polylists, triangles, polygons, fanned),
    in metres along its <unit>, Z up, written as binary STL. Refuses scene transforms, which the
    robots checked here do not use."""
    ns = {"c": "http://www.collada.org/2005/11/COLLADASchema"}
    root = ET.parse(dae).getroot()
    up = root.findtext("c:asset/c:up_axis", "Y_UP", ns).strip()
    unit = root.find("c:asset/c:unit", ns)
    scale = float(unit.get("meter", "1")) if unit is not None else 1.0
    for tag in ("matrix", "translate", "rotate", "scale", "instance_node"):
        if root.find(f".//c:library_visual_scenes//c:{tag}", ns) is not None:
            fail(f"{dae}: a <{tag}> in the scene, which this converter does not apply")
    triangles = []
    for mesh in root.findall("c:library_geometries/c:geometry/c:mesh", ns):
        vertices = mesh.find("c:vertices", ns)
        position = vertices.find("c:input[@semantic='POSITION']", ns).get("source")[1:]
        source = mesh.find(f"c:source[@id='{position}']", ns)
        points = np.array(source.findtext("c:float_array", "", ns).split(), float).reshape(-1, 3)
        points = points * scale @ UP_AXIS[up].T
        for kind in ("triangles", "polylist", "polygons"):
            for prims in mesh.findall(f"c:{kind}", ns):
                inputs = prims.findall("c:input", ns)
                stride = max(int(i.get("offset", 0)) for i in inputs) + 1
                offset = int(next(i for i in inputs if i.get("semantic") == "VERTEX").get("offset", 0))
                blocks = [prims.findtext("c:p", "", ns)] if kind != "polygons" else [
                    p.text or "" for p in prims.findall("c:p", ns)
                ]
                for block in blocks:
                    index = np.array(block.split(), int)[offset::stride]
                    if kind == "triangles":
                        counts = [3] * (len(index) // 3)
                    elif kind == "polylist":
                        counts = [int(v) for v in prims.findtext("c:vcount", "", ns).split()]
                    else:
                        counts = [len(index)]
                    at = 0
                    for n in counts:
                        polygon = index[at : at + n]
                        at += n
                        for k in range(1, n - 1):
                            triangles.append(points[[polygon[0], polygon[k], polygon[k + 1]]])
    if not triangles:
        fail(f"{dae}: no triangles")
    with open(stl, "wb") as f:
        f.write(b"\0" * 80 + struct.pack("<I", len(triangles)))
        for t in triangles:
            f.write(struct.pack("<12fH", 0, 0, 0, *t.ravel(), 0))


def load(urdf, descriptions):
    with open(urdf) as f:
        text = f.read()
    text = text.replace(
        "package://example-robot-data/robots/", os.path.abspath(descriptions) + "/"
    ).replace('filename="file://', 'filename="')
    # Visual geometry is not collided; Collada collision meshes become STL files.
    text = re.sub(r"<visual>.*?</visual>", "", text, flags=re.S)
    # The STL files are read when the model is built and removed with the scratch folder.
    with tempfile.TemporaryDirectory(prefix="collision_check_") as scratch:
        return build(text, scratch)


def build(text, scratch):
    def converted(match):
        dae = match.group(1)
        stl = os.path.join(scratch, f"{len(os.listdir(scratch))}.stl")
        collada_to_stl(dae, stl)
        return f'filename="{stl}"'
    text = re.sub(r'filename="([^"]+\.dae)"', converted, text, flags=re.I)
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
    # What each pair of bodies is to the check: not checked (0: the same body, or a pair plan.json
    # lists), touching at rest (1: by how much, `rest`) or checked (2).
    body_names = [model.body(b).name for b in range(model.nbody)]
    kind = np.full((model.nbody, model.nbody), 2)
    rest = np.zeros((model.nbody, model.nbody))
    for a, name_a in enumerate(body_names):
        for b, name_b in enumerate(body_names):
            pair = frozenset((name_a, name_b))
            if a == b or pair in not_checked:
                kind[a, b] = 0
            elif pair in at_rest:
                kind[a, b] = 1
                rest[a, b] = at_rest[pair]
    deepest = {"checked": 0.0, "touching at rest": 0.0}
    for q in poses:
        data.qpos[:] = 0
        for name, value in zip(dofs, q):
            data.qpos[address[name]] = value
        # Positions and contacts only: no dynamics.
        mujoco.mj_kinematics(model, data)
        mujoco.mj_collision(model, data)
        if data.ncon == 0:
            continue
        a = model.geom_bodyid[data.contact.geom1]
        b = model.geom_bodyid[data.contact.geom2]
        dist = data.contact.dist
        pairs = kind[a, b]
        touching = pairs == 1
        if touching.any():
            beyond = dist[touching] - rest[a, b][touching]
            worst = int(np.argmin(beyond))
            deepest["touching at rest"] = min(deepest["touching at rest"], float(beyond[worst]))
            if beyond[worst] < -SLACK - TOLERANCE:
                i = np.flatnonzero(touching)[worst]
                fail(
                    f"{body_names[a[i]]} and {body_names[b[i]]} overlap {-dist[i] * 1e3:.1f} mm, "
                    f"at rest {-rest[a[i], b[i]] * 1e3:.1f} mm"
                )
        checked = pairs == 2
        if checked.any():
            i = np.flatnonzero(checked)[int(np.argmin(dist[checked]))]
            deepest["checked"] = min(deepest["checked"], float(dist[i]))
            if dist[i] < -TOLERANCE:
                fail(f"{body_names[a[i]]} and {body_names[b[i]]} overlap {-dist[i] * 1e3:.1f} mm at a planned pose")
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
