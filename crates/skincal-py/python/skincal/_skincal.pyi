"""Type stubs of skincal's native module (the Python API is in `skincal`)."""

from typing import Callable, Dict, List, Optional, Tuple

import numpy as np
import numpy.typing as npt

__version__: str

class SkincalError(Exception):
    """An error of skincal: the message names the file, field or sensor and what to do."""

class Measurements:
    @staticmethod
    def load(path: str) -> "Measurements": ...
    @staticmethod
    def from_json(text: str) -> "Measurements": ...
    @staticmethod
    def from_arrays(
        dofs: List[str],
        sus: List[str],
        q: npt.NDArray[np.float64],
        statics: npt.NDArray[np.float64],
        dynamic: npt.NDArray[np.float64],
        pattern: Tuple[float, float],
        static_sd: Optional[npt.NDArray[np.float64]] = None,
        dynamic_sd: Optional[npt.NDArray[np.float64]] = None,
        structure: Optional[str] = None,
    ) -> "Measurements": ...
    def to_json(self) -> str: ...
    def save(self, path: str, force: bool = False) -> None: ...
    @property
    def dofs(self) -> List[str]: ...
    @property
    def sus(self) -> List[str]: ...
    def training(
        self,
    ) -> Optional[
        Tuple[
            npt.NDArray[np.float64],
            npt.NDArray[np.float64],
            npt.NDArray[np.float64],
            Tuple[float, float],
            Optional[npt.NDArray[np.float64]],
            Optional[npt.NDArray[np.float64]],
        ]
    ]: ...
    def structure_json(self) -> str: ...

class NativeStructure:
    @staticmethod
    def load(path: str) -> "NativeStructure": ...
    def to_json(self) -> str: ...
    def save(self, path: str, force: bool = False) -> None: ...

class NativeModel:
    @staticmethod
    def load(path: str) -> "NativeModel": ...
    def to_json(self) -> str: ...
    def save(self, path: str, force: bool = False) -> None: ...
    def predict(
        self, q: npt.NDArray[np.float64], pattern: Tuple[float, float]
    ) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]: ...
    def su_frames(self, q: List[float]) -> List[npt.NDArray[np.float64]]: ...
    def names(self) -> Tuple[List[str], List[str]]: ...
    def validate(self, other: Measurements) -> str: ...
    def to_urdf(self) -> str: ...

class NativePaperModel:
    def to_json(self) -> str: ...
    def save(self, path: str, force: bool = False) -> None: ...
    def su_frames(self, limb: int, q: List[float]) -> List[npt.NDArray[np.float64]]: ...

def simulate(
    robot: str,
    poses: int = 20,
    noise: float = 0.01,
    seed: int = 1,
    structure: bool = True,
    training: bool = True,
    tilted: bool = True,
    pose_seed: Optional[int] = None,
) -> Tuple[Measurements, str]: ...
def explore(measurements: Measurements) -> NativeStructure: ...
def calibrate(
    measurements: Measurements,
    structure: Optional[NativeStructure] = None,
    noise: Optional[float] = None,
    progress: Optional[Callable[[str, int, int], None]] = None,
) -> NativeModel: ...
def calibrate_paper(
    measurements: Measurements,
    structure: Optional[NativeStructure] = None,
    seed: int = 1,
    e_stop: float = 0.1,
    max_evaluations: int = 100000,
    progress: Optional[Callable[[str, int, int], None]] = None,
) -> NativePaperModel: ...
def ingest(
    logs: List[str],
    plan: Optional[str] = None,
    pattern: Optional[Tuple[float, float]] = None,
    progress: Optional[Callable[[str, int, int], None]] = None,
) -> Tuple[Measurements, str]: ...
def plan(
    robot: str,
    protocol: str = "short",
    poses: Optional[int] = None,
    accuracy: Optional[float] = None,
    seed: int = 1,
) -> str: ...
def robots() -> Dict[str, str]: ...
def check(model: NativeModel, logs: List[str]) -> str: ...

class NativeLiveCheck:
    def __init__(self, model: NativeModel) -> None: ...
    def joints(self, stamp: float, names: List[str], positions: List[float]) -> None: ...
    def imu(
        self, stamps: List[float], sus: List[str], accelerations: npt.NDArray[np.float64]
    ) -> None: ...
    def report(self) -> Optional[str]: ...
    def held(self) -> Tuple[int, int, int]: ...
def bench_calibrate(
    measurements: Measurements, structure: NativeStructure, repeats: int
) -> float: ...
