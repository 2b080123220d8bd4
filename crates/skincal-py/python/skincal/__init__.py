"""skincal: a robot's skin calibrates itself from its own accelerometers.

The skin is many small sensor units (SUs), each a 3-axis accelerometer. From their static gravity
readings and the accelerations that short excitation patterns cause, skincal finds the robot's
kinematic tree (:func:`explore`) and fits every limb's kinematics and every SU's pose
(:func:`calibrate`), with uncertainties; the result predicts readings, checks itself against new
data and exports URDF. Units are SI throughout (m, rad, m/s²); arrays are numpy arrays of float64.

    >>> import skincal
    >>> data = skincal.simulate("paper-7dof", seed=1)
    >>> structure = skincal.explore(data)
    >>> model = skincal.calibrate(data, structure)
    >>> [limb.converged for limb in model.limbs]
    [True]

Errors are :class:`SkincalError` with the library's message (it names the file, field or sensor
and what to do); a file that does not exist is a :class:`FileNotFoundError` and a pose that is not
finite a :class:`ValueError`, as Python's own. Long work releases the interpreter, so other
threads run meanwhile.
"""

from __future__ import annotations

import errno
import json
import os
import time
from dataclasses import dataclass, field
from functools import cached_property
from os import PathLike
from typing import Callable, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from . import _skincal
from ._skincal import SkincalError, __version__


def _existing(path: "Path", what: str) -> str:
    """``path`` as a string, or :class:`FileNotFoundError` naming it and what it should hold."""
    if not os.path.exists(path):
        raise FileNotFoundError(errno.ENOENT, f"no {what} at this path", str(path))
    return str(path)


def _measurement_set(data: "Union[MeasurementSet, Path]") -> "MeasurementSet":
    """A measurement set, or the one a path names (a ``measurements.json`` or its directory)."""
    if isinstance(data, MeasurementSet):
        return data
    if isinstance(data, (str, PathLike)):
        path = os.fspath(data)
        if os.path.isdir(path):
            path = os.path.join(path, "measurements.json")
        return MeasurementSet.load(path)
    raise TypeError(
        f"expected a MeasurementSet or the path of a measurements.json (or its directory), "
        f"not {type(data).__name__}"
    )


def _throttled(progress, interval: float = 0.2):
    """``progress(stage, done, total)`` called on a new stage, at its end, and otherwise at most
    every ``interval`` s: a fast job reports a few lines, not hundreds."""
    if progress is None:
        return None
    last = {"stage": None, "done": None, "at": 0.0}

    def report(stage, done, total):
        now = time.monotonic()
        if stage == last["stage"] and done == last["done"]:
            return
        new_stage, finished = stage != last["stage"], total and done >= total
        if new_stage or finished or now - last["at"] >= interval:
            last.update(stage=stage, done=done, at=now)
            progress(stage, done, total)

    return report

__all__ = [
    "SkincalError",
    "check",
    "CheckReport",
    "LiveCheck",
    "SuCheck",
    "MeasurementSet",
    "Training",
    "Structure",
    "Segment",
    "Joint",
    "LimbPath",
    "Diagnostic",
    "Model",
    "Limb",
    "Validation",
    "PaperModel",
    "PaperLimb",
    "simulate",
    "explore",
    "calibrate",
    "ingest",
    "plan",
    "robots",
    "__version__",
]

Path = Union[str, "PathLike[str]"]

#: The paper's excitation pattern (A rad/s, f Hz): what `predict` uses unless told otherwise.
PAPER_PATTERN = (0.5, 2.0)


