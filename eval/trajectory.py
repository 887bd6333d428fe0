"""The trajectory type and its text formats (TUM, EuRoC ground truth).

A :class:`Trajectory` is a time-ordered list of poses ``T_world_body``: stamps in seconds, positions in metres
(frame: the trajectory's world frame) and orientations as unit quaternions in scipy's ``xyzw`` order. A
trajectory whose orientation is unknown (Rosario's GPS-RTK ground truth: identity quaternions everywhere) has
``has_orientation=False``; its quaternions are then identity and must not be used for rotation errors.

I/O functions return or take text; writing files atomically is the pipeline's job.
"""

from __future__ import annotations

import io
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from eval.errors import EvalInputError
from eval.quat import qmul

__all__ = ["Trajectory", "read_tum", "parse_tum", "format_tum", "format_tum_rows", "write_tum",
           "read_euroc_gt", "parse_euroc_gt"]

_IDENTITY_TOL = 1e-9


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Poses ``T_world_body`` over time.

    Attributes:
        stamps_s: (N,) float64, seconds, strictly increasing.
        positions: (N, 3) float64, metres, body origin in the world frame.
        quats_xyzw: (N, 4) float64, unit quaternions (x, y, z, w) of ``R_world_body``.
        has_orientation: False when orientations are unknown (all identity in the source file).
    """

    stamps_s: np.ndarray
    positions: np.ndarray
    quats_xyzw: np.ndarray
    has_orientation: bool = True

    def __post_init__(self) -> None:
        # private copies, so that later changes to the caller's arrays do not reach the trajectory. The arrays stay
        # writeable (scipy's Rotation.apply rejects read-only input) but must be treated as read-only.
        stamps = np.array(self.stamps_s, dtype=np.float64, copy=True).reshape(-1)
        positions = np.array(self.positions, dtype=np.float64, copy=True)
        quats = np.array(self.quats_xyzw, dtype=np.float64, copy=True)
        n = stamps.shape[0]
        if positions.shape != (n, 3):
            raise EvalInputError(f"trajectory positions must have shape ({n}, 3), got {positions.shape}")
        if quats.shape != (n, 4):
            raise EvalInputError(f"trajectory quaternions must have shape ({n}, 4), got {quats.shape}")
        if not (np.all(np.isfinite(stamps)) and np.all(np.isfinite(positions)) and np.all(np.isfinite(quats))):
            raise EvalInputError("trajectory contains NaN or infinite values")
        if n > 1 and np.any(np.diff(stamps) <= 0.0):
            i = int(np.flatnonzero(np.diff(stamps) <= 0.0)[0])
            raise EvalInputError(f"trajectory stamps must increase strictly (pose {i + 1} at {stamps[i + 1]!r} s "
                                 f"follows {stamps[i]!r} s)")
        norms = np.linalg.norm(quats, axis=1)
        if n and np.any(norms < 1e-6):
            raise EvalInputError("trajectory contains a zero quaternion")
        if n:
            quats = quats / norms[:, None]
        object.__setattr__(self, "stamps_s", stamps)
        object.__setattr__(self, "positions", positions)
        object.__setattr__(self, "quats_xyzw", quats)
        object.__setattr__(self, "has_orientation", bool(self.has_orientation))

    # ---- construction -------------------------------------------------------------------------------------------
    @classmethod
    def from_positions(cls, stamps_s: np.ndarray, positions: np.ndarray) -> Trajectory:
        """A position-only trajectory (identity quaternions, ``has_orientation=False``)."""
        stamps = np.asarray(stamps_s, dtype=np.float64).reshape(-1)
        quats = np.zeros((stamps.shape[0], 4))
        quats[:, 3] = 1.0
        return cls(stamps, positions, quats, has_orientation=False)

    # ---- accessors ----------------------------------------------------------------------------------------------
    def __len__(self) -> int:
        return int(self.stamps_s.shape[0])

    @property
    def rotations(self) -> Rotation:
        """``R_world_body`` for every pose as one scipy ``Rotation`` (identity when ``has_orientation`` is False)."""
        return Rotation.from_quat(self.quats_xyzw)

    @property
    def duration_s(self) -> float:
        """Time from the first to the last pose, seconds (0 for fewer than 2 poses)."""
        return float(self.stamps_s[-1] - self.stamps_s[0]) if len(self) > 1 else 0.0

    def path_length_m(self) -> float:
        """Distance travelled along the positions, metres."""
        if len(self) < 2:
            return 0.0
        return float(np.linalg.norm(np.diff(self.positions, axis=0), axis=1).sum())

    def distances_m(self) -> np.ndarray:
        """(N,) cumulative distance travelled at each pose, metres (0 at the first pose)."""
        out = np.zeros(len(self))
        if len(self) > 1:
            np.cumsum(np.linalg.norm(np.diff(self.positions, axis=0), axis=1), out=out[1:])
        return out

    def subset(self, index: np.ndarray) -> Trajectory:
        """The poses at ``index`` (integer indices or a boolean mask), same ``has_orientation``."""
        return Trajectory(self.stamps_s[index], self.positions[index], self.quats_xyzw[index],
                          has_orientation=self.has_orientation)

    def transformed(self, rotation: np.ndarray, translation: np.ndarray, scale: float = 1.0) -> Trajectory:
        """Apply ``p' = s·R·p + t`` and ``R'_world_body = R·R_world_body`` (R (3,3), t (3,) metres).

        Orientations of a position-only trajectory stay identity.
        """
        rot = np.asarray(rotation, dtype=np.float64).reshape(3, 3)
        t = np.asarray(translation, dtype=np.float64).reshape(3)
        positions = scale * self.positions @ rot.T + t
        if self.has_orientation:
            quats = qmul(Rotation.from_matrix(rot).as_quat(), self.quats_xyzw)
        else:
            quats = self.quats_xyzw
        return Trajectory(self.stamps_s, positions, quats, has_orientation=self.has_orientation)


# ---- TUM ----------------------------------------------------------------------------------------------------------
def _all_identity(quats: np.ndarray) -> bool:
    if quats.shape[0] == 0:
        return True
    q = quats / np.linalg.norm(quats, axis=1, keepdims=True)
    return bool(np.all(np.abs(q[:, :3]) < _IDENTITY_TOL) and np.all(np.abs(np.abs(q[:, 3]) - 1.0) < _IDENTITY_TOL))


def _parse_tum_fast(text: str) -> Trajectory | None:
    """numpy's C parser for well-formed files; None when anything is off (the line-by-line parser then finds
    the offending line and raises with its number)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "input contained no data": the slow path reports it
            data = np.loadtxt(io.StringIO(text, newline=None), comments="#", dtype=np.float64, ndmin=2)
    except ValueError:
        return None
    if data.ndim != 2 or data.shape[0] == 0 or data.shape[1] != 8 or not np.all(np.isfinite(data)):
        return None
    if np.any(np.diff(data[:, 0]) <= 0.0) or np.any(np.sum(np.abs(data[:, 4:8]), axis=1) < 1e-6):
        return None
    quats = data[:, 4:8]
    return Trajectory(data[:, 0], data[:, 1:4], quats, has_orientation=not _all_identity(quats))


