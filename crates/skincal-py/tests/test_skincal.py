"""The Python package against the truth, against the files the CLI writes, and on bad input.

Needs the `skincal` command (SKINCAL_BIN, or target/release/skincal): `cargo xtask test` builds it
and installs the package before running these tests.
"""

import json
import os
import subprocess
import threading
from pathlib import Path

import numpy as np
import pytest

import skincal

ROOT = Path(__file__).resolve().parents[3]


def cli(*args, cwd):
    binary = os.environ.get("SKINCAL_BIN") or str(ROOT / "target" / "release" / "skincal")
    if not Path(binary).exists():
        pytest.fail(f"no skincal command at {binary}: build it (cargo build --release) or set SKINCAL_BIN")
    done = subprocess.run([binary, *args], cwd=cwd, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_the_paper_arm_end_to_end_against_the_truth():
    data = skincal.simulate("paper-7dof", seed=3)
    assert data.truth["robot"]["name"]
    structure = skincal.explore(data)
    assert structure.complete
    assert len(structure.joints) == 7 and len(structure.limbs) == 1
    (path,) = structure.limbs
    assert path.start == structure.root == structure.segments[0].id
    assert path.dofs == data.dofs and path.sus == data.sus
    assert [j.child for j in structure.joints] == path.segments
    assert all(d.severity != "error" for d in structure.diagnostics)
    # A serial chain: the sorted activity matrix is lower triangular with a full diagonal.
    activity = structure.activity
    assert activity.shape == (8, 7)
    assert np.array_equal(activity[1:], np.tril(np.ones((7, 7), dtype=bool)))
    model = skincal.calibrate(data, structure)
    (limb,) = model.limbs
    assert limb.converged and 0.8 < limb.residual < 1.2
    assert set(limb.su_poses) == set(data.sus)
    for pose in limb.su_poses.values():
        assert pose.shape == (4, 4)
        assert np.allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-12)
    assert limb.dh is not None and limb.dh["dof_dof"]["a"].shape == (6,)
    assert np.all(limb.dh["dof_dof_sd"]["a"] > 0)
    # What no reading tells is named, never given a deviation: the first SU's and the first
    # pair's height along and turn about the vertical first axis; every later pair is determined.
    assert set(limb.su_undetermined) == {"su1", "su2"}, limb.su_undetermined
    first = limb.su_undetermined["su1"]["position"]
    assert first.shape[1] == 3 and np.isclose(np.linalg.norm(first @ [0.0, 0.0, 1.0]), 1.0)
    # Noise-free readings of the true robot at 30 other poses: the model predicts them to the
    # accuracy the calibration's noise allows (the CLI's own figures for this setting).
    held = skincal.simulate("paper-7dof", seed=3, pose_seed=99, noise=0.0, structure=False)
    check = model.validate(held)
    assert check.poses == 20
    assert check.static_rms < 0.06 and check.dynamic_rms < 0.03, check
    static, dynamic = model.predict(held.training.poses, held.training.pattern)
    t = held.training
    # The arrays against the true robot's readings, SU by SU in the set's order.
    assert model.sus == held.sus
    errors = np.linalg.norm(static - t.static, axis=2)
    assert np.sqrt(np.mean(errors**2)) < 0.06 and errors.max() < 0.2
    assert dynamic.shape == t.dynamic.shape
    # Per excited DoF, the error of its dynamic readings over every SU it moves (the others are
    # read and predicted zero), as the arrays give it.
    assert [d["dof"] for d in check.dofs] == model.dofs == held.dofs
    for k, d in enumerate(check.dofs):
        squares = np.sum((dynamic[:, k] - t.dynamic[:, k]) ** 2)
        assert np.isclose(np.sqrt(squares / d["dynamic_count"]), d["dynamic_rms"], rtol=1e-9), d
    # One pose alone gives the same numbers.
    one_static, _ = model.predict(t.poses[0], t.pattern)
    assert np.array_equal(one_static, static[0])
    assert "<robot" in model.to_urdf()


def test_arrays_round_trip_exactly_with_the_files_the_cli_writes(tmp_path):
    cli("simulate", "--robot", "humanoid", "--out", "sim", cwd=tmp_path)
    path = tmp_path / "sim" / "measurements.json"
    loaded = skincal.MeasurementSet.load(path)
    t = loaded.training
    assert t.poses.shape == (20, 26) and t.static.shape == (20, 31, 3)
    assert t.dynamic.shape == (20, 26, 31, 3)
    rebuilt = skincal.MeasurementSet.from_arrays(
        loaded.dofs, loaded.sus, t.poses, t.static, t.dynamic, t.pattern,
        structure=loaded.structure_experiment,
    )
    assert rebuilt.to_json() == path.read_text()
    again = rebuilt.training
    for a, b in [(t.poses, again.poses), (t.static, again.static), (t.dynamic, again.dynamic)]:
        assert np.array_equal(a, b)
    rebuilt.save(tmp_path / "copy.json")
    assert (tmp_path / "copy.json").read_bytes() == path.read_bytes()