@dataclass(frozen=True)
class Training:
    """The training experiment of a measurement set, as arrays.

    ``poses`` (P×D, rad), ``static`` readings (P×U×3, m/s²), ``dynamic`` accelerations
    (P×D×U×3, m/s²: every SU's response to the pattern on each DoF; zero where a DoF was not
    excited at a pose), the ``pattern`` (A rad/s, f Hz), and each reading's standard deviation
    (``static_sd`` P×U, ``dynamic_sd`` P×D×U, m/s²) when the set has them (ingested logs do).
    """

    poses: np.ndarray
    static: np.ndarray
    dynamic: np.ndarray
    pattern: Tuple[float, float]
    static_sd: Optional[np.ndarray] = None
    dynamic_sd: Optional[np.ndarray] = None


class MeasurementSet:
    """Readings of one robot's skin: the structure experiment and the training experiment."""

    def __init__(self, native: "_skincal.Measurements", truth: Optional[dict] = None):
        self._native = native
        #: The simulator's truth (robot, orientations, intrinsics) for a simulated set, else None.
        self.truth = truth

    @classmethod
    def load(cls, path: Path) -> "MeasurementSet":
        """Reads and checks a ``measurements.json`` file."""
        return cls(_skincal.Measurements.load(_existing(path, "measurement set")))

    @classmethod
    def from_json(cls, text: str) -> "MeasurementSet":
        """Parses and checks a measurement set's JSON text."""
        return cls(_skincal.Measurements.from_json(text))

    @classmethod
    def from_arrays(
        cls,
        dofs: Sequence[str],
        sus: Sequence[str],
        poses: np.ndarray,
        static: np.ndarray,
        dynamic: np.ndarray,
        pattern: Tuple[float, float] = PAPER_PATTERN,
        static_sd: Optional[np.ndarray] = None,
        dynamic_sd: Optional[np.ndarray] = None,
        structure: Optional[dict] = None,
    ) -> "MeasurementSet":
        """A measurement set from arrays (shapes as in :class:`Training`); ``structure`` is a
        structure experiment as :attr:`structure_experiment` gives it. Checked as a file is."""
        as_array = lambda a: None if a is None else np.ascontiguousarray(a, dtype=np.float64)
        return cls(
            _skincal.Measurements.from_arrays(
                list(dofs),
                list(sus),
                as_array(poses),
                as_array(static),
                as_array(dynamic),
                (float(pattern[0]), float(pattern[1])),
                as_array(static_sd),
                as_array(dynamic_sd),
                None if structure is None else json.dumps(structure),
            )
        )

    def save(self, path: Path, force: bool = False) -> None:
        """Writes the set as ``skincal`` writes it, whole or not at all; an existing file is
        refused unless ``force``."""
        self._native.save(str(path), force)

    def to_json(self) -> str:
        """The set's JSON text, exactly as the CLI writes it."""
        return self._native.to_json()

    @property
    def dofs(self) -> List[str]:
        """DoF names: the order of every pose vector."""
        return self._native.dofs

    @property
    def sus(self) -> List[str]:
        """SU names: the order of every list of readings."""
        return self._native.sus

    @property
    def training(self) -> Optional[Training]:
        """The training experiment as arrays, or None."""
        t = self._native.training()
        return None if t is None else Training(*t)

    @property
    def structure_experiment(self) -> Optional[dict]:
        """The structure experiment (base orientations, rest readings, one move per DoF) as a
        dict, or None."""
        return json.loads(self._native.structure_json())

    def __repr__(self) -> str:
        return repr(self._native)


@dataclass(frozen=True)
class Segment:
    """A segment of the discovered tree: the SUs on it and the joint that moves it (none for the
    reference); ``without_su`` when it was assumed to connect the tree although no SU is on it."""

    id: str
    sus: List[str]
    parent_joint: Optional[str] = None
    without_su: bool = False


@dataclass(frozen=True)
class Joint:
    """A joint: its DoFs (input order), the segment it is mounted on and the one it moves."""

    id: str
    dofs: List[str]
    parent: str
    child: str


@dataclass(frozen=True)
class LimbPath:
    """A limb of the tree: from a reference (the root or a branching segment) outwards."""

    start: str
    end: str
    joints: List[str]
    segments: List[str]
    dofs: List[str]
    sus: List[str]