def parse_tum(text: str, source: str = "<text>") -> Trajectory:
    """Parse TUM text: one pose a line, ``t x y z qx qy qz qw`` (seconds, metres, xyzw), separated by whitespace.

    LF or CRLF line ends, ``#`` comments (whole lines or trailing) and blank lines are accepted. Lines must be in
    strictly increasing time. If every quaternion is the identity the trajectory is position-only
    (``has_orientation=False``), as in Rosario's GPS ground truth.

    Raises:
        EvalInputError: naming ``source`` and the line number of a malformed line, or when there is no pose.
    """
    fast = _parse_tum_fast(text)
    if fast is not None:
        return fast
    rows: list[list[float]] = []
    linenos: list[int] = []
    for lineno, raw in enumerate(io.StringIO(text, newline=None), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        if len(parts) != 8:
            raise EvalInputError(f"{source}:{lineno}: expected 8 numbers 't x y z qx qy qz qw', got {len(parts)} "
                                 f"fields: {line[:80]!r}")
        try:
            values = [float(v) for v in parts]
        except ValueError:
            raise EvalInputError(f"{source}:{lineno}: not a number in {line[:80]!r}") from None
        if not all(np.isfinite(values)):
            raise EvalInputError(f"{source}:{lineno}: NaN or infinite value in {line[:80]!r}")
        if abs(values[4]) + abs(values[5]) + abs(values[6]) + abs(values[7]) < 1e-6:
            raise EvalInputError(f"{source}:{lineno}: zero quaternion in {line[:80]!r}")
        if rows and values[0] <= rows[-1][0]:
            raise EvalInputError(f"{source}:{lineno}: time stamp {parts[0]} does not increase (previous line "
                                 f"{linenos[-1]} has {rows[-1][0]!r})")
        rows.append(values)
        linenos.append(lineno)
    if not rows:
        raise EvalInputError(f"{source}: no poses (empty file or only comments)")
    data = np.asarray(rows, dtype=np.float64)
    quats = data[:, 4:8]
    return Trajectory(data[:, 0], data[:, 1:4], quats, has_orientation=not _all_identity(quats))


def read_tum(path: Path | str) -> Trajectory:
    """Read a TUM trajectory file (see :func:`parse_tum`); errors name the file and line."""
    p = Path(path)
    try:
        text = p.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise EvalInputError(f"{p}: no such file") from None
    except IsADirectoryError:
        raise EvalInputError(f"{p}: is a directory, expected a TUM trajectory file") from None
    except UnicodeDecodeError as exc:
        raise EvalInputError(f"{p}: not a text file ({exc.reason} at byte {exc.start})") from None
    return parse_tum(text, source=str(p))


def format_tum(traj: Trajectory, header: str | None = None) -> str:
    """TUM text of ``traj`` (LF line ends; stamps with 9 decimals, positions and quaternions with 9).

    ``header``, if given, is written as ``#`` comment lines first. Reading the text back with :func:`parse_tum`
    gives the same poses to within 1e-9.
    """
    return format_tum_rows(traj.stamps_s, traj.positions, traj.quats_xyzw, header)


def format_tum_rows(stamps_s: np.ndarray, positions: np.ndarray, quats_xyzw: np.ndarray,
                    header: str | None = None) -> str:
    """TUM text ``t x y z qx qy qz qw`` of raw arrays, written as given (no checks, no renormalisation): the one
    TUM writer, behind :func:`format_tum`.

    Args:
        stamps_s: (N,) seconds.  positions: (N, 3) metres.  quats_xyzw: (N, 4) unit quaternions.
        header: ``#`` comment lines written first (none when None or empty).
    """
    buf = io.StringIO()
    if header:
        for line in header.splitlines():
            buf.write(f"# {line}\n")
    data = np.column_stack([stamps_s, positions, quats_xyzw])
    if len(data):
        np.savetxt(buf, data, fmt="%.9f", delimiter=" ", newline="\n")
    return buf.getvalue()


def write_tum(traj: Trajectory, header: str | None = None) -> str:
    """Alias of :func:`format_tum`: returns the text; the caller writes it (atomically)."""
    return format_tum(traj, header=header)


# ---- EuRoC --------------------------------------------------------------------------------------------------------
def parse_euroc_gt(text: str, source: str = "<text>") -> Trajectory:
    """Parse EuRoC ``state_groundtruth_estimate0/data.csv``.

    Columns: ``timestamp [ns], p_RS_R_x, p_RS_R_y, p_RS_R_z [m], q_RS_w, q_RS_x, q_RS_y, q_RS_z, v..., b_w...,
    b_a...``; only the first 8 are used. Comma separated, ``#`` header. Quaternions are converted from wxyz to xyzw.
    Stamps are converted to seconds as ``ns // 10**9 + (ns % 10**9)·1e-9`` to keep nanosecond resolution.
    """
    ns_list: list[int] = []
    rows: list[list[float]] = []
    for lineno, raw in enumerate(io.StringIO(text, newline=None), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = [f.strip() for f in line.split(",")]
        if len(parts) < 8:
            raise EvalInputError(f"{source}:{lineno}: expected at least 8 comma-separated fields "
                                 f"'t_ns, px, py, pz, qw, qx, qy, qz', got {len(parts)}")
        try:
            ns = int(parts[0])
            values = [float(v) for v in parts[1:8]]
        except ValueError:
            raise EvalInputError(f"{source}:{lineno}: not a number in {line[:80]!r}") from None
        if not all(np.isfinite(values)):
            raise EvalInputError(f"{source}:{lineno}: NaN or infinite value")
        if ns_list and ns <= ns_list[-1]:
            raise EvalInputError(f"{source}:{lineno}: time stamp {ns} ns does not increase")
        ns_list.append(ns)
        rows.append(values)
    if not rows:
        raise EvalInputError(f"{source}: no poses (empty file or only comments)")
    ns_arr = np.asarray(ns_list, dtype=np.int64)
    stamps = (ns_arr // 1_000_000_000).astype(np.float64) + (ns_arr % 1_000_000_000).astype(np.float64) * 1e-9
    data = np.asarray(rows, dtype=np.float64)
    quats_xyzw = data[:, [4, 5, 6, 3]]
    return Trajectory(stamps, data[:, 0:3], quats_xyzw, has_orientation=not _all_identity(quats_xyzw))


def read_euroc_gt(path: Path | str) -> Trajectory:
    """Read a EuRoC ground-truth CSV file (see :func:`parse_euroc_gt`); errors name the file and line."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise EvalInputError(f"{p}: no such file") from None
    except UnicodeDecodeError as exc:
        raise EvalInputError(f"{p}: not a text file ({exc.reason})") from None
    return parse_euroc_gt(text, source=str(p))