def test_calibrate_returns_the_clis_model_byte_for_byte(tmp_path):
    cli("simulate", "--robot", "humanoid", "--out", "sim", cwd=tmp_path)
    cli("explore", "sim", cwd=tmp_path)
    cli("calibrate", "sim", cwd=tmp_path)
    data = skincal.MeasurementSet.load(tmp_path / "sim" / "measurements.json")
    structure = skincal.Structure.load(tmp_path / "sim" / "structure.json")
    model = skincal.calibrate(data, structure)
    model.save(tmp_path / "model.json")
    assert (tmp_path / "model.json").read_bytes() == (tmp_path / "sim" / "model.json").read_bytes()
    assert all(limb.converged for limb in model.limbs) and len(model.limbs) == 5
    # The file the CLI wrote predicts what the Python model predicts.
    cli_model = skincal.Model.load(tmp_path / "sim" / "model.json")
    q = np.random.default_rng(5).uniform(-1, 1, size=(4, len(model.dofs)))
    for a, b in zip(model.predict(q), cli_model.predict(q)):
        assert np.array_equal(a, b)


def _rz(t):
    c, s = np.cos(t), np.sin(t)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    return m


def _rx(t):
    c, s = np.cos(t), np.sin(t)
    m = np.eye(4)
    m[1:3, 1:3] = [[c, -s], [s, c]]
    return m


def _shift(x=0.0, z=0.0):
    m = np.eye(4)
    m[0, 3], m[2, 3] = x, z
    return m


def test_the_papers_method_gives_the_clis_chains_and_frames_by_eq_5_and_7(tmp_path):
    # 10 training poses: the paper's global search meets its stop in 0.2 s (at 20 some steps run
    # to the cap on evaluations, 10 s each way).
    cli("simulate", "--robot", "paper-7dof", "--seed", "3", "--poses", "10", "--out", "sim",
        cwd=tmp_path)
    cli("calibrate", "sim", "--method", "paper", cwd=tmp_path)
    calls = []
    model = skincal.calibrate(
        tmp_path / "sim", method="paper", progress=lambda *c: calls.append(c)
    )
    assert isinstance(model, skincal.PaperModel)
    assert calls[0] == ("S7", 0, 1) and calls[-1][1:] == (1, 1)
    # The CLI's file, but for the wall times.
    def timeless(text):
        data = json.loads(text)
        for limb in data["limbs"]:
            for step in limb["steps"]:
                step.pop("seconds")
        return data
    assert timeless(model.to_json()) == timeless((tmp_path / "sim" / "model-paper.json").read_text())
    (limb,) = model.limbs
    assert limb.dofs == [f"dof{k}" for k in range(1, 8)] and limb.dof_dof.shape == (6, 4)
    assert limb.dof_su.shape == (7, 6) and len(limb.steps) == 7
    # The SU frames by the paper's chain (eq. 4, 5 and 7), written here from the DH tables.
    q = np.random.default_rng(2).uniform(-1, 1, 7)
    frames = model.su_frames("S7", q)
    segment = np.eye(4)
    for k, su in enumerate(limb.sus):
        t0, d, a, al, tacc, dacc = limb.dof_su[k]
        expected = segment @ _rz(q[k] + t0) @ _shift(z=d) @ _shift(x=a) @ _rx(al) @ _rz(tacc) @ _shift(z=dacc)
        assert np.allclose(frames[su], expected, atol=1e-12), su
        if k < 6:
            t0, d, a, al = limb.dof_dof[k]
            segment = segment @ _rz(q[k] + t0) @ _shift(z=d) @ _shift(x=a) @ _rx(al)
    with pytest.raises(ValueError):
        model.su_frames("S7", np.full(7, np.nan))
    with pytest.raises(KeyError):
        model.su_frames("S8", q)
    with pytest.raises(ValueError):
        skincal.calibrate(tmp_path / "sim", method="paper", noise=0.01)
    model.save(tmp_path / "again.json")
    assert json.loads((tmp_path / "again.json").read_text()) == json.loads(model.to_json())