@dataclass(frozen=True)
class Diagnostic:
    """A finding of exploration: ``severity`` (info, warning or error), what it is (``kind``),
    the plain-language ``message`` and the SUs and DoFs it concerns."""

    kind: str
    severity: str
    message: str
    sus: List[str]
    dofs: List[str]


class Structure:
    """The kinematic structure exploration found: segments, joints, limbs, diagnostics."""

    def __init__(self, native: "_skincal.NativeStructure"):
        self._native = native

    @cached_property
    def _data(self) -> dict:
        return json.loads(self._native.to_json())

    @classmethod
    def load(cls, path: Path) -> "Structure":
        """Reads and checks a ``structure.json`` file."""
        return cls(_skincal.NativeStructure.load(_existing(path, "structure")))

    def save(self, path: Path, force: bool = False) -> None:
        """Writes ``structure.json`` as ``skincal explore`` does, whole or not at all."""
        self._native.save(str(path), force)

    def to_json(self) -> str:
        return self._native.to_json()

    @property
    def complete(self) -> bool:
        """Whether the tree is complete (no error-level diagnostic)."""
        return self._data["complete"]

    @property
    def root(self) -> str:
        """The static reference segment."""
        return self._data["root"]

    @property
    def segments(self) -> List[Segment]:
        """Segments in depth-first order; the first is the reference."""
        return [
            Segment(s["id"], s["sus"], s.get("parent_joint"), s.get("without_su", False))
            for s in self._data["segments"]
        ]

    @property
    def joints(self) -> List[Joint]:
        """Joints; ``Jn`` moves ``Sn``."""
        return [Joint(j["id"], j["dofs"], j["parent"], j["child"]) for j in self._data["joints"]]

    @property
    def limbs(self) -> List[LimbPath]:
        """Limbs, each from its reference segment to an end effector or a branching segment."""
        return [
            LimbPath(l["from"], l["to"], l["joints"], l["segments"], l["dofs"], l["sus"])
            for l in self._data["limbs"]
        ]

    @property
    def diagnostics(self) -> List[Diagnostic]:
        """Findings, in the order exploration lists them."""
        return [
            Diagnostic(d["kind"], d["severity"], d["message"], d["sus"], d["dofs"])
            for d in self._data["diagnostics"]
        ]

    @property
    def unplaced_sus(self) -> List[str]:
        """SUs left out of the tree."""
        return self._data["unplaced_sus"]

    @property
    def activity(self) -> np.ndarray:
        """The merged and sorted activity matrix (paper Fig. 2): segments × joints, True where
        the joint moves the segment; labels in :attr:`activity_labels`."""
        return np.array(self._data["matrix"]["entries"], dtype=bool)

    @property
    def activity_labels(self) -> Tuple[List[str], List[str]]:
        """(segment ids, joint ids) of :attr:`activity`'s rows and columns."""
        m = self._data["matrix"]
        return m["segments"], m["joints"]

    def __repr__(self) -> str:
        return (
            f"<Structure: {len(self.segments)} segments, {len(self.joints)} joints, "
            f"{len(self.limbs)} limbs, {'complete' if self.complete else 'INCOMPLETE'}>"
        )


@dataclass(frozen=True)
class Limb:
    """One calibrated limb.

    ``su_poses``: each SU's pose (4×4, m) in the body frame at the zero pose;
    ``su_sd``: each SU's position (m) and orientation (rad) standard deviation relative to the
    previous SU (the first: to the reference frame), in the directions the readings determine;
    ``su_undetermined``: for an SU whose pose has directions no reading determines, those
    directions (unit vectors: its position's in the frame it is relative to, its orientation's
    axes in its own frame) — their standard deviation is not finite; ``joint_covariance``: the covariance of the fitted joint lines (4 per DoF of
    ``joint_covariance_dofs``: turns about x, y in rad, shifts along x, y in m); ``dh``: for a
    paper-style chain, the DH+2 table as arrays (``dof_dof``: theta0, d, a, alpha per DoF;
    ``dof_su``: also theta_acc, d_acc per SU; and their ``_sd``), else None.
    """

    name: str
    parent: Optional[str]
    dofs: List[str]
    sus: List[str]
    converged: bool
    residual: float
    su_poses: Dict[str, np.ndarray]
    su_sd: Dict[str, Tuple[float, float]]
    su_undetermined: Dict[str, Dict[str, np.ndarray]]
    joint_covariance: np.ndarray
    joint_covariance_dofs: List[str]
    gravity: np.ndarray
    dh: Optional[Dict[str, Dict[str, np.ndarray]]] = None
    details: dict = field(default_factory=dict, repr=False)


