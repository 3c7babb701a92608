"""The run folder: everything a run produces, written as it happens.

Streams (events, trajectories, tree changes) are appended and flushed line by line, so that a
crash or Ctrl-C loses nothing already computed (a reader tolerates a torn last line); a stream
that cannot be written (a full disk) stops and says so at the end, it does not stop the flight; summaries
(metrics, map, plots, report) are written once at the end, on every exit path, each **atomically**:
to a temporary file beside it, then renamed over it, so a kill or a full disk mid-write leaves the
old file or none — never an empty or half-written ``metrics.json``.

The formats this module writes are read here too, so one module knows each of them: the TUM
trajectories (:func:`read_tum`, :func:`tum_values` for a stream read line by line), the JSON-lines
streams (:func:`read_jsonl`),
``landmarks.json`` (:func:`write_landmarks`, :func:`read_landmarks`) and ``metrics.json``
(:func:`read_metrics`). A file that cannot be read
is one :class:`~amslam.errors.RunFileError` naming the file and the line or record; only a torn
*last* line of a stream (a run stopped mid-write) is dropped, with a warning.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import tempfile
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

from amslam.errors import AmslamError, RunFileError
from amslam.geometry import tum_line
from amslam.types import Landmark

TRAJECTORIES = ("ground_truth", "vio", "slam")


def jsonable(value: Any) -> Any:
    """``value`` with numpy arrays and scalars, enums and non-finite floats made JSON-safe."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, np.generic):
        return jsonable(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if hasattr(value, "value") and hasattr(value, "name"):  # enums
        return value.value
    return value


def _read_umask() -> int:
    # os.umask can only be read by setting it; done once, at import, before any thread runs
    umask = os.umask(0)
    os.umask(umask)
    return umask


#: the process's file-creation mask, for files made by mkstemp (see write_atomically)
_UMASK = _read_umask()


def write_atomically(path: Path, data: str | bytes) -> Path:
    """Write ``data`` to ``path`` through a temporary file in the same folder and a rename.

    The rename is atomic on POSIX file systems: a reader (or a run killed mid-write) sees the old
    file or the new one, never a torn one. On failure (a full disk) the temporary file is removed
    and the error raised; the previous file, if any, is untouched.
    """
    path = Path(path)
    mode = "wb" if isinstance(data, bytes) else "w"
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        # mkstemp makes the file owner-only (0600), and the rename keeps that: a run's summary files
        # came out unreadable to the other users of a shared machine while its streams were not.
        # Give it the mode an ordinary open() would: 0666 less the umask.
        os.chmod(fd, 0o666 & ~_UMASK)
        with os.fdopen(fd, mode) as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    return path


def write_output(path: Path, text: str) -> Path:
    """A file the user named (``--out FILE``), its folder made if need be. Written in place, not
    atomically: it may be a special file (``/dev/stdout``) that a rename would replace. A place it
    cannot be written (``/proc``, a folder, a read-only disk) is one :class:`AmslamError`
    ``cannot write PATH: why``."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise AmslamError(f"cannot write {path}: {exc.strerror or exc}") from None
    return path


def new_folder(root: Path, name: str, what: str = "a run folder") -> Path:
    """``<root>/<name>``, or ``<name>-2``, ``-3``, … : ``mkdir`` itself decides, so processes that
    start in the same second never pick the same folder (checking ``exists`` first would race).

    Every output folder amslam creates (a run's, an experiment's) comes from here, so a ``--out``
    that cannot hold one (a file, ``/proc``, a read-only disk) is one :class:`AmslamError` saying
    ``cannot create WHAT in ROOT: why``."""
    try:
        root.mkdir(parents=True, exist_ok=True)
        for suffix in range(1, 10_000):
            path = root / (name if suffix == 1 else f"{name}-{suffix}")
            try:
                path.mkdir()
            except FileExistsError:
                continue
            return path
    except OSError as exc:  # a file where the folder should be, no permission, a read-only disk
        raise AmslamError(f"cannot create {what} in {root}: {exc.strerror or exc}") from None
    raise AmslamError(f"cannot create {what} in {root}: 10000 folders named {name}-* already")


class Stream:
    """One append-only stream of a run folder (``events.jsonl``, a trajectory), flushed line by line.

    A write, flush or close that fails (a full disk, a file-size limit) is remembered in
    :attr:`error`, never raised: a flight must not fall out of the air because its log cannot be
    written. The stream then stops (its last line may be torn, which every reader tolerates) and
    the runner reports it as an output error, like a summary file it could not write.
    """

    def __init__(self, path: Path):
        self.path = Path(path)
        self._file: IO[str] = open(self.path, "w")  # noqa: SIM115 — lives as long as the run
        #: the first failure, ``name: OSError: ...``, or None
        self.error: str | None = None

    @property
    def closed(self) -> bool:
        return self._file.closed

    def write(self, line: str) -> None:
        """Append ``line`` (ending in a newline) and flush it; nothing once the stream failed."""
        if self.error is not None or self._file.closed:
            return
        try:
            self._file.write(line)
            self._file.flush()
        except OSError as exc:
            self._failed(exc)
            with contextlib.suppress(OSError):  # what is buffered is lost with the disk space
                self._file.close()

    def close(self) -> None:
        if self._file.closed:
            return
        try:
            self._file.close()  # the file is closed even when its last flush fails
        except OSError as exc:
            self._failed(exc)

    def _failed(self, exc: OSError) -> None:
        if self.error is None:
            self.error = f"{self.path.name}: {type(exc).__name__}: {exc}"


class RunFiles:
    """The summary files of a run folder, each written atomically: what the runner and the
    run-end observers (an application such as the report, given only the folder) write."""

    def __init__(self, path: Path):
        self.path = Path(path)

    def write_text(self, name: str, text: str) -> Path:
        """A summary file of the run, written atomically (:func:`write_atomically`)."""
        return write_atomically(self.path / name, text)

    def write_yaml(self, name: str, data: Any) -> Path:
        # imported here, not at the top: `amslam plugins` and `--help` import this module (through the
        # applications) and read or write no YAML (issue #20)
        import yaml

        return self.write_text(name, yaml.safe_dump(jsonable(data), sort_keys=False))

    def write_json(self, name: str, data: Any) -> Path:
        return self.write_text(name, json.dumps(jsonable(data), indent=2) + "\n")

    def write_ply(self, name: str, points: np.ndarray) -> Path:
        """Points as an ASCII PLY (readable by Open3D, MeshLab, CloudCompare)."""
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        properties = "".join(f"property float {axis}\n" for axis in "xyz")
        header = f"ply\nformat ascii 1.0\nelement vertex {len(points)}\n{properties}end_header\n"
        body = "".join(f"{x:.3f} {y:.3f} {z:.3f}\n" for x, y, z in points)
        return self.write_text(name, header + body)

    def write_trajectory(self, which: str, stamps: list[float], poses: list[np.ndarray]) -> Path:
        """``<which>.tum`` as a whole (SLAM key poses change when the graph is optimised)."""
        return self.write_text(
            f"{which}.tum", "".join(tum_line(t, T) for t, T in zip(stamps, poses, strict=True))
        )


class RunDir(RunFiles):
    """One run's folder, ``<root>/<mission>-<timestamp>/``: its streams, and its files (:class:`RunFiles`)."""

    def __init__(self, root: Path, mission_name: str):
        stamp = time.strftime("%Y%m%d-%H%M%S")
        super().__init__(new_folder(Path(root), f"{mission_name}-{stamp}"))
        path = self.path
        self._events = Stream(path / "events.jsonl")
        self._tree = Stream(path / "tree.jsonl")
        self._tum: dict[str, Stream] = {}
        self._closed_streams: list[Stream] = []

    # -- streams ------------------------------------------------------------------------------

    def event(self, t: float, name: str, /, **fields: Any) -> None:
        """Append one event to ``events.jsonl`` (the run's clock ``t`` wins over a field of that name)."""
        record = {"t": round(float(t), 4), "event": name, **{k: v for k, v in fields.items() if k != "t"}}
        self._events.write(json.dumps(jsonable(record)) + "\n")

    def tree_change(self, record: dict[str, Any]) -> None:
        """Append one behaviour-tree change record to ``tree.jsonl``."""
        self._tree.write(json.dumps(jsonable(record)) + "\n")

    def pose(self, which: str, stamp: float, T: np.ndarray) -> None:
        """Append a pose to ``<which>.tum``."""
        f = self._tum.get(which)
        if f is None:
            f = self._tum[which] = Stream(self.path / f"{which}.tum")
        f.write(tum_line(stamp, T))

    def close_trajectories(self) -> None:
        """End the trajectory streams: the flight is over, and a run-end observer may replace a
        trajectory as a whole (:meth:`RunFiles.write_trajectory`) without a stream still open on it."""
        for f in self._tum.values():
            f.close()
        self._closed_streams += self._tum.values()
        self._tum.clear()

    def stream_errors(self) -> list[str]:
        """The streams that could not all be written (:attr:`Stream.error`), so far."""
        streams = (self._events, self._tree, *self._tum.values(), *self._closed_streams)
        return [f.error for f in streams if f.error is not None]

    def close(self) -> None:
        for f in (self._events, self._tree, *self._tum.values()):
            f.close()


# -- readers of the formats written above -------------------------------------------------------


def _read_text(path: Path) -> str:
    try:
        return Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:  # strerror: the OSError's text without the path again
        raise RunFileError(f"{path}: cannot be read ({getattr(exc, 'strerror', None) or exc})") from None


def _torn_last_line(path: Path, number: int, total: int, what: str, warnings: list[str] | None) -> bool:
    """Whether a malformed line is the last one: a run stopped mid-write. It is dropped, and said
    in ``warnings``; a malformed line before it is an error (the caller's)."""
    if number != total:
        return False
    if warnings is not None:
        warnings.append(f"{path}:{number}: {what} (a run stopped mid-write?): line dropped")
    return True


def read_jsonl(path: Path, warnings: list[str] | None = None) -> list[tuple[int, dict[str, Any]]]:
    """The records of a JSON-lines stream (``events.jsonl``, ``tree.jsonl``,
    ``measurements.jsonl``) with their line numbers; blank lines skipped, a torn last line dropped
    (and said in ``warnings``).

    Raises:
        RunFileError: the file cannot be read, or a line before the last is not a JSON object;
            ``FILE:LINE: what``.
    """
    lines = _read_text(path).splitlines()
    records = []
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError as exc:
            if _torn_last_line(path, number, len(lines), "not JSON", warnings):
                break
            raise RunFileError(f"{path}:{number}: not JSON ({exc.msg})") from None
        if not isinstance(record, dict):
            raise RunFileError(f"{path}:{number}: not a JSON object")
        records.append((number, record))
    return records


@dataclass(frozen=True)
class Trajectory:
    """A TUM trajectory: N stamps (s) and N×7 poses ``x y z qx qy qz qw`` (unit quaternions)."""

    stamps: np.ndarray
    poses: np.ndarray

    def __len__(self) -> int:
        return len(self.stamps)

    def matrices(self) -> np.ndarray:
        """The poses as N×4×4 transforms."""
        from scipy.spatial.transform import Rotation

        T = np.tile(np.eye(4), (len(self), 1, 1))
        if len(self):
            T[:, :3, :3] = Rotation.from_quat(self.poses[:, 3:7]).as_matrix()
            T[:, :3, 3] = self.poses[:, :3]
        return T


def tum_values(line: str) -> list[float] | None:
    """The eight finite numbers ``t x y z qx qy qz qw`` of a TUM line (:func:`~amslam.geometry.tum_line`);
    None for a blank line, a ``#`` comment or a malformed line (a reader that skips bad lines)."""
    text = line.strip()
    if not text or text.startswith("#"):
        return None
    try:
        values = [float(v) for v in text.split()]
    except ValueError:
        return None
    return values if len(values) == 8 and all(math.isfinite(v) for v in values) else None


def read_tum(path: Path, warnings: list[str] | None = None) -> Trajectory:
    """A whole ``<which>.tum``, checked: eight numbers a line (``#`` comments and blank lines
    allowed), time never going back, no zero quaternion; the quaternions normalised.

    A malformed *last* line is a run stopped mid-write: it is dropped and said in ``warnings``.

    Raises:
        RunFileError: the file cannot be read, or a line (other than the last) is bad;
            ``FILE:LINE: what``.
    """
    lines = _read_text(path).splitlines()
    stamps: list[float] = []
    poses: list[list[float]] = []
    for number, line in enumerate(lines, 1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        values = tum_values(text)
        if values is None:
            if _torn_last_line(path, number, len(lines), "not 8 numbers", warnings):
                break
            raise RunFileError(
                f"{path}:{number}: expected 8 numbers 't x y z qx qy qz qw', got {text[:60]!r}"
            )
        if stamps and values[0] < stamps[-1]:
            raise RunFileError(f"{path}:{number}: time {values[0]} goes back (previous {stamps[-1]})")
        norm = math.sqrt(sum(q * q for q in values[4:]))
        if norm < 1e-6:
            raise RunFileError(f"{path}:{number}: quaternion is zero")
        stamps.append(values[0])
        poses.append([*values[1:4], *(q / norm for q in values[4:])])
    return Trajectory(np.asarray(stamps, float), np.asarray(poses, float).reshape(-1, 7))


def _read_json(path: Path) -> Any:
    try:
        return json.loads(_read_text(path))
    except json.JSONDecodeError as exc:
        raise RunFileError(f"{path}:{exc.lineno}: not JSON ({exc.msg})") from None


def read_metrics(path: Path) -> dict[str, Any]:
    """``metrics.json`` (the runner's, :meth:`RunFiles.write_json`; the run folder or the file).

    Raises:
        RunFileError: the file cannot be read, is not JSON or not a JSON object; named.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "metrics.json"
    metrics = _read_json(path)
    if not isinstance(metrics, dict):
        raise RunFileError(f"{path}: not a JSON object")
    return metrics


def read_run_mission(path: Path) -> dict[str, Any]:
    """A run folder's ``mission.yaml`` (the mission as flown, every default filled in) as plain
    data (the run folder or the file). Not validated: a run of another version, or of plugins
    not installed here, still reads; use :func:`amslam.mission.load_mission` to fly it again.

    Raises:
        RunFileError: the file cannot be read, is not YAML or not a mapping; named.
    """
    import yaml

    path = Path(path)
    if path.is_dir():
        path = path / "mission.yaml"
    try:
        mission = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise RunFileError(f"{path}: cannot be read ({getattr(exc, 'strerror', None) or exc})") from None
    except yaml.YAMLError as exc:
        raise RunFileError(f"{path}: not readable YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(mission, dict):
        raise RunFileError(f"{path}: not a mission (a YAML mapping expected)")
    return mission


def landmark_records(landmarks: Iterable[Landmark]) -> list[dict[str, Any]]:
    """Landmarks as the records of ``landmarks.json``: ``id``, ``class``, ``position``,
    ``covariance`` (nulls where not finite: a backend without uncertainty), ``observations`` and,
    when fitted, ``shape``; when kept, ``class_probabilities`` (class → probability)."""
    return [
        jsonable(
            {
                "id": lm.id,
                "class": lm.class_name,
                "position": np.asarray(lm.position, float),
                "covariance": np.atleast_2d(np.asarray(lm.covariance, float)),
                "observations": lm.observations,
                **({"shape": lm.shape} if lm.shape else {}),
                **({"class_probabilities": lm.class_probabilities} if lm.class_probabilities else {}),
            }
        )
        for lm in landmarks
    ]


def write_landmarks(path: Path, landmarks: Sequence[Landmark]) -> Path:
    """``landmarks.json`` (:func:`landmark_records`), written atomically."""
    return write_atomically(Path(path), json.dumps(landmark_records(landmarks), indent=2) + "\n")


def _is_vector(value: Any, n: int) -> bool:
    return (
        isinstance(value, list)
        and len(value) == n
        and all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in value)
    )


def _is_covariance_row(value: Any) -> bool:
    return isinstance(value, list) and len(value) == 3 and all(v is None or _is_vector([v], 1) for v in value)


def read_landmarks(path: Path) -> list[dict[str, Any]]:
    """``landmarks.json``, checked: a list of ``{id?, class, position, covariance?, observations?,
    shape?, class_probabilities?}`` (:func:`landmark_records`). A covariance holding nulls
    (unknown) becomes None.

    Raises:
        RunFileError: the file cannot be read, is not JSON, or a record is malformed;
            ``FILE: landmark I: what``.
    """
    landmarks = _read_json(path)
    if not isinstance(landmarks, list):
        raise RunFileError(f"{path}: expected a JSON list of landmarks")
    for i, lm in enumerate(landmarks):
        where = f"{path}: landmark {i}"
        if (
            not isinstance(lm, dict)
            or not isinstance(lm.get("class"), str)
            or not _is_vector(lm.get("position"), 3)
        ):
            raise RunFileError(f"{where}: needs a 'class' string and a 'position' [x, y, z]")
        cov = lm.get("covariance")
        if cov is not None and not (
            isinstance(cov, list) and len(cov) == 3 and all(map(_is_covariance_row, cov))
        ):
            raise RunFileError(f"{where}: 'covariance' must be a 3×3 list of numbers (or nulls: unknown)")
        if cov is not None and any(v is None for row in cov for v in row):
            lm["covariance"] = None  # a backend without uncertainty (odometry SLAM) writes nulls
        shape = lm.get("shape")
        if shape is not None and not (isinstance(shape, dict) and isinstance(shape.get("model"), str)):
            raise RunFileError(f"{where}: 'shape' must be an object with a 'model'")
        probs = lm.get("class_probabilities")
        if probs is not None and not (
            isinstance(probs, dict)
            and all(isinstance(c, str) and _is_vector([p], 1) and 0 <= p <= 1 for c, p in probs.items())
        ):
            raise RunFileError(f"{where}: 'class_probabilities' must map class names to numbers in [0, 1]")
    return landmarks