def test_ingest_and_plan_give_what_the_cli_gives(tmp_path, monkeypatch):
    cli("plan", "--robot", "paper-7dof", "--poses", "3", "--out", "p", cwd=tmp_path)
    cli("record", "--robot", "paper-7dof", "--plan", "p/plan.json", "--out", "up.mcap", cwd=tmp_path)
    cli("record", "--robot", "paper-7dof", "--plan", "p/plan.json", "--out", "tilt.mcap",
        "--part", "structure", "--tilted", cwd=tmp_path)
    cli("ingest", "up.mcap", "tilt.mcap", "--plan", "p/plan.json", "--out", "real", cwd=tmp_path)
    calls = []
    monkeypatch.chdir(tmp_path)  # the set names its logs as given
    data, report = skincal.ingest(
        ["up.mcap", Path("tilt.mcap")],
        plan="p/plan.json",
        progress=lambda stage, done, total: calls.append((stage, done, total)),
    )
    assert data.to_json() == (tmp_path / "real" / "measurements.json").read_text()
    assert report["training_poses"] == 3 and report["warnings"] == []
    assert calls and all(done <= total for _, done, total in calls if total)
    # A job of a fraction of a second reports each stage and its end, not every step.
    stages = {stage for stage, _, _ in calls}
    assert len(calls) <= 3 * len(stages) + 5, calls
    t = data.training
    assert t.static_sd.shape == (3, 7) and np.all(t.static_sd > 0)
    program = skincal.plan("paper-7dof")
    assert program["duration"] <= 60 and program["forecast"]["static_rms"] < 0.009
    assert program == json.loads(skincal._skincal.plan("paper-7dof", "short", None, None, 1))
    assert skincal.plan("paper-7dof", protocol="paper")["duration"] > 400


def test_bad_input_raises_skincal_errors_that_say_what_is_wrong(tmp_path):
    with pytest.raises(skincal.SkincalError, match="no-such-robot"):
        skincal.simulate("no-such-robot")
    with pytest.raises(FileNotFoundError, match="missing.json"):
        skincal.MeasurementSet.load(tmp_path / "missing.json")
    with pytest.raises(FileNotFoundError):
        skincal.Model.load(str(tmp_path / "missing.json"))
    with pytest.raises(FileNotFoundError, match="nowhere.mcap"):
        skincal.ingest([tmp_path / "nowhere.mcap"])
    data = skincal.simulate("paper-7dof", poses=4)
    broken = json.loads(data.to_json())
    broken["training"]["poses"][1]["static"][2] = [0.0, 0.0]
    with pytest.raises(skincal.SkincalError, match="static"):
        skincal.MeasurementSet.from_json(json.dumps(broken))
    t = data.training
    with pytest.raises(skincal.SkincalError, match="statics: shape"):
        skincal.MeasurementSet.from_arrays(data.dofs, data.sus, t.poses, t.static[:, :3], t.dynamic)
    model = skincal.calibrate(data, noise=0.01)
    with pytest.raises(skincal.SkincalError, match="one angle per DoF"):
        model.predict(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="finite"):
        model.predict(np.full(7, np.nan))
    # Paths where a set is expected: the file, or its directory.
    data.save(tmp_path / "set" / "measurements.json")
    assert skincal.explore(tmp_path / "set").complete
    assert skincal.explore(str(tmp_path / "set" / "measurements.json")).complete
    with pytest.raises(TypeError, match="MeasurementSet"):
        skincal.explore(42)
    with pytest.raises(ValueError, match="'ml' or 'paper'"):
        skincal.calibrate(data, method="kalman")
    with pytest.raises(skincal.SkincalError, match="at least 10 poses"):
        skincal.calibrate(data, method="paper")
    model.save(tmp_path / "model.json")
    with pytest.raises(skincal.SkincalError, match="exists"):
        model.save(tmp_path / "model.json")
    model.save(tmp_path / "model.json", force=True)


def test_calibration_releases_the_interpreter_and_reports_each_limb():
    data = skincal.simulate("humanoid")
    structure = skincal.explore(data)
    calls = []
    worker = threading.Thread(
        target=lambda: skincal.calibrate(data, structure, progress=lambda *a: calls.append(a))
    )
    count = 0
    worker.start()
    while worker.is_alive():
        count += 1
    worker.join()
    # Holding the interpreter, the native call would leave this loop a handful of turns.
    assert count > 10_000, count
    limbs = [limb.end for limb in structure.limbs]
    assert sorted(name for name, _, _ in calls) == sorted(limbs)
    assert [(done, total) for _, done, total in calls] == [(k + 1, 5) for k in range(5)]