@dataclass(frozen=True)
class Validation:
    """Predictions against a second measurement set: RMS and largest errors (norm of the
    3-vector difference, m/s²), the per-SU table, and per excited DoF its dynamic readings'
    errors (``dofs``: ``dof``, ``dynamic_rms``, ``dynamic_max``, ``dynamic_count``, ``floor``)."""

    poses: int
    static_rms: float
    static_max: float
    dynamic_rms: float
    dynamic_max: float
    sus: List[dict]
    dofs: List[dict] = field(default_factory=list)


def _dh_arrays(dh: Optional[dict]) -> Optional[Dict[str, Dict[str, np.ndarray]]]:
    if not dh:
        return None
    out = {}
    for table, rows in dh.items():
        if isinstance(rows, list) and rows:
            out[table] = {k: np.array([r[k] for r in rows]) for k in rows[0]}
    return out


class Model:
    """A calibrated body: per limb the fitted kinematics and SU poses with their uncertainties."""

    def __init__(self, native: "_skincal.NativeModel"):
        self._native = native

    @cached_property
    def _data(self) -> dict:
        return json.loads(self._native.to_json())

    @cached_property
    def _names(self) -> Tuple[List[str], List[str]]:
        return self._native.names()

    @classmethod
    def load(cls, path: Path) -> "Model":
        """Reads and checks a ``model.json`` file."""
        return cls(_skincal.NativeModel.load(_existing(path, "model")))

    def save(self, path: Path, force: bool = False) -> None:
        """Writes ``model.json`` byte for byte as ``skincal calibrate`` does, whole or not at
        all."""
        self._native.save(str(path), force)

    def to_json(self) -> str:
        return self._native.to_json()

    @property
    def dofs(self) -> List[str]:
        """The model's DoFs: the columns of :meth:`predict`'s poses."""
        return list(self._names[0])

    @property
    def sus(self) -> List[str]:
        """The model's SUs: the order of :meth:`predict`'s readings."""
        return list(self._names[1])

    @property
    def pattern(self) -> Tuple[float, float]:
        """The excitation pattern (A, f) of the training data."""
        p = self._data.get("pattern") or {"amplitude": PAPER_PATTERN[0], "frequency": PAPER_PATTERN[1]}
        return (p["amplitude"], p["frequency"])

    @property
    def limbs(self) -> List[Limb]:
        """The calibrated limbs."""
        frames = self.su_frames()
        out = []
        for limb in self._data["limbs"]:
            e = limb["estimate"]
            cov = e.get("joint_covariance") or {"dofs": [], "matrix": []}
            out.append(
                Limb(
                    name=limb["name"],
                    parent=limb.get("parent"),
                    dofs=limb["dofs"],
                    sus=limb["sus"],
                    converged=e["converged"],
                    residual=e["residual_ratio"],
                    su_poses={s: frames[s] for s in limb["sus"] if s in frames},
                    su_sd={u["su"]: (u["position_sd"], u["orientation_sd"]) for u in e["uncertainty"]},
                    su_undetermined={
                        u["su"]: {
                            "position": np.array(u.get("undetermined_position", []), dtype=float).reshape(-1, 3),
                            "orientation": np.array(u.get("undetermined_orientation", []), dtype=float).reshape(-1, 3),
                        }
                        for u in e["uncertainty"]
                        if u.get("undetermined_position") or u.get("undetermined_orientation")
                    },
                    joint_covariance=np.array(cov["matrix"], dtype=float).reshape(
                        4 * len(cov["dofs"]), 4 * len(cov["dofs"])
                    ),
                    joint_covariance_dofs=cov["dofs"],
                    gravity=np.array(limb["gravity"]),
                    dh=_dh_arrays(e.get("dh")),
                    details=e,
                )
            )
        return out

    def su_frames(self, pose: Optional[np.ndarray] = None) -> Dict[str, np.ndarray]:
        """Every SU's pose (4×4, m) in the body frame at ``pose`` (rad per model DoF; zero pose
        by default)."""
        q = np.zeros(len(self._names[0])) if pose is None else np.asarray(pose, dtype=np.float64)
        return dict(zip(self._names[1], self._native.su_frames([float(x) for x in q])))

    def predict(
        self, poses: np.ndarray, pattern: Optional[Tuple[float, float]] = None
    ) -> Tuple[np.ndarray, np.ndarray]:
        """The readings the model predicts at ``poses`` (N×D rad, or one pose of D): static
        (N×U×3) and the dynamic acceleration of ``pattern`` (default: the training data's) on each
        DoF (N×D×U×3), m/s², in the order of :attr:`dofs` and :attr:`sus`."""
        q = np.asarray(poses, dtype=np.float64)
        if not np.all(np.isfinite(q)):
            raise ValueError("poses: every angle must be a finite number of rad (found NaN or inf)")
        single = q.ndim == 1
        q = np.ascontiguousarray(q.reshape(1, -1) if single else q)
        p = self.pattern if pattern is None else (float(pattern[0]), float(pattern[1]))
        static, dynamic = self._native.predict(q, p)
        return (static[0], dynamic[0]) if single else (static, dynamic)

    def validate(self, other: Union[MeasurementSet, Path]) -> Validation:
        """Predicts ``other``'s training experiment (its poses and pattern) and compares;
        ``other`` may be the path of a measurement set or its directory."""
        v = json.loads(self._native.validate(_measurement_set(other)._native))
        return Validation(
            poses=v["poses"],
            static_rms=v["static_rms"],
            static_max=v["static_max"],
            dynamic_rms=v["dynamic_rms"],
            dynamic_max=v["dynamic_max"],
            sus=v["sus"],
            dofs=v.get("dofs", []),
        )

    def to_urdf(self) -> str:
        """The calibrated kinematics as URDF text, as ``skincal export-urdf`` writes it."""
        return self._native.to_urdf()

    def __repr__(self) -> str:
        converged = sum(l["estimate"]["converged"] for l in self._data["limbs"])
        return f"<Model: {len(self._data['limbs'])} limbs ({converged} converged), {len(self._names[1])} SUs>"


