"""ROS 1 bags from a CSV log, written by the rosbags package (an independent implementation of
the ROS 1 bag format and serialization), for skincal to ingest.

    python3 ros1_bag.py CSV_DIR OUT.bag[:none|bz2|lz4] [OUT.bag[:COMPRESSION] ...]

Each bag holds the whole log, its chunks compressed as its suffix says (none by default); the
messages are serialized once for all of them.

Joint states go to /joint_states as sensor_msgs/JointState, skin samples to /skin/imu as
sensor_msgs/Imu (one message per SU sample), stamped as in the CSV.

Needs the packages of tests/python/requirements.txt (`cargo xtask test` installs them).
"""

import argparse
import csv

import numpy as np
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_typestore


def stamp(typestore, text):
    # Whole nanoseconds from the decimal text, not through a float.
    whole, _, fraction = text.partition(".")
    nanos = int((fraction + "000000000")[:9])
    return typestore.types["builtin_interfaces/msg/Time"](sec=int(whole), nanosec=nanos)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("csv_dir")
    parser.add_argument("bags", nargs="+", metavar="OUT.bag[:COMPRESSION]")
    args = parser.parse_args()
    bags = []
    for bag in args.bags:
        path, _, compression = bag.rpartition(":")
        if compression not in ("none", "bz2", "lz4"):
            path, compression = bag, "none"
        bags.append((path, compression))
    ts = get_typestore(Stores.ROS1_NOETIC)
    Header = ts.types["std_msgs/msg/Header"]
    JointState = ts.types["sensor_msgs/msg/JointState"]
    Imu = ts.types["sensor_msgs/msg/Imu"]
    Quaternion = ts.types["geometry_msgs/msg/Quaternion"]
    Vector3 = ts.types["geometry_msgs/msg/Vector3"]
    rows = []
    with open(f"{args.csv_dir}/joint_states.csv") as f:
        reader = csv.reader(f)
        names = next(reader)[1:]
        for seq, row in enumerate(reader):
            t = stamp(ts, row[0])
            msg = JointState(
                header=Header(seq=seq, stamp=t, frame_id=""),
                name=names,
                position=np.array([float(x) for x in row[1:]]),
                velocity=np.array([], dtype=float),
                effort=np.array([], dtype=float),
            )
            rows.append((t.sec * 10**9 + t.nanosec, 0, ts.serialize_ros1(msg, JointState.__msgtype__)))
    unknown = np.full(9, 0.0)
    unknown[0] = -1.0
    with open(f"{args.csv_dir}/imu.csv") as f:
        reader = csv.reader(f)
        next(reader)
        for seq, row in enumerate(reader):
            t = stamp(ts, row[0])
            msg = Imu(
                header=Header(seq=seq, stamp=t, frame_id=row[1]),
                orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=unknown,
                angular_velocity=Vector3(x=0.0, y=0.0, z=0.0),
                angular_velocity_covariance=unknown,
                linear_acceleration=Vector3(x=float(row[2]), y=float(row[3]), z=float(row[4])),
                linear_acceleration_covariance=np.zeros(9),
            )
            rows.append((t.sec * 10**9 + t.nanosec, 1, ts.serialize_ros1(msg, Imu.__msgtype__)))
    # In time order, joint states first at equal stamps, as a recorder would see them.
    rows.sort(key=lambda r: (r[0], r[1]))
    for path, compression in bags:
        writer = Writer(path)
        if compression != "none":
            writer.set_compression(getattr(Writer.CompressionFormat, compression.upper()))
        with writer:
            connections = [
                writer.add_connection("/joint_states", JointState.__msgtype__, typestore=ts),
                writer.add_connection("/skin/imu", Imu.__msgtype__, typestore=ts),
            ]
            for time, topic, data in rows:
                writer.write(connections[topic], time, data)


if __name__ == "__main__":
    main()
