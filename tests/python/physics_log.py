"""A robot log from an independent rigid-body physics simulation (MuJoCo), for skincal to ingest.

    python3 physics_log.py ROBOT.json PLAN.json OUT_DIR [options]

ROBOT.json is a skincal robot description (the `robot` of a truth file: DH or axis placements of
the DoFs, DH+2 or origin placements of the SUs); PLAN.json a plan written by `skincal plan`. The robot is
built as a MuJoCo model with mass (capsule links of aluminium tube), motor armature and one
position servo per DoF (MuJoCo's position actuator, a PD loop without feed-forward; 6 Hz bandwidth
and damping 0.8 at the first pose by default, or at the largest inertia over the plan's poses), so moving one DoF deflects the others and every stop rings. The servos follow the
plan's poses with a protocol of their own, not the plan's timing:

- moves and transfers: quintic profiles over the plan's durations;
- holds: the plan's, except the pause after each pattern (`--pause`, 0.5 s);
- excitations: the paper's pattern (eq. 10) *without a window*, one period from rest, so the
  commanded acceleration steps at both ends (on every DoF excited together, when the plan runs
  limbs in parallel); run backwards where forwards would leave the DoF's range (the plan's limits),
  or, with `--away-from-nearer-limit`, wherever the pose is nearer the upper limit.

Prismatic DoFs (`"kind": "prismatic"`) are slide joints, run through the pattern scaled by 0.1 m
per rad as skincal's plans do. Every SU is a site whose specific force (the second difference of its position over the integrator's
substeps, minus gravity, in the site frame) is recorded with Gaussian noise and the quantisation of a
10-bit ±2 g part. The integrator is MuJoCo's implicitfast (the servos' damping taken implicitly):
its trajectory's acceleration is not the forward dynamics' qacc that MuJoCo's own accelerometer
reads, so the skin is read from the trajectory itself, whatever the integrator;
joint positions are read through 17-bit encoders.
Writes OUT_DIR/joint_states.csv and OUT_DIR/imu.csv (skincal's CSV log) at 1 kHz; with `--raw`,
the same samples as little-endian doubles instead (OUT_DIR/raw.json names the DoFs and SUs and
gives the first stamp, the period and the count; OUT_DIR/joint_states.f64 holds each sample's
joint positions, OUT_DIR/imu.f64 each sample's SUs' x, y, z), for a caller that writes the log
itself: formatting the CSV takes Python longer than the simulation.

Needs the packages of tests/python/requirements.txt (`cargo xtask test` installs them).
"""

import argparse
import json
import math
import os
import sys

import mujoco
from mujoco import rollout
import numpy as np


def rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def transform(rotation=None, translation=(0.0, 0.0, 0.0)):
    t = np.eye(4)
    if rotation is not None:
        t[:3, :3] = rotation
    t[:3, 3] = translation
    return t


def dh(row):
    """Standard DH: Rz(theta0) Tz(d) Tx(a) Rx(alpha), then Rz(theta_acc) Tz(d_acc) for an SU."""
    t = (
        transform(rot_z(row["theta0"]))
        @ transform(translation=(0.0, 0.0, row["d"]))
        @ transform(translation=(row["a"], 0.0, 0.0))
        @ transform(rot_x(row["alpha"]))
    )
    if "theta_acc" in row:
        t = t @ transform(rot_z(row["theta_acc"])) @ transform(translation=(0.0, 0.0, row["d_acc"]))
    return t


def placement(entry):
    """The joint frame of a DoF on its parent segment, and the joint axis in it."""
    if "dh" in entry:
        return dh(entry["dh"]), np.array([0.0, 0.0, 1.0])
    origin = entry.get("origin", {})
    xyz = origin.get("xyz", [0.0, 0.0, 0.0])
    roll, pitch, yaw = origin.get("rpy", [0.0, 0.0, 0.0])
    frame = transform(rot_z(yaw) @ rot_y(pitch) @ rot_x(roll), xyz)
    return frame, np.array(entry.get("axis", [0.0, 0.0, 1.0]), dtype=float)


def is_slide(dof):
    """Whether a DoF of the robot or the plan is prismatic (positions in m)."""
    return dof.get("kind") == "prismatic"


# The plan's pattern is in rad; a prismatic DoF runs it scaled by this, m per rad (skincal's
# `DofKind::pattern_scale`).
PRISMATIC_PATTERN_SCALE = 0.1


