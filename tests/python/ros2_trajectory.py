"""The ROS 2 trajectories `skincal plan` writes, checked against the reference ROS 2 libraries.

    python3 ros2_trajectory.py check PLAN_DIR
        For every goal*.yaml of PLAN_DIR/ros2: parses it as `ros2 action send_goal` does (PyYAML's
        safe_load), checks that its keys are fields of control_msgs/action/FollowJointTrajectory's
        goal, builds its trajectory as a trajectory_msgs/msg/JointTrajectory with the rosbags
        typestore of ROS 2 Humble (the messages' real definitions) and serialises it to CDR. The
        matching joint_trajectory*.mcap must hold exactly that message (same bytes), read with the
        mcap package and decoded with the same typestore. Checks the joint names against plan.json,
        times strictly increasing, every knot on trajectory.csv's 1 kHz grid within 1e-9 rad (the
        CSV's 9 decimals) of its row and every other knot within 1e-5 rad of the line between
        its two rows. Prints one line per file.

Needs the packages of tests/python/requirements.txt (`cargo xtask test` installs them).
"""

import csv
import json
import os
import sys

import numpy as np
import yaml
from mcap.reader import make_reader
from rosbags.typesys import Stores, get_typestore

GOAL_FIELDS = {
    "trajectory",
    "multi_dof_trajectory",
    "path_tolerance",
    "goal_tolerance",
    "goal_time_tolerance",
}


def fail(message):
    print("FAIL: " + message)
    sys.exit(1)


def duration(store, value):
    if set(value) != {"sec", "nanosec"}:
        fail(f"a duration has fields {sorted(value)}, not sec and nanosec")
    return store.types["builtin_interfaces/msg/Duration"](sec=value["sec"], nanosec=value["nanosec"])


def trajectory_message(store, fields):
    Point = store.types["trajectory_msgs/msg/JointTrajectoryPoint"]
    names = set(Point.__dataclass_fields__)
    points = []
    for p in fields["points"]:
        unknown = set(p) - names
        if unknown:
            fail(f"JointTrajectoryPoint has no field {sorted(unknown)}")
        points.append(
            Point(
                positions=np.array(p.get("positions", []), dtype=np.float64),
                velocities=np.array(p.get("velocities", []), dtype=np.float64),
                accelerations=np.array(p.get("accelerations", []), dtype=np.float64),
                effort=np.array(p.get("effort", []), dtype=np.float64),
                time_from_start=duration(store, p["time_from_start"]),
            )
        )
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    return store.types["trajectory_msgs/msg/JointTrajectory"](
        header=Header(stamp=Time(sec=0, nanosec=0), frame_id=""),
        joint_names=list(fields["joint_names"]),
        points=points,
    )


def mcap_message(path):
    with open(path, "rb") as f:
        reader = make_reader(f)
        found = list(reader.iter_messages())
    if len(found) != 1:
        fail(f"{path}: {len(found)} messages, expected one trajectory")
    schema, channel, message = found[0]
    if schema.name != "trajectory_msgs/msg/JointTrajectory" or schema.encoding != "ros2msg":
        fail(f"{path}: schema {schema.name} ({schema.encoding})")
    if not channel.topic.endswith("/joint_trajectory") or channel.message_encoding != "cdr":
        fail(f"{path}: topic {channel.topic} ({channel.message_encoding})")
    return channel.topic, message.data


def csv_rows(path):
    with open(path) as f:
        rows = list(csv.reader(f))
    return rows[0][1:], {round(float(r[0]) * 1000): [float(v) for v in r[1:]] for r in rows[1:]}


def check(plan_dir):
    store = get_typestore(Stores.ROS2_HUMBLE)
    with open(os.path.join(plan_dir, "plan.json")) as f:
        plan = json.load(f)
    dofs = [d["name"] for d in plan["dofs"]]
    header, grid = csv_rows(os.path.join(plan_dir, "trajectory.csv"))
    if header != dofs:
        fail(f"trajectory.csv's columns {header} are not the plan's DoFs {dofs}")
    ros2 = os.path.join(plan_dir, "ros2")
    goals = sorted(n for n in os.listdir(ros2) if n.startswith("goal") and n.endswith(".yaml"))
    if not goals:
        fail(f"no goal*.yaml in {ros2}")
    for name in goals:
        with open(os.path.join(ros2, name)) as f:
            goal = yaml.safe_load(f)
        if not set(goal) <= GOAL_FIELDS:
            fail(f"{name}: {sorted(set(goal) - GOAL_FIELDS)} are not FollowJointTrajectory goal fields")
        duration(store, goal["goal_time_tolerance"])
        message = trajectory_message(store, goal["trajectory"])
        if list(message.joint_names) != dofs:
            fail(f"{name}: joint names {message.joint_names}, plan {dofs}")
        times = [p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in message.points]
        if not all(b > a for a, b in zip(times, times[1:])) or times[0] <= 0:
            fail(f"{name}: times not strictly increasing from above 0")
        worst, compared, between = 0.0, 0, 0.0
        for t, p in zip(times, message.points):
            if len(p.positions) != len(dofs) or len(p.velocities) != len(dofs):
                fail(f"{name}: a point at {t} s has {len(p.positions)} positions")
            ms = t * 1000
            if abs(ms - round(ms)) < 1e-6 and round(ms) in grid:
                worst = max(worst, float(np.max(np.abs(p.positions - grid[round(ms)]))))
                compared += 1
            elif int(ms) in grid and int(ms) + 1 in grid:
                # Between two rows: their straight line, which bends by ~q''·(1 ms)²/8 at most.
                u = ms - int(ms)
                line = (1 - u) * np.array(grid[int(ms)]) + u * np.array(grid[int(ms) + 1])
                between = max(between, float(np.max(np.abs(p.positions - line))))
            elif t == times[-1] and ms < max(grid) + 1.001:
                # The end, past the last row: the program ends still, at that row's pose.
                worst = max(worst, float(np.max(np.abs(p.positions - grid[max(grid)]))))
            else:
                fail(f"{name}: a knot at {t} s is outside trajectory.csv")
        if compared < 10 or worst > 1e-9 or between > 1e-5:
            fail(
                f"{name}: {compared} knots on the 1 kHz grid, largest difference {worst} rad; "
                f"{between} rad from the grid between rows"
            )
        mcap_name = name.replace("goal", "joint_trajectory").replace(".yaml", ".mcap")
        topic, data = mcap_message(os.path.join(ros2, mcap_name))
        ours = store.deserialize_cdr(data, "trajectory_msgs/msg/JointTrajectory")
        if list(ours.joint_names) != dofs or len(ours.points) != len(message.points):
            fail(f"{mcap_name}: {len(ours.points)} points for joints {ours.joint_names}")
        if bytes(store.serialize_cdr(message, "trajectory_msgs/msg/JointTrajectory")) != bytes(data):
            fail(f"{mcap_name}: its CDR is not the goal's trajectory as ROS 2 serialises it")
        print(
            f"{name}: {len(times)} knots, {times[-1]:.3f} s, {compared} on the 1 kHz grid within "
            f"{worst:.1e} rad, the others {between:.1e} rad from it; {mcap_name} on {topic}: the "
            "same message"
        )


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "check":
        check(sys.argv[2])
    else:
        print(__doc__)
        sys.exit(2)