@dataclass
class SuCheck:
    """One SU's check: ``verdict`` is ``unchanged``, ``moved``, ``bias-changed``,
    ``scale-changed``, ``swapped``, ``reads-as``, ``other-segment``, ``broken`` or
    ``not-enough-motion``; ``detail`` its other fields (``with``, ``su``, ``segment``, ``how``:
    ``silent``, ``frozen``, ``railed``, ``dead``, ``noisy`` or ``erratic``); ``change`` the shift
    (m), turn (rad), bias change (m/s²) and relative change of each axis' sensitivity
    (``scale``) the log estimates, with their deviations."""

    su: str
    verdict: str
    detail: Dict[str, str]
    blocks: int
    p_value: float
    residual_ratio: float
    change: Optional[dict]
    untold: str
    never_told: str
    advice: str
    samples: Optional[dict] = None
    """How many samples the log held of it (``sent``, ``repeated``, ``unusable``) and the longest
    stretches of one repeated value and of unusable samples (``longest_repeat``,
    ``longest_unusable``, s)."""
    or_zero: Optional[dict] = None
    """For a moved (or scale-changed) SU that alone tells a DoF's zero: that zero (``dof``,
    ``offset``, ``offset_sd`` in rad), which reads the same as the change on this one SU."""


@dataclass
class CheckReport:
    """A skin checked against motion: one :class:`SuCheck` per SU of the model."""

    seconds: float
    sus: List[SuCheck]
    notes: List[str]
    zero: Optional[dict] = None
    """A DoF whose zero moved: ``dof``, ``offset`` and ``offset_sd`` (rad), ``sus``."""
    zeros_untold: List[str] = field(default_factory=list)
    """DoFs whose zero this log does not tell (too little of their motion, or no SU beyond them
    that the model still explains)."""
    zeros_never_told: List[str] = field(default_factory=list)
    """DoFs whose zero no motion tells (a vertical axis on the still reference segment)."""
    alike: List[List[str]] = field(default_factory=list)
    """Pairs of SUs that read alike in every pose (turned alike on the still reference segment):
    no motion tells an exchange of the two."""

    def changed(self) -> List[SuCheck]:
        """The SUs that do not read what the model predicts."""
        return [s for s in self.sus if s.verdict not in ("unchanged", "not-enough-motion")]


