"""Trajectories from other systems (OpenVINS, ORB-SLAM3, VINS-Fusion, …) in the same comparison as agrivio's runs.

A researcher runs another system on the EuRoC export of a sequence (``agrivio simulate --euroc``: body frame ``S``
= the IMU) and passes its TUM file as ``--external NAME=path.tum`` to ``agrivio compare`` or ``agrivio replay``.
The estimate is evaluated exactly like agrivio's VIO runs of that sequence — same ground truth, association,
alignment and lever arm (:func:`pipeline.report_stage.options_for` of a VIO record) — and becomes a run record
labelled ``external: NAME``, so it is a row of every table and a path of every figure, marked as external.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from eval.errors import EvalInputError
from eval.evaluate import EvalOptions, Evaluation, evaluate
from eval.records import RunRecord
from eval.trajectory import Trajectory, read_tum
from pipeline.errors import AgrivioError

EXTERNAL_PREFIX = "external"


@dataclass(frozen=True)
class ExternalTrack:
    """One external estimate: ``name`` (as given), the TUM ``path`` and its ``trajectory`` (stamps in seconds on
    the bag clock, positions in metres, body = IMU as in the EuRoC export); ``sequence`` it belongs to when given
    as ``NAME@SEQUENCE=path`` (None: the only sequence of the comparison)."""

    name: str
    path: Path
    trajectory: Trajectory
    sequence: str | None = None

    @property
    def label(self) -> str:
        """How it appears in tables, figures and the replay: ``external: NAME``."""
        return f"{EXTERNAL_PREFIX}: {self.name}"


def parse_external(spec: str) -> tuple[str, str | None, Path]:
    """``NAME[@SEQUENCE]=path.tum`` → ``(NAME, SEQUENCE or None, path)``; AgrivioError (one line) for a spec
    without ``=`` or with an empty part."""
    name, sep, path = spec.partition("=")
    name, path = name.strip(), path.strip()
    name, at, sequence = name.partition("@")
    name, sequence = name.strip(), sequence.strip()
    if not sep or not name or not path or (at and not sequence):
        raise AgrivioError(f"--external {spec!r}: expected NAME=path.tum or NAME@SEQUENCE=path.tum "
                           f"(e.g. openvins=traj_openvins.tum)")
    if any(c in name for c in "/\\"):
        raise AgrivioError(f"--external {spec!r}: NAME must not contain a path separator")
    return name, sequence or None, Path(path)


def load_external(specs: Sequence[str]) -> list[ExternalTrack]:
    """Parse and read every ``--external`` spec (in order); AgrivioError naming the file and the problem."""
    tracks: list[ExternalTrack] = []
    seen: set[str] = set()
    for spec in specs:
        name, sequence, path = parse_external(spec)
        if name in seen:
            raise AgrivioError(f"--external {spec!r}: the name {name!r} is given twice")
        seen.add(name)
        if not path.is_file():
            raise AgrivioError(f"{path}: external trajectory ({name}) not found")
        try:
            traj = read_tum(path)
        except EvalInputError as exc:
            raise AgrivioError(f"external trajectory ({name}): {exc}") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise AgrivioError(f"{path}: external trajectory ({name}) unreadable ({type(exc).__name__})") from None
        if len(traj) < 3:
            raise AgrivioError(f"{path}: external trajectory ({name}) has {len(traj)} pose(s); need at least 3")
        tracks.append(ExternalTrack(name, path, traj, sequence))
    return tracks


def evaluate_external(track: ExternalTrack, ref: Trajectory, options: EvalOptions) -> Evaluation:
    """``track`` against ``ref`` with ``options``; AgrivioError naming the file when they cannot be compared."""
    opts = options
    if opts.lever_arm_m is not None and not track.trajectory.has_orientation:
        raise AgrivioError(f"{track.path}: external trajectory ({track.name}) has no orientation (identity "
                           f"quaternions), so the GT lever arm cannot be applied")
    try:
        return evaluate(ref, track.trajectory, opts)
    except EvalInputError as exc:
        raise AgrivioError(f"{track.path}: external trajectory ({track.name}) cannot be compared with the ground "
                           f"truth: {exc}") from None


def external_record(track: ExternalTrack, sequence: str, gt_path: str, evaluation: Evaluation) -> RunRecord:
    """A run record of an evaluated external estimate (variant ``external:NAME``, label ``external: NAME``)."""
    return RunRecord(sequence=sequence, variant=f"{EXTERNAL_PREFIX}:{track.name}", seed=0,
                     metrics=evaluation.metrics(), estimate_path=str(track.path.resolve()), gt_path=gt_path,
                     label=track.label,
                     extra={"external": True, "source": str(track.path),
                            "eval_options": evaluation.options.to_dict()})


def is_external(rec: RunRecord) -> bool:
    """Whether a record stands for an external estimate."""
    return bool(rec.extra.get("external")) or rec.variant.startswith(EXTERNAL_PREFIX + ":")
