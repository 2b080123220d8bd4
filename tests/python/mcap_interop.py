"""Interoperability of skincal's ROS 2 MCAP logs with the reference Python implementation.

    python3 mcap_interop.py check LOG.mcap PLAN.json
        Decodes the first /skin/imu and /joint_states messages with mcap-ros2-support and checks
        them against the plan (an independent source: the commanded first pose) and physics.
    python3 mcap_interop.py convert CSV_DIR OUT.mcap
        Writes the CSV log (joint_states.csv, imu.csv) as a ROS 2 MCAP with the Python writer,
        for skincal to ingest.

Needs the packages of tests/python/requirements.txt (`cargo xtask test` installs them).
"""

import csv
import json
import math
import sys

from mcap_ros2.reader import read_ros2_messages
from mcap_ros2.writer import Writer

SEP = "=" * 80 + "\n"
HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"
TIME = "int32 sec\nuint32 nanosec\n"
JOINT_STATE = (
    "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n"
    "float64[] effort\n" + SEP + "MSG: std_msgs/Header\n" + HEADER + SEP
    + "MSG: builtin_interfaces/Time\n" + TIME
)
IMU = (
    "std_msgs/Header header\ngeometry_msgs/Quaternion orientation\n"
    "float64[9] orientation_covariance\ngeometry_msgs/Vector3 angular_velocity\n"
    "float64[9] angular_velocity_covariance\ngeometry_msgs/Vector3 linear_acceleration\n"
    "float64[9] linear_acceleration_covariance\n" + SEP + "MSG: std_msgs/Header\n" + HEADER
    + SEP + "MSG: builtin_interfaces/Time\n" + TIME + SEP
    + "MSG: geometry_msgs/Quaternion\nfloat64 x\nfloat64 y\nfloat64 z\nfloat64 w\n" + SEP
    + "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n"
)


def fail(message):
    print("FAIL: " + message)
    sys.exit(1)


def check(log, plan_path):
    with open(plan_path) as f:
        plan = json.load(f)
    dofs = [d["name"] for d in plan["dofs"]]
    first_pose = plan["phases"][0]["from"]
    joint = imu = None
    for m in read_ros2_messages(log):
        if m.channel.topic == "/joint_states" and joint is None:
            joint = m
        elif m.channel.topic == "/skin/imu" and imu is None:
            imu = m
        if joint is not None and imu is not None:
            break
    if joint is None or imu is None:
        fail("no /joint_states or no /skin/imu message")
    if joint.schema.name != "sensor_msgs/msg/JointState" or imu.schema.name != "sensor_msgs/msg/Imu":
        fail(f"schemas {joint.schema.name}, {imu.schema.name}")
    j = joint.ros_msg
    if list(j.name) != dofs:
        fail(f"joint names {list(j.name)} != plan DoFs {dofs}")
    for name, got, want in zip(dofs, j.position, first_pose):
        if abs(got - want) > 1e-9:
            fail(f"{name}: position {got} != planned {want}")
    i = imu.ros_msg
    if not i.header.frame_id:
        fail("empty frame_id")
    if i.orientation_covariance[0] != -1.0:
        fail(f"orientation_covariance[0] = {i.orientation_covariance[0]}, expected -1 (unknown)")
    a = i.linear_acceleration
    norm = math.sqrt(a.x * a.x + a.y * a.y + a.z * a.z)
    # At rest an accelerometer reads 1 g (plus at most ±0.01 g of noise per axis).
    if abs(norm - 9.81) > 0.2:
        fail(f"|linear_acceleration| = {norm} m/s² at rest, expected 9.81")
    stamp = i.header.stamp.sec + i.header.stamp.nanosec * 1e-9
    jstamp = j.header.stamp.sec + j.header.stamp.nanosec * 1e-9
    if abs(stamp - jstamp) > 1e-3 or imu.log_time_ns <= 0:
        fail(f"stamps {stamp} and {jstamp} should be the same first sample")
    print(f"ok: {j.name[0]}={j.position[0]:.6f} rad, {i.header.frame_id} |a|={norm:.4f} m/s², "
          f"stamp {stamp:.3f}")


def convert(directory, out):
    with open(out, "wb") as f:
        writer = Writer(output=f)
        js = writer.register_msgdef("sensor_msgs/msg/JointState", JOINT_STATE)
        imu = writer.register_msgdef("sensor_msgs/msg/Imu", IMU)

        def stamp(text):
            ns = round(float(text) * 1e9)
            return ns, {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}

        with open(f"{directory}/joint_states.csv") as jf, open(f"{directory}/imu.csv") as sf:
            joints = csv.reader(jf)
            names = next(joints)[1:]
            skin = csv.reader(sf)
            next(skin)
            pending = next(skin, None)
            for row in joints:
                ns, t = stamp(row[0])
                writer.write_message(
                    "/joint_states", js,
                    {"header": {"stamp": t, "frame_id": ""}, "name": names,
                     "position": [float(v) for v in row[1:]], "velocity": [], "effort": []},
                    log_time=ns, publish_time=ns)
                # The skin samples up to this joint state's time.
                while pending is not None and float(pending[0]) <= float(row[0]) + 1e-9:
                    sns, st = stamp(pending[0])
                    writer.write_message(
                        "/skin/imu", imu,
                        {"header": {"stamp": st, "frame_id": pending[1]},
                         "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
                         "orientation_covariance": [-1.0] + [0.0] * 8,
                         "angular_velocity": {"x": 0.0, "y": 0.0, "z": 0.0},
                         "angular_velocity_covariance": [-1.0] + [0.0] * 8,
                         "linear_acceleration": {"x": float(pending[2]), "y": float(pending[3]),
                                                 "z": float(pending[4])},
                         "linear_acceleration_covariance": [0.0] * 9},
                        log_time=sns, publish_time=sns)
                    pending = next(skin, None)
        writer.finish()
    print(f"ok: wrote {out}")


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "check":
        check(sys.argv[2], sys.argv[3])
    elif len(sys.argv) == 4 and sys.argv[1] == "convert":
        convert(sys.argv[2], sys.argv[3])
    else:
        print(__doc__)
        sys.exit(2)