def _check_report(text: str) -> CheckReport:
    data = json.loads(text)
    sus = []
    for s in data["sus"]:
        verdict = dict(s["verdict"])
        kind = verdict.pop("kind")
        sus.append(
            SuCheck(
                su=s["su"],
                verdict=kind,
                detail=verdict,
                blocks=s["blocks"],
                p_value=s["p_value"],
                residual_ratio=s["residual_ratio"],
                change=s.get("change"),
                untold=s.get("untold", ""),
                never_told=s.get("never_told", ""),
                advice=s.get("advice", ""),
                samples=s.get("samples"),
                or_zero=s.get("or_zero"),
            )
        )
    return CheckReport(
        seconds=data["seconds"],
        sus=sus,
        notes=data.get("notes", []),
        zero=data.get("zero"),
        zeros_untold=data.get("zeros_untold", []),
        zeros_never_told=data.get("zeros_never_told", []),
        alike=data.get("alike", []),
    )


def _model(model: "Union[Model, Path]") -> "Model":
    return model if isinstance(model, Model) else Model.load(model)


def check(model: "Union[Model, Path]", logs: Sequence[Path]) -> CheckReport:
    """Whether every SU still reads what ``model`` predicts in logs of any motion of the robot
    (MCAP, rosbag2, ROS 1, CSV directories) or a ``motion.json``: as ``skincal check``."""
    paths = [_existing(p, "log") for p in logs]
    return _check_report(_skincal.check(_model(model)._native, paths))


class LiveCheck:
    """The check fed as the robot moves: joint states and skin samples pushed as they come (a ROS 2
    node's callbacks), a report at any moment, memory bounded however long it runs.

        >>> live = skincal.LiveCheck(model)
        >>> live.joints(stamp, names, positions)          # each JointState
        >>> live.imu(stamps, su_names, accelerations)      # skin samples, N×3 m/s²
        >>> report = live.report()                          # None during the first 10 s
    """

    def __init__(self, model: "Union[Model, Path]"):
        self._native = _skincal.NativeLiveCheck(_model(model)._native)

    def joints(self, stamp: float, names: Sequence[str], positions: Sequence[float]) -> None:
        """One joint state: stamp (s), joint names, positions (rad)."""
        self._native.joints(float(stamp), list(names), [float(x) for x in positions])

    def imu(self, stamps: Sequence[float], sus: Sequence[str], accelerations: np.ndarray) -> None:
        """Skin samples: N stamps (s), N SU names, N×3 specific forces (m/s²)."""
        a = np.ascontiguousarray(accelerations, dtype=np.float64).reshape(-1, 3)
        self._native.imu([float(t) for t in stamps], list(sus), a)

    def report(self) -> Optional[CheckReport]:
        """The check so far, or ``None`` before enough motion has come to judge the noise."""
        text = self._native.report()
        return None if text is None else _check_report(text)

    def held(self) -> Tuple[int, int, int]:
        """Joint states and skin blocks held by the stream, and blocks kept for the refit."""
        return self._native.held()