def same(a, b, rel=1e-9):
    """Equal JSON, numbers within `rel` (the extension and the CLI are built apart: the last bits
    of a sum may differ)."""
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same(a[k], b[k], rel) for k in a)
    if isinstance(a, list):
        return isinstance(b, list) and len(a) == len(b) and all(same(x, y, rel) for x, y in zip(a, b))
    if isinstance(a, float) or isinstance(b, float):
        return abs(a - b) <= rel * max(abs(a), abs(b), 1e-300)
    return a == b


def test_check_and_live_check_name_two_boards_swapped_in_their_ports(tmp_path):
    """A calibration by the CLI's continuous program, then 40 s of other motion whose skin log has
    two boards' ids exchanged (re-plugged into each other's ports): `check` names both, as the CLI
    does; a live check fed the same samples in time order says the same, holding little."""
    run = lambda *a: cli(*a, cwd=tmp_path)
    run("plan", "--robot", "paper-7dof", "--protocol", "continuous", "--out", "plan", "--no-forecast")
    run("record", "--robot", "paper-7dof", "--plan", "plan/plan.json", "--out", "up.mcap")
    run("record", "--robot", "paper-7dof", "--plan", "plan/plan.json", "--out", "tilt.mcap",
        "--part", "structure", "--tilted")
    run("ingest", "up.mcap", "tilt.mcap", "--out", "cal")
    run("explore", "cal")
    run("calibrate", "cal")
    run("plan", "--robot", "paper-7dof", "--protocol", "continuous", "--sweep", "40", "--seed", "9",
        "--out", "work", "--no-forecast")
    run("record", "--robot", "paper-7dof", "--plan", "work/plan.json", "--out", "work",
        "--part", "training", "--seed", "4", "--format", "csv")
    imu = tmp_path / "work" / "imu.csv"
    text = imu.read_text().replace(",su3,", ",tmp,").replace(",su7,", ",su3,").replace(",tmp,", ",su7,")
    imu.write_text(text)

    report = skincal.check(tmp_path / "cal" / "model.json", [tmp_path / "work"])
    verdicts = {s.su: (s.verdict, s.detail) for s in report.sus}
    assert verdicts["su3"] == ("swapped", {"with": "su7"}), verdicts
    assert verdicts["su7"] == ("swapped", {"with": "su3"}), verdicts
    assert {s.su for s in report.changed()} == {"su3", "su7"}
    # The arm's first axis is vertical on its still base: no motion tells its zero. dof7 moves
    # su7 alone, which now reads another's place: nothing in this log tells dof7's zero.
    assert report.zeros_never_told == ["dof1"], report
    assert report.zeros_untold == ["dof7"], report
    binary = os.environ.get("SKINCAL_BIN") or str(ROOT / "target" / "release" / "skincal")
    done = subprocess.run([binary, "check", "cal/model.json", "work", "--json"], cwd=tmp_path,
                          capture_output=True, text=True)
    assert done.returncode == 3, done.stderr
    native = json.loads(skincal._skincal.check(
        skincal.Model.load(tmp_path / "cal" / "model.json")._native, [str(tmp_path / "work")]))
    assert same(json.loads(done.stdout)["report"], native)

    joints = np.loadtxt(tmp_path / "work" / "joint_states.csv", delimiter=",", skiprows=1)
    names = (tmp_path / "work" / "joint_states.csv").read_text().split("\n", 1)[0].split(",")[1:]
    rows = [line.split(",") for line in text.splitlines()[1:]]
    stamps = np.array([float(r[0]) for r in rows])
    sus = [r[1] for r in rows]
    acc = np.array([[float(x) for x in r[2:5]] for r in rows])
    live = skincal.LiveCheck(tmp_path / "cal" / "model.json")
    start, most, j, i = joints[0, 0], (0, 0, 0), 0, 0
    for k, edge in enumerate(np.arange(start + 0.01, joints[-1, 0] + 0.02, 0.01)):
        while j < len(joints) and joints[j, 0] < edge:
            live.joints(joints[j, 0], names, joints[j, 1:])
            j += 1
        n = np.searchsorted(stamps, edge)
        live.imu(stamps[i:n], sus[i:n], acc[i:n])
        i = n
        if k % 500 == 0:
            most = tuple(max(a, b) for a, b in zip(most, live.held()))
    streamed = live.report()
    assert streamed is not None
    assert {s.su: (s.verdict, s.detail) for s in streamed.sus} == verdicts
    assert most[0] < 7 * 400 and most[1] < 200, most