def sensor_frame(su):
    """The frame of an SU on its segment: DH+2 or xyz and rpy (URDF's order, Rz·Ry·Rx)."""
    if "dh" in su:
        return dh(su["dh"])
    roll, pitch, yaw = su.get("rpy", [0.0, 0.0, 0.0])
    return transform(rot_z(yaw) @ rot_y(pitch) @ rot_x(roll), su.get("xyz", [0.0, 0.0, 0.0]))


def pose_attributes(t):
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, t[:3, :3].flatten())
    p = t[:3, 3]
    return f'pos="{p[0]:.12g} {p[1]:.12g} {p[2]:.12g}" quat="{q[0]:.12g} {q[1]:.12g} {q[2]:.12g} {q[3]:.12g}"'


def mjcf(robot, gravity, gravcomp=False):
    """MJCF of the robot: one body per segment (its frame is the segment frame of skincal's model,
    which the DoF turns), a capsule to every child joint and SU, a site per SU."""
    reference = robot["reference"]
    dofs = robot["dofs"]
    sus = robot["sus"]
    children = {}
    for d in dofs:
        children.setdefault(d["parent"], []).append(d)
    on = {}
    for s in sus:
        on.setdefault(s["segment"], []).append(s)

    def geoms(segment, indent):
        ends = [placement(c)[0][:3, 3] for c in children.get(segment, [])]
        ends += [sensor_frame(s)[:3, 3] for s in on.get(segment, [])]
        out = []
        for i, e in enumerate(ends):
            if np.linalg.norm(e) < 1e-3:
                continue
            out.append(
                f'{indent}<geom type="capsule" size="0.035" fromto="0 0 0 {e[0]:.9g} {e[1]:.9g} {e[2]:.9g}"/>'
            )
        out.append(f'{indent}<geom type="sphere" size="0.045"/>')
        return out

    def body(segment, indent):
        lines = geoms(segment, indent)
        for s in on.get(segment, []):
            lines.append(f'{indent}<site name="{s["name"]}" {pose_attributes(sensor_frame(s))}/>')
        for d in children.get(segment, []):
            frame, axis = placement(d)
            compensated = ' gravcomp="1"' if gravcomp else ""
            lines.append(f'{indent}<body name="{d["child"]}" {pose_attributes(frame)}{compensated}>')
            kind = "slide" if is_slide(d) else "hinge"
            lines.append(
                f'{indent}  <joint name="{d["name"]}" type="{kind}" axis="{axis[0]} {axis[1]} {axis[2]}" armature="0.02"/>'
            )
            lines += body(d["child"], indent + "  ")
            lines.append(f"{indent}</body>")
        return lines

    world = body(reference, "    ")
    # Position servos; their gains are set once the model's inertia is known.
    servos = [f'    <position name="{d["name"]}" joint="{d["name"]}" kp="1" kv="1"/>' for d in dofs]
    # What the log records of every state: the joint positions, and every SU's position and axes
    # in the world (its acceleration is the positions' second difference, see `main`).
    sensors = [f'    <jointpos joint="{d["name"]}"/>' for d in dofs]
    sensors += [f'    <framepos objtype="site" objname="{s["name"]}"/>' for s in sus]
    sensors += [
        f'    <frame{axis}axis objtype="site" objname="{s["name"]}"/>' for s in sus for axis in "xyz"
    ]
    # Aluminium tube: 2.7 t/m³ over the full capsule is too heavy; a quarter of it.
    return "\n".join(
        [
            '<mujoco model="skin">',
            f'  <option timestep="0.00025" gravity="{gravity[0]} {gravity[1]} {gravity[2]}" integrator="implicitfast"/>',
            '  <default><geom density="700" contype="0" conaffinity="0"/></default>',
            "  <worldbody>",
            *world,
            "  </worldbody>",
            "  <actuator>",
            *servos,
            "  </actuator>",
            "  <sensor>",
            *sensors,
            "  </sensor>",
            "</mujoco>",
        ]
    )


def quintic(a, b, u):
    s = u * u * u * (10.0 - 15.0 * u + 6.0 * u * u)
    return a + (b - a) * s