def simulate(
    robot: str,
    *,
    poses: int = 20,
    noise: float = 0.01,
    seed: int = 1,
    structure: bool = True,
    training: bool = True,
    tilted: bool = True,
    pose_seed: Optional[int] = None,
) -> MeasurementSet:
    """Simulates a robot's skin as ``skincal simulate`` does: ``robot`` is a built-in name
    (:func:`robots`), a ``.toml`` description or a URDF (one random SU per link); ``noise`` is
    uniform ±noise g on every reading component. The truth is in the result's ``truth``."""
    native, truth = _skincal.simulate(
        robot, poses, noise, seed, structure, training, tilted, pose_seed
    )
    return MeasurementSet(native, json.loads(truth))


def explore(measurements: Union[MeasurementSet, Path]) -> Structure:
    """Structural exploration (default settings): the kinematic tree from the structure
    experiment. ``measurements`` may be the path of a set or of its directory."""
    return Structure(_skincal.explore(_measurement_set(measurements)._native))


@dataclass(frozen=True)
class PaperLimb:
    """One chain as the paper's method estimated it (Fig. 6): ``dof_dof`` the DoF-to-DoF DH rows
    (theta0, d, a, alpha per row, rad and m), ``dof_su`` the DoF-to-SU rows (also theta_acc,
    d_acc), ``fixed`` the parameters the data cannot determine, ``steps`` the progressive steps
    (SU, excited DoFs, evaluations, seconds, e_T in g², NLopt's stop)."""

    name: str
    dofs: List[str]
    sus: List[str]
    dof_dof: np.ndarray
    dof_su: np.ndarray
    fixed: List[str]
    steps: List[dict]

    @property
    def converged(self) -> bool:
        """Whether every step reached e_T ≤ e_stop."""
        return all(s["converged"] for s in self.steps)

    @property
    def evaluations(self) -> int:
        return sum(s["evaluations"] for s in self.steps)


class PaperModel:
    """The paper's estimate of every serial chain: what ``skincal calibrate --method paper``
    writes to ``model-paper.json``."""

    def __init__(self, native: "_skincal.NativePaperModel"):
        self._native = native

    @cached_property
    def _data(self) -> dict:
        return json.loads(self._native.to_json())

    def save(self, path: Path, force: bool = False) -> None:
        """Writes ``model-paper.json``, whole or not at all."""
        self._native.save(str(path), force)

    def to_json(self) -> str:
        return self._native.to_json()

    @property
    def limbs(self) -> List[PaperLimb]:
        dh = ("theta0", "d", "a", "alpha")
        su = dh + ("theta_acc", "d_acc")
        return [
            PaperLimb(
                name=e["chain"]["name"],
                dofs=[d for j in e["chain"]["joints"] for d in j["dofs"]],
                sus=[u for j in e["chain"]["joints"] for u in j["sus"]],
                dof_dof=np.array([[r[k] for k in dh] for r in e["dof_dof"]]).reshape(-1, 4),
                dof_su=np.array([[r[k] for k in su] for r in e["dof_su"]]).reshape(-1, 6),
                fixed=list(e["fixed"]),
                steps=list(e["steps"]),
            )
            for e in self._data["limbs"]
        ]

    def su_frames(self, limb: str, pose: np.ndarray) -> Dict[str, np.ndarray]:
        """Each SU's frame (4×4, m) of chain ``limb`` at ``pose`` (one angle per DoF of the
        chain, rad), in the chain's base frame."""
        names = [l.name for l in self.limbs]
        if limb not in names:
            raise KeyError(f"limb {limb!r}: the model has {', '.join(names)}")
        i = names.index(limb)
        q = np.asarray(pose, dtype=float).ravel()
        frames = self._native.su_frames(i, q.tolist())
        return dict(zip(self.limbs[i].sus, frames))

    def __repr__(self) -> str:
        limbs = self.limbs
        done = sum(l.converged for l in limbs)
        return f"<PaperModel: {len(limbs)} chains, {done} converged>"


