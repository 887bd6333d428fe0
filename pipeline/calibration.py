"""Calibration I/O: Kalibr camchain YAML and ROS ``camera_info`` → :class:`msckf.camera.StereoRig`, and back.

Conventions (Kalibr, see rosario.md §4):

* ``camX/T_cam_imu`` (4×4) maps IMU-frame points into camera X; ``cam1/T_cn_cnm1`` maps cam0 points into cam1.
  The rig uses ``T_left_imu = cam0/T_cam_imu`` and ``T_right_left = cam1/T_cn_cnm1`` (as S-MSCKF does; the
  redundant ``cam1/T_cam_imu`` is read but not used for the rig). When ``cam1/T_cam_imu`` disagrees with
  ``cam1/T_cn_cnm1 · cam0/T_cam_imu`` by more than :data:`CAMCHAIN_TOL_DEG` / :data:`CAMCHAIN_TOL_M` (the shipped
  Rosario camchain: 0.29°, camera centres 1.5 mm apart — 1.8 mm between the translation vectors), one warning
  line per file says so and which one is used: the stereo extrinsic ``T_cn_cnm1`` that Kalibr estimates
  directly between the cameras, which rectification needs.
* ``intrinsics: [fx, fy, cx, cy]`` in pixels of the raw (distorted) image; ``distortion_model: radtan`` with
  ``distortion_coeffs: [k1, k2, p1, p2]``; ``resolution: [width, height]``.
* ``camera_info``: K (3×3), D (plumb_bob ``k1 k2 p1 p2 k3``), R (3×3 rectification rotation), P (3×4 rectified
  projection). A loader takes R and P from camera_info rather than recomputing them (rosario.md §4.2).

Errors are :class:`CalibrationError` (an ``AgrivioError``), whose message names the file and the problem.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from msckf.camera import PinholeRadtan, StereoRig
from pipeline.atomic import write_text_atomic
from pipeline.errors import AgrivioError


class CalibrationError(AgrivioError):
    """A calibration file (camchain YAML) or camera_info is missing data or holds inconsistent values."""

    def __init__(self, path: Path | str, problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")


@dataclass(frozen=True)
class CameraInfo:
    """The calibration part of one ``sensor_msgs/CameraInfo`` message (bag-independent).

    Attributes:
        width, height: image size in pixels.
        distortion_model: ROS name, ``"plumb_bob"`` for Rosario.
        K: (3, 3) raw intrinsics, pixels.  D: (n,) distortion coefficients.
        R: (3, 3) rectification rotation (``p_rect = R @ p_cam``).  P: (3, 4) rectified projection, pixels.
    """

    width: int
    height: int
    distortion_model: str
    K: np.ndarray
    D: np.ndarray
    R: np.ndarray
    P: np.ndarray


@dataclass(frozen=True)
class Camchain:
    """A parsed two-camera Kalibr camchain.

    Attributes:
        left, right: raw camera models (cam0, cam1).
        T_left_imu: (4, 4) ``cam0/T_cam_imu``.  T_right_left: (4, 4) ``cam1/T_cn_cnm1``.
        T_right_imu: (4, 4) ``cam1/T_cam_imu`` if present, else ``T_right_left @ T_left_imu``.
        timeshift_s: ``cam0/timeshift_cam_imu`` in seconds (t_imu = t_cam + shift).
        topics: ``(cam0 rostopic, cam1 rostopic)``, empty strings if absent.
    """

    left: PinholeRadtan
    right: PinholeRadtan
    T_left_imu: np.ndarray
    T_right_left: np.ndarray
    T_right_imu: np.ndarray
    timeshift_s: float = 0.0
    topics: tuple[str, str] = ("", "")

    def rig(self, alpha: float = 0.0) -> StereoRig:
        """Stereo rig with rectification computed by ``cv2.stereoRectify`` (``alpha=0`` like the Rosario bags)."""
        return StereoRig.from_extrinsics(self.left, self.right, self.T_right_left, self.T_left_imu, alpha=alpha)


# ---- reading ---------------------------------------------------------------------------------------------------
def _get(node: Any, key: str, path: Path, where: str) -> Any:
    if not isinstance(node, dict) or key not in node:
        raise CalibrationError(path, f"missing key {where}{key}")
    return node[key]


def _array(value: Any, shape: tuple[int, ...], path: Path, name: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise CalibrationError(path, f"{name} must be numbers of shape {shape}, got {value!r}") from None
    if arr.shape != shape:
        raise CalibrationError(path, f"{name} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise CalibrationError(path, f"{name} holds non-finite values")
    return arr


def _camera(node: dict, name: str, path: Path) -> PinholeRadtan:
    if not isinstance(node, dict):
        raise CalibrationError(path, f"{name} must be a mapping of Kalibr camera fields")
    model = node.get("camera_model", "pinhole")
    if model != "pinhole":
        raise CalibrationError(path, f"{name}/camera_model is {model!r}; only 'pinhole' is supported")
    dist_model = node.get("distortion_model", "radtan")
    if dist_model not in ("radtan", "plumb_bob"):
        raise CalibrationError(path, f"{name}/distortion_model is {dist_model!r}; only 'radtan' is supported")
    fx, fy, cx, cy = _array(_get(node, "intrinsics", path, f"{name}/"), (4,), path, f"{name}/intrinsics")
    dist = np.asarray(_get(node, "distortion_coeffs", path, f"{name}/"), dtype=np.float64).reshape(-1)
    if dist.size not in (4, 5):
        raise CalibrationError(path, f"{name}/distortion_coeffs must hold 4 radtan coefficients, got {dist.size}")
    w, h = _array(_get(node, "resolution", path, f"{name}/"), (2,), path, f"{name}/resolution")
    try:
        return PinholeRadtan(int(w), int(h), float(fx), float(fy), float(cx), float(cy), tuple(float(d) for d in dist))
    except ValueError as exc:
        raise CalibrationError(path, f"{name}: {exc}") from None


def _load_yaml(path: Path) -> dict:
    if not path.is_file():
        raise CalibrationError(path, "calibration file not found")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise CalibrationError(path, f"not valid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise CalibrationError(path, "not a Kalibr camchain (top level is not a mapping)")
    return data


def _transform(value: Any, path: Path, name: str) -> np.ndarray:
    T = _array(value, (4, 4), path, name)
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or abs(np.linalg.det(R) - 1.0) > 1e-4:
        raise CalibrationError(path, f"{name} does not hold a rotation matrix")
    if not np.allclose(T[3], [0, 0, 0, 1]):
        raise CalibrationError(path, f"{name} last row must be [0, 0, 0, 1]")
    return T


#: Largest disagreement between ``cam1/T_cam_imu`` and ``cam1/T_cn_cnm1 · cam0/T_cam_imu`` left unmentioned.
CAMCHAIN_TOL_DEG = 0.05
CAMCHAIN_TOL_M = 0.5e-3
_WARNED: set[str] = set()  # camchain files already warned about in this process
_WARNED_ENV = "AGRIVIO_CAMCHAIN_WARNED"  # ... and in its parent (spawned workers inherit the environment)


def camchain_discrepancy(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """(rotation angle in degrees, translation in metres) of ``T_a · T_b⁻¹`` for two 4×4 transforms.

    For two camera-from-IMU transforms the translation is the distance between the two camera centres.
    """
    D = T_a @ np.linalg.inv(T_b)
    cos = np.clip((np.trace(D[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.degrees(np.arccos(cos))), float(np.linalg.norm(D[:3, 3]))


def _warn_if_inconsistent(path: Path, T_right_imu: np.ndarray, T_chained: np.ndarray) -> None:
    deg, m = camchain_discrepancy(T_right_imu, T_chained)
    key = str(path.resolve())
    # worker processes inherit the environment: a camchain the parent warned about is not warned about again
    inherited = set(os.environ.get(_WARNED_ENV, "").split(os.pathsep)) - {""}
    if (deg > CAMCHAIN_TOL_DEG or m > CAMCHAIN_TOL_M) and key not in _WARNED | inherited:
        _WARNED.add(key)
        os.environ[_WARNED_ENV] = os.pathsep.join(sorted(_WARNED | inherited))
        print(f"warning: {path}: cam1/T_cam_imu differs from cam1/T_cn_cnm1 · cam0/T_cam_imu by {deg:.2f}° and "
              f"{m * 1e3:.1f} mm (camera centre); using cam0/T_cam_imu and cam1/T_cn_cnm1 (the direct "
              f"camera-to-camera estimate that rectification needs, as S-MSCKF does); cam1/T_cam_imu is ignored",
              file=sys.stderr)


def read_camchain(path: Path | str) -> Camchain:
    """Parse a Kalibr camchain YAML with ``cam0`` (left) and ``cam1`` (right)."""
    path = Path(path)
    data = _load_yaml(path)
    cam0 = _get(data, "cam0", path, "")
    cam1 = _get(data, "cam1", path, "")
    left = _camera(cam0, "cam0", path)
    right = _camera(cam1, "cam1", path)
    if left.size != right.size:
        raise CalibrationError(path, f"cam0 resolution {left.size} differs from cam1 resolution {right.size}")
    T_left_imu = _transform(_get(cam0, "T_cam_imu", path, "cam0/"), path, "cam0/T_cam_imu")
    T_right_left = _transform(_get(cam1, "T_cn_cnm1", path, "cam1/"), path, "cam1/T_cn_cnm1")
    if "T_cam_imu" in cam1:
        T_right_imu = _transform(cam1["T_cam_imu"], path, "cam1/T_cam_imu")
        _warn_if_inconsistent(path, T_right_imu, T_right_left @ T_left_imu)
    else:
        T_right_imu = T_right_left @ T_left_imu
    return Camchain(left, right, T_left_imu, T_right_left, T_right_imu,
                    timeshift_s=float(cam0.get("timeshift_cam_imu", 0.0)),
                    topics=(str(cam0.get("rostopic", "")), str(cam1.get("rostopic", ""))))


def rig_from_camchain(path: Path | str, alpha: float = 0.0) -> StereoRig:
    """Kalibr camchain YAML → stereo rig, rectification from ``cv2.stereoRectify`` with ``alpha``."""
    chain = read_camchain(path)
    try:
        return chain.rig(alpha)
    except ValueError as exc:
        raise CalibrationError(path, f"cannot build a stereo rig: {exc}") from None


def _camera_from_info(info: CameraInfo, side: str, source: Path) -> PinholeRadtan:
    if info.distortion_model not in ("plumb_bob", "radtan"):
        raise CalibrationError(source, f"{side} camera_info distortion_model is {info.distortion_model!r}; "
                                       "only 'plumb_bob' is supported")
    K = _array(info.K, (3, 3), source, f"{side} camera_info K")
    D = np.asarray(info.D, dtype=np.float64).reshape(-1)
    if D.size not in (4, 5):
        raise CalibrationError(source, f"{side} camera_info D must hold 4 or 5 plumb_bob coefficients, got {D.size}")
    try:
        return PinholeRadtan(int(info.width), int(info.height), float(K[0, 0]), float(K[1, 1]), float(K[0, 2]),
                             float(K[1, 2]), tuple(float(d) for d in D))
    except ValueError as exc:
        raise CalibrationError(source, f"{side} camera_info: {exc}") from None


def rig_from_camera_info(left: CameraInfo, right: CameraInfo, camchain: Path | str | Camchain,
                         source: Path | str = "camera_info") -> StereoRig:
    """Stereo rig from the bag's camera_info (K, D, R, P, size) plus camchain extrinsics.

    Args:
        left, right: camera_info contents of cam0 and cam1.
        camchain: a parsed :class:`Camchain` or the YAML path; only ``T_cam_imu`` / ``T_cn_cnm1`` are used.
        source: the file the camera_info came from (for error messages), e.g. the bag path.
    """
    source = Path(source)
    chain = camchain if isinstance(camchain, Camchain) else read_camchain(camchain)
    cam_l = _camera_from_info(left, "left", source)
    cam_r = _camera_from_info(right, "right", source)
    if cam_l.size != cam_r.size:
        raise CalibrationError(source, f"left camera_info size {cam_l.size} differs from right {cam_r.size}")
    arrays = {}
    for side, info in (("left", left), ("right", right)):
        arrays[f"R_{side}"] = _array(info.R, (3, 3), source, f"{side} camera_info R")
        arrays[f"P_{side}"] = _array(info.P, (3, 4), source, f"{side} camera_info P")
    try:
        return StereoRig(cam_l, cam_r, chain.T_right_left, chain.T_left_imu, **arrays)
    except ValueError as exc:
        raise CalibrationError(source, f"camera_info does not describe a rectified stereo pair: {exc}") from None


def camera_info_from_rig(rig: StereoRig) -> tuple[CameraInfo, CameraInfo]:
    """The (left, right) camera_info a bag writer stores for ``rig`` (D as 5 plumb_bob coefficients)."""
    out = []
    for cam, R, P in ((rig.left, rig.R_left, rig.P_left), (rig.right, rig.R_right, rig.P_right)):
        out.append(CameraInfo(cam.width, cam.height, "plumb_bob", cam.K, cam.D, np.asarray(R), np.asarray(P)))
    return out[0], out[1]


# ---- writing ---------------------------------------------------------------------------------------------------
def _kalibr_camera(cam: PinholeRadtan) -> dict:
    dist = [float(d) for d in cam.D]
    if abs(dist[4]) > 0.0:
        raise ValueError("Kalibr radtan has 4 coefficients; this camera has a non-zero k3")
    return {
        "camera_model": "pinhole",
        "distortion_coeffs": dist[:4],
        "distortion_model": "radtan",
        "intrinsics": [float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy)],
        "resolution": [int(cam.width), int(cam.height)],
    }


def _matrix(T: np.ndarray) -> list[list[float]]:
    return [[float(v) for v in row] for row in np.asarray(T)]


def camchain_yaml(rig: StereoRig, topics: tuple[str, str] = ("/stereo/left/image_raw", "/stereo/right/image_raw"),
                  timeshift_s: float = 0.0) -> str:
    """Kalibr camchain YAML text for ``rig`` (``cam1/T_cam_imu`` = ``T_right_left @ T_left_imu``)."""
    cam0 = {"T_cam_imu": _matrix(rig.T_left_imu), "cam_overlaps": [1], **_kalibr_camera(rig.left),
            "rostopic": topics[0], "timeshift_cam_imu": float(timeshift_s)}
    cam1 = {"T_cam_imu": _matrix(rig.T_right_imu), "T_cn_cnm1": _matrix(rig.T_right_left), "cam_overlaps": [0],
            **_kalibr_camera(rig.right), "rostopic": topics[1], "timeshift_cam_imu": float(timeshift_s)}
    header = ("# Kalibr camchain written by agrivio.\n"
              "# camX/T_cam_imu maps IMU-frame points into camera X; cam1/T_cn_cnm1 maps cam0 points into cam1.\n")
    return header + yaml.safe_dump({"cam0": cam0, "cam1": cam1}, default_flow_style=None, sort_keys=False)


def write_camchain(rig: StereoRig, path: Path | str, **kwargs: Any) -> None:
    """Write :func:`camchain_yaml` of ``rig`` to ``path`` atomically."""
    write_text_atomic(path, camchain_yaml(rig, **kwargs))


def summarize_rig(rig: StereoRig) -> str:
    """A few human-readable lines describing the rig (used by ``agrivio info``)."""
    T = rig.T_right_left
    angle = np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
    return "\n".join([
        f"image size        {rig.left.width}x{rig.left.height} px",
        f"left  fx fy cx cy {rig.left.fx:.3f} {rig.left.fy:.3f} {rig.left.cx:.3f} {rig.left.cy:.3f}  "
        f"D {np.array2string(rig.left.D, precision=6)}",
        f"right fx fy cx cy {rig.right.fx:.3f} {rig.right.fy:.3f} {rig.right.cx:.3f} {rig.right.cy:.3f}  "
        f"D {np.array2string(rig.right.D, precision=6)}",
        f"rectified fx cx cy {rig.fx:.3f} {rig.cx:.3f} {rig.cy:.3f}",
        f"baseline          {rig.baseline:.5f} m (|t| {np.linalg.norm(T[:3, 3]):.5f} m, rotation {angle:.3f} deg)",
        f"T_left_imu t      {np.array2string(rig.T_left_imu[:3, 3], precision=4)} m",
    ])