def sweep(phase, centre):
    """A continuous program's sweep: every DoF along its windowed Fourier series about `centre`."""
    frequency, ramp, duration = phase["frequency"], phase["ramp"], phase["duration"]
    harmonics = [np.array(h, dtype=float).reshape(-1, 2) for h in phase["harmonics"]]

    def window(t):
        w = np.where((t > 0.0) & (t < duration), 1.0, 0.0)
        if ramp > 0.0:
            rising = (t > 0.0) & (t < ramp)
            falling = (t > duration - ramp) & (t < duration) & ~rising
            w = np.where(rising, quintic(0.0, 1.0, np.clip(t / ramp, 0.0, 1.0)), w)
            w = np.where(falling, quintic(0.0, 1.0, np.clip((duration - t) / ramp, 0.0, 1.0)), w)
        return w

    def at(t, centre=centre):
        q = np.tile(centre, (len(t), 1))
        w = window(t)
        for d, h in enumerate(harmonics):
            k = np.arange(1, len(h) + 1)
            phase_angle = 2.0 * math.pi * frequency * np.outer(t, k)
            q[:, d] += w * (np.sin(phase_angle) @ h[:, 0] + np.cos(phase_angle) @ h[:, 1])
        return q

    return at


def reference(plan, part, pause, dof_index, backwards_near_limits=True, away_from_nearer_limit=False):
    """The commanded trajectory as a list of (duration, function of times → q) segments: each
    function takes an array of times from the segment's start and returns one row of positions per
    time."""
    pattern = plan["pattern"]
    amplitude, frequency = pattern["amplitude"], pattern["frequency"]
    w = 2.0 * math.pi * frequency
    segments = []
    previous_excitation = False
    for phase in plan["phases"]:
        if part is not None and phase["part"] != part:
            continue
        a, b = np.array(phase["from"]), np.array(phase["to"])
        action = phase["action"]
        if action == "still":
            duration = pause if previous_excitation else phase["duration"]
            segments.append((duration, lambda t, b=b: np.tile(b, (len(t), 1))))
        elif action in ("move", "transfer"):
            duration = phase["duration"]
            segments.append(
                (duration, lambda t, a=a, b=b, T=duration: quintic(a, b, np.minimum(t / T, 1.0)[:, None]))
            )
        elif action == "sweep":
            segments.append((phase["duration"], sweep(phase, a)))
        elif action == "excitation":
            # One DoF, or several together (a plan's parallel limbs).
            excited = [dof_index[n] for n in [phase["dof"], *phase.get("together", [])]]
            scale = np.array(
                [PRISMATIC_PATTERN_SCALE if is_slide(plan["dofs"][d]) else 1.0 for d in excited]
            )
            sense = np.ones(len(excited))
            if backwards_near_limits:
                for i, d in enumerate(excited):
                    excursion = 2.0 * amplitude / w * scale[i]
                    lower = plan["dofs"][d].get("lower", -math.inf)
                    upper = plan["dofs"][d].get("upper", math.inf)
                    nearer_upper = away_from_nearer_limit and upper - a[d] < a[d] - lower
                    if a[d] + excursion > upper or nearer_upper:
                        sense[i] = -1.0
            sense = sense * scale

            def excite(t, a=a, excited=excited, sense=sense):
                q = np.tile(a, (len(t), 1))
                q[:, excited] += np.outer(1.0 - np.cos(w * t), sense * amplitude / w)
                return q

            segments.append((1.0 / frequency, excite))
        previous_excitation = action == "excitation"
    return segments


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("robot")
    parser.add_argument("plan")
    parser.add_argument("out")
    parser.add_argument("--part", choices=["structure", "training"], help="run only this part")
    parser.add_argument("--gravity", default="0,0,-9.81", help="gravity in the base frame, m/s²")
    parser.add_argument("--bandwidth", type=float, default=6.0, help="servo bandwidth, Hz")
    parser.add_argument("--damping", type=float, default=0.8, help="servo damping ratio")
    parser.add_argument(
        "--tune",
        choices=["first", "largest"],
        default="first",
        help="servo gains from the inertia at the first pose, or the largest over the plan's poses",
    )
    parser.add_argument(
        "--gravcomp",
        action="store_true",
        help="compensate gravity on every moving body (the servos then need not sag under it)",
    )
    parser.add_argument("--pause", type=float, default=0.5, help="hold after each pattern, s")
    parser.add_argument(
        "--forwards-only",
        action="store_true",
        help="run every pattern forwards, also where it leaves the DoF's range",
    )
    parser.add_argument(
        "--away-from-nearer-limit",
        action="store_true",
        help="run each pattern away from the nearer limit of its DoF (backwards in the upper half)",
    )
    parser.add_argument("--noise", type=float, default=0.05, help="accelerometer noise σ, m/s²")
    parser.add_argument("--encoder-bits", type=int, default=17, help="encoder resolution (0: exact)")
    parser.add_argument("--adc-bits", type=int, default=10, help="accelerometer resolution over ±2 g (0: exact)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--start", type=float, default=1_700_000_000.0, help="first stamp, s")
    parser.add_argument("--raw", action="store_true", help="write the samples as doubles, not CSV")
    args = parser.parse_args()

    with open(args.robot) as f:
        robot = json.load(f)
    with open(args.plan) as f:
        plan = json.load(f)
    gravity = [float(x) for x in args.gravity.split(",")]
    model = mujoco.MjModel.from_xml_string(mjcf(robot, gravity, args.gravcomp))
    data = mujoco.MjData(model)
    names = [d["name"] for d in plan["dofs"]]
    dof_index = {n: i for i, n in enumerate(names)}
    qadr = [model.jnt_qposadr[model.joint(n).id] for n in names]
    vadr = [model.jnt_dofadr[model.joint(n).id] for n in names]
    su_names = [s["name"] for s in robot["sus"]]

    segments = reference(
        plan, args.part, args.pause, dof_index, not args.forwards_only, args.away_from_nearer_limit
    )
    if not segments:
        sys.exit("the plan has no phase of that part")
    q0 = segments[0][1](np.zeros(1))[0]

    # Servo gains from the joint-space inertia at the first pose (or the largest over the plan's
    # poses, `--tune largest`, so that no pose leaves a servo below its bandwidth and damping):
    # kp = I ω², kv = 2ζ I ω.
    def diagonal_inertia(q):
        data.qpos[qadr] = q
        mujoco.mj_forward(model, data)
        full = np.zeros((model.nv, model.nv))
        mujoco.mj_fullM(model, data, full)
        return np.array([full[v, v] for v in vadr])

    poses = [q0]
    if args.tune == "largest":
        poses += [np.array(p["to"]) for p in plan["phases"] if args.part in (None, p["part"])]
    inertia = np.max([diagonal_inertia(q) for q in poses], axis=0)
    omega = 2.0 * math.pi * args.bandwidth
    kp = inertia * omega**2
    kv = 2.0 * args.damping * inertia * omega
    # MuJoCo's position actuator: force = kp·ctrl − kp·q − kv·q̇.
    for i, n in enumerate(names):
        a = model.actuator(n).id
        model.actuator_gainprm[a, 0] = kp[i]
        model.actuator_biasprm[a, 1] = -kp[i]
        model.actuator_biasprm[a, 2] = -kv[i]
    aadr = [model.actuator(n).id for n in names]

    # Stiff servos on light distal links need short steps: 4 substeps per 1 ms sample up to 6 Hz,
    # more above (the stiffness grows with the bandwidth squared). implicitfast evaluates the
    # dynamics once a step where RK4 did four times: the paper arm's 90 s log takes 4.5 s against
    # 14.6, its joint positions within 0.24 mrad of RK4's and its skin within 0.004 m/s² RMS.
    substeps = max(4, math.ceil(4 * (args.bandwidth / 6.0) ** 2))
    model.opt.timestep = 0.001 / substeps
    dt = model.opt.timestep * substeps
    rng = np.random.default_rng(args.seed)
    encoder = 2.0 * math.pi / 2**args.encoder_bits if args.encoder_bits else 0.0
    lsb = 4.0 * 9.81 / 2**args.adc_bits if args.adc_bits else 0.0

    h = model.opt.timestep
    gravity_vector = np.array(gravity)
    nsu = len(su_names)
    robot_dofs = [d["name"] for d in robot["dofs"]]
    joint_sensor = [robot_dofs.index(n) for n in names]
    # The sensors' layout (see `mjcf`): joint positions, then every site's position, then its
    # axes.
    nd = len(robot_dofs)
    full = mujoco.mjtState.mjSTATE_FULLPHYSICS

    def roll(state, control, check=False):
        """Runs one step per row of `control` (the servos' commands, in `names` order) from the
        full physics `state`, in MuJoCo's own loop; returns the state after the last step and the
        sensors after every step (row k: after step k). With `check`, that row convention is
        checked against the sensors computed in the states after a few steps."""
        ctrl = np.zeros((len(control), model.nu))
        ctrl[:, aadr] = control
        states, sensors = rollout.rollout(model, data, state, ctrl[None])
        states, sensors = states[0], sensors[0]
        # MuJoCo computes a step's sensors at its start: after step k they are step k+1's; after
        # the last step, they are computed here.
        mujoco.mj_setState(model, data, states[-1], full)
        mujoco.mj_forward(model, data)
        after = np.concatenate([sensors[1:], data.sensordata[None]])
        for k in np.linspace(0, len(after) - 1, 7).astype(int) if check else []:
            mujoco.mj_setState(model, data, states[k], full)
            mujoco.mj_forward(model, data)
            assert np.array_equal(after[k], data.sensordata), "rollout's sensors are not its states'"
        return states[-1], after

    def record(state, commands):
        """The samples of one run of the servos' `commands` (one row per substep, `substeps` per
        1 ms sample): per sample, the joint positions and every SU's specific force at its
        second-to-last substep. The acceleration is the second difference of the site's positions
        over the substeps (what an accelerometer senses, from the trajectory itself). Returns the
        state after the run with the samples."""
        state, after = roll(state, commands)
        n = len(commands) // substeps
        at = after.reshape(n, substeps, -1)
        q = at[:, -2, :nd][:, joint_sensor]
        p = at[:, -3:, nd : nd + 3 * nsu].reshape(n, 3, nsu, 3)
        a = (p[:, 2] - 2.0 * p[:, 1] + p[:, 0]) / h**2
        axes = at[:, -2, nd + 3 * nsu :].reshape(n, nsu, 3, 3)
        # In the site's frame: the component along each of its axes.
        return state, q, np.einsum("nsij,nsj->nsi", axes, a - gravity_vector)

    # The servos' command is interpolated at every substep (a command held for a whole period
    # would jerk at 1 kHz): substep j of the sample ending at t is commanded at t − dt + (j+1)·h.
    offsets = (np.arange(substeps) + 1) * h - dt
    state = np.zeros(mujoco.mj_stateSize(model, full))
    mujoco.mj_getState(model, data, state, full)
    # Settle at the first pose (gravity sag) before recording.
    state, _ = roll(state, np.tile(q0, (int(2.0 / dt) * substeps, 1)), check=True)
    qs, accs = [], []
    for duration, trajectory in segments:
        n = int(round(duration / dt))
        # At most 2 s of samples at a time: the sensors of every substep are held meanwhile.
        for first in range(0, n, 2000):
            samples = np.arange(first, min(n, first + 2000)) + 1
            times = (samples[:, None] * dt + offsets[None]).reshape(-1)
            state, q, a = record(state, trajectory(times))
            qs.append(q)
            accs.append(a)
    qs = np.concatenate(qs)
    accs = np.concatenate(accs)
    if encoder:
        # A slide's encoder counts the same number of steps over a metre as a turn's over a
        # revolution.
        steps = np.array([encoder / (2.0 * math.pi) if is_slide(d) else encoder for d in plan["dofs"]])
        qs = np.round(qs / steps) * steps
    accs = accs + rng.normal(0.0, args.noise, accs.shape)
    if lsb:
        accs = np.clip(np.round(accs / lsb) * lsb, -2.0 * 9.81, 2.0 * 9.81 - lsb)

    os.makedirs(args.out, exist_ok=True)
    if args.raw:
        with open(os.path.join(args.out, "raw.json"), "w") as f:
            json.dump({"dofs": names, "sus": su_names, "start": args.start, "period": dt, "samples": len(qs)}, f)
        qs.astype("<f8").tofile(os.path.join(args.out, "joint_states.f64"))
        accs.astype("<f8").tofile(os.path.join(args.out, "imu.f64"))
        print(f"{len(qs)} samples, {len(qs) * dt:.1f} s, kp {np.round(kp, 1).tolist()}")
        return
    stamps = args.start + np.arange(len(qs)) * dt
    # One sample's rows formatted at once: each template takes the stamp and the sample's values.
    joint_row = "%.6f," + ",".join(["%.9f"] * len(names)) + "\n"
    imu_rows = "".join(f"%.6f,{name},%.6f,%.6f,%.6f\n" for name in su_names)
    with open(os.path.join(args.out, "joint_states.csv"), "w") as f:
        f.write("stamp," + ",".join(names) + "\n")
        for t, q in zip(stamps.tolist(), qs.tolist()):
            f.write(joint_row % (t, *q))
    with open(os.path.join(args.out, "imu.csv"), "w") as f:
        f.write("stamp,frame_id,ax,ay,az\n")
        for t, a in zip(stamps.tolist(), accs.tolist()):
            f.write(imu_rows % tuple(x for v in a for x in (t, *v)))
    print(f"{len(qs)} samples, {len(qs) * dt:.1f} s, kp {np.round(kp, 1).tolist()}")


if __name__ == "__main__":
    main()