def calibrate(
    measurements: Union[MeasurementSet, Path],
    structure: Optional[Structure] = None,
    method: str = "ml",
    noise: Optional[float] = None,
    progress: Optional[Callable[[str, int, int], None]] = None,
    seed: int = 1,
    e_stop: float = 0.1,
    max_evaluations: int = 100_000,
) -> Union[Model, PaperModel]:
    """Kinematic estimation of every limb, as ``skincal calibrate``.

    ``method="ml"`` (the default) fits every limb by maximum likelihood and returns a
    :class:`Model`; ``noise`` (g, uniform) weights every reading alike instead of by its own
    standard deviation, as ``--noise``. ``method="paper"`` runs the paper's estimator
    (progressive MLSL-LDS + Nelder–Mead on e_T) on every serial chain and returns a
    :class:`PaperModel`; ``seed``, ``e_stop`` (g²) and ``max_evaluations`` (per step) are its
    settings, as ``--seed``, ``--e-stop`` and ``--max-evaluations``. ``structure`` defaults to
    exploring the set's structure experiment; ``progress(limb, done, total)`` is called as each
    limb is calibrated. ``measurements`` may be the path of a set or of its directory."""
    if method not in ("ml", "paper"):
        raise ValueError(f"method {method!r}: use 'ml' or 'paper'")
    measurements = _measurement_set(measurements)
    native_structure = None if structure is None else structure._native
    if method == "paper":
        if noise is not None:
            raise ValueError("noise: the paper's method weighs no reading; leave it out")
        native = _skincal.calibrate_paper(
            measurements._native, native_structure, seed, e_stop, max_evaluations, progress
        )
        return PaperModel(native)
    native = _skincal.calibrate(measurements._native, native_structure, noise, progress)
    return Model(native)


def ingest(
    logs: Sequence[Path],
    plan: Optional[Path] = None,
    pattern: Optional[Tuple[float, float]] = None,
    progress: Optional[Callable[[str, int, int], None]] = None,
) -> Tuple[MeasurementSet, dict]:
    """Reads robot logs (MCAP, rosbag2 directories with .mcap or .db3, ROS 1 bags, skincal's CSV
    directories) into a measurement set, as ``skincal ingest``: ``plan`` is the ``plan.json`` they
    follow (its pattern and still periods), ``pattern`` the nominal (A, f) instead;
    ``progress(stage, done, total)`` is called while the logs are read (on each new stage, at
    its end, and at most five times a second between). Returns the set and the
    report (windows found, excitations, coupled motion, warnings)."""
    native, report = _skincal.ingest(
        [_existing(p, "log") for p in logs],
        None if plan is None else _existing(plan, "plan"),
        None if pattern is None else (float(pattern[0]), float(pattern[1])),
        _throttled(progress),
    )
    return MeasurementSet(native), json.loads(report)


def plan(
    robot: str,
    protocol: str = "short",
    poses: Optional[int] = None,
    accuracy: Optional[float] = None,
    seed: int = 1,
) -> dict:
    """The exploration program for a robot, as ``skincal plan`` writes ``plan.json``: ``short``
    (limbs in parallel, as many poses as the forecast needs for ``accuracy`` m/s², 0.009 unless
    ``poses`` is given) or ``paper``. Its ``forecast`` is the held-out RMS it expects."""
    return json.loads(_skincal.plan(robot, protocol, poses, accuracy, seed))


def robots() -> Dict[str, str]:
    """The built-in robots: name → description (TOML)."""
    return _skincal.robots()
