"""Writers of the simulator's outputs besides the bag: depth chunks, ground-truth text files, EuRoC/ASL folder.

Every file is written atomically (temporary name, then rename); the EuRoC folder is assembled in a temporary
folder renamed into place at the end.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np
import yaml

from msckf.camera import StereoRig
from pipeline.depth import encode_depth_mm, to_grey
from pipeline.png_chunks import Chunk, read_chunk, write_chunk
from pipeline.png_codec import PNG_FAST, decode_png, encode_png_bytes
from pipeline.sim.config import ImuConfig

DEPTH_CHUNK = 32


def _png(img: np.ndarray) -> bytes:
    return encode_png_bytes(img, PNG_FAST)


def _unpng(buf: np.ndarray) -> np.ndarray:
    return decode_png(buf, "a depth chunk")


def _finite(depth: np.ndarray) -> np.ndarray:
    """inf (sky) → NaN, so that the millimetre encoding stores 0 (none)."""
    return np.where(np.isfinite(depth), depth, np.float32(np.nan))


def encode_depth_frame(depth: np.ndarray, label: np.ndarray, glare: np.ndarray, right_depth: np.ndarray | None = None,
                       right_label: np.ndarray | None = None) -> tuple:
    """PNG byte streams of one frame's ground truth, as :class:`DepthChunkWriter` stores them: ``(depth, label,
    glare, right depth or None, right label or None)``; depth in uint16 millimetres (0 = none), glare × 255."""
    g = np.clip(np.rint(np.nan_to_num(glare) * 255.0), 0, 255).astype(np.uint8)
    return (_png(encode_depth_mm(_finite(depth))), _png(label), _png(g),
            None if right_depth is None else _png(encode_depth_mm(_finite(right_depth))),
            None if right_label is None else _png(right_label))


class DepthChunkWriter:
    """Streams exact ground-truth depth of every left frame into ``depth/chunk_NNNNN.npz`` files.

    Each chunk holds ``DEPTH_CHUNK`` frames: ``index`` (n,), ``stamp_ns`` (n,), and PNG byte streams with
    offsets for ``depth`` (uint16 millimetres of Z in the rectified left camera, 0 = none: sky or beyond
    65.535 m), ``label`` (uint8 ``render.LABEL_*``) and ``glare`` (uint8, sun-glare sensor level × 255);
    optionally ``rdepth``/``rlabel`` for the rectified right camera.
    """

    def __init__(self, folder: Path, chunk: int = DEPTH_CHUNK) -> None:
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.chunk = chunk
        self._rows: list[tuple] = []
        self.frames = 0

    def add(self, index: int, stamp_ns: int, depth: np.ndarray, label: np.ndarray, glare: np.ndarray,
            right_depth: np.ndarray | None = None, right_label: np.ndarray | None = None) -> None:
        self.add_encoded(index, stamp_ns, encode_depth_frame(depth, label, glare, right_depth, right_label))

    def add_encoded(self, index: int, stamp_ns: int, blobs: tuple) -> None:
        """Add a frame already encoded by :func:`encode_depth_frame` (e.g. in a render worker)."""
        self._rows.append((int(index), int(stamp_ns), *blobs))
        self.frames += 1
        if len(self._rows) == self.chunk:
            self.flush()

    def flush(self) -> None:
        if not self._rows:
            return
        first = self._rows[0][0]
        layers = {key: [r[j] for r in self._rows]
                  for j, key in ((2, "depth"), (3, "label"), (4, "glare"), (5, "rdepth"), (6, "rlabel"))}
        write_chunk(self.folder / f"chunk_{first // self.chunk:05d}.npz", [r[0] for r in self._rows],
                    [r[1] for r in self._rows], layers)
        self._rows = []


class DepthChunkReader:
    """Random access to the frames written by :class:`DepthChunkWriter` (keeps the last chunk decoded-ready)."""

    def __init__(self, folder: Path, chunk: int = DEPTH_CHUNK) -> None:
        self.folder = Path(folder)
        self.chunk = chunk
        self._cache: tuple[int, Chunk] | None = None

    def _load(self, c: int) -> Chunk:
        if self._cache is None or self._cache[0] != c:
            path = self.folder / f"chunk_{c:05d}.npz"
            if not path.is_file():
                raise FileNotFoundError(f"{path}: depth chunk missing")
            self._cache = (c, read_chunk(path))
        return self._cache[1]

    def _find(self, index: int) -> tuple[Chunk, int]:
        """The chunk holding frame ``index`` and the frame's position in it (IndexError when it is not there)."""
        data = self._load(index // self.chunk)
        pos = data.position(index)
        if pos is None:
            raise IndexError(f"frame {index} not in {self.folder}")
        return data, pos

    def get(self, index: int, key: str = "depth") -> np.ndarray:
        """Decoded image ``key`` of frame ``index``: depth/rdepth as float32 metres (NaN = none), else uint8."""
        data, pos = self._find(index)
        if key not in data.layers:
            raise KeyError(f"{self.folder}: no {key!r} stored")
        img = _unpng(data.blob(key, pos))
        if key in ("depth", "rdepth"):
            return np.where(img > 0, img.astype(np.float32) / 1000.0, np.float32(np.nan)).astype(np.float32)
        return img

    def stamp_ns(self, index: int) -> int:
        data, pos = self._find(index)
        return int(data.stamp_ns[pos])


# ---- EuRoC / ASL ---------------------------------------------------------------------------------------------------
def _matrix_yaml(T: np.ndarray) -> dict:
    return {"cols": 4, "rows": 4, "data": [float(v) for v in np.asarray(T).reshape(-1)]}


def imu_sensor_yaml(imu: ImuConfig, max_speed_m_s: float = 1.0) -> dict:
    """``imu0/sensor.yaml`` with noise figures that describe the data, vibration included.

    The simulated IMU adds engine/structure vibration (25–65 Hz sinusoids, RMS ``vibration_*_rms`` × speed in m/s,
    times a slow 0.5–1.0 modulation) on top of the sensor's white noise. A filter that reads only the sensor's
    noise density under-weights that error (accelerometer 0.076 m/s² per sample implied against ≈ 0.18 m/s² seen
    while moving) and may diverge, so ``*_noise_density`` is the white-noise equivalent of both at the sequence's
    top speed ``max_speed_m_s``: ``sqrt(density² + vibration_rms² / rate)`` (per-sample σ = density · √rate). The
    sensor-only figures and the vibration are given as well, under ``agrivio_*`` keys.
    """
    v = max(float(max_speed_m_s), 0.0)
    vib_acc, vib_gyro = float(imu.vibration_acc_rms) * v, float(imu.vibration_gyro_rms) * v
    rate = float(imu.rate_hz)
    return {"sensor_type": "imu",
            "comment": (f"agrivio simulated IMU (Rosario axes: x up, y right, z forward). Noise densities include "
                        f"the simulated vibration at the top speed {v:.2f} m/s (accelerometer {vib_acc:.3f} m/s^2 "
                        f"RMS, gyroscope {vib_gyro:.4f} rad/s RMS, 25-65 Hz) as white-noise equivalents; the "
                        f"sensor-only figures are under agrivio_*_sensor"),
            "T_BS": _matrix_yaml(np.eye(4)), "rate_hz": rate,
            "gyroscope_noise_density": float(np.hypot(imu.gyro_noise_density, vib_gyro / np.sqrt(rate))),
            "gyroscope_random_walk": float(imu.gyro_random_walk),
            "accelerometer_noise_density": float(np.hypot(imu.acc_noise_density, vib_acc / np.sqrt(rate))),
            "accelerometer_random_walk": float(imu.acc_random_walk),
            "agrivio_gyroscope_noise_density_sensor": float(imu.gyro_noise_density),
            "agrivio_accelerometer_noise_density_sensor": float(imu.acc_noise_density),
            "agrivio_gyroscope_vibration_rms_at_top_speed": vib_gyro,
            "agrivio_accelerometer_vibration_rms_at_top_speed": vib_acc,
            "agrivio_top_speed_m_s": v}


class EurocWriter:
    """Streams an EuRoC/ASL folder (``mav0/cam0``, ``cam1``, ``imu0``, ``state_groundtruth_estimate0``).

    Images are the raw (distorted) frames converted to 8-bit grey PNG, as EuRoC's; the body frame ``S`` is the
    IMU; ground truth is the IMU pose, velocity and biases in the ENU world frame ``R``.
    """

    def __init__(self, target: Path, rig: StereoRig, imu: ImuConfig, cam_rate_hz: float,
                 max_speed_m_s: float = 1.0) -> None:
        self.target = Path(target)
        self.target.parent.mkdir(parents=True, exist_ok=True)
        self.tmp = Path(tempfile.mkdtemp(prefix=f".{self.target.name}.", dir=self.target.parent))
        m = self.tmp / "mav0"
        for sub in ("cam0/data", "cam1/data", "imu0", "state_groundtruth_estimate0"):
            (m / sub).mkdir(parents=True, exist_ok=True)
        self._cam_csv = [open(m / f"cam{c}/data.csv", "w") for c in (0, 1)]
        for f in self._cam_csv:
            f.write("#timestamp [ns],filename\n")
        self._imu = open(m / "imu0/data.csv", "w")
        self._imu.write("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
                        "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n")
        self._gt = open(m / "state_groundtruth_estimate0/data.csv", "w")
        self._gt.write("#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], "
                       "q_RS_z [], v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], "
                       "b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], "
                       "b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]\n")
        for c, cam, T_cam_imu in ((0, rig.left, rig.T_left_imu), (1, rig.right, rig.T_right_imu)):
            meta = {"sensor_type": "camera", "comment": f"agrivio simulated {'left' if c == 0 else 'right'} camera "
                    "(raw, distorted)", "T_BS": _matrix_yaml(np.linalg.inv(T_cam_imu)), "rate_hz": float(cam_rate_hz),
                    "resolution": [int(cam.width), int(cam.height)], "camera_model": "pinhole",
                    "intrinsics": [float(cam.fx), float(cam.fy), float(cam.cx), float(cam.cy)],
                    "distortion_model": "radial-tangential",
                    "distortion_coefficients": [float(v) for v in cam.D[:4]]}
            (m / f"cam{c}/sensor.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
        imu_meta = imu_sensor_yaml(imu, max_speed_m_s)
        (m / "imu0/sensor.yaml").write_text(yaml.safe_dump(imu_meta, sort_keys=False))
        (m / "state_groundtruth_estimate0/sensor.yaml").write_text(yaml.safe_dump(
            {"sensor_type": "visual-inertial", "comment": "ground truth IMU pose in ENU", "T_BS":
             _matrix_yaml(np.eye(4))}, sort_keys=False))

    def add_stereo(self, stamp_ns: int, left_bgr: np.ndarray, right_bgr: np.ndarray) -> None:
        for c, img in ((0, left_bgr), (1, right_bgr)):
            name = f"{int(stamp_ns)}.png"
            cv2.imwrite(str(self.tmp / f"mav0/cam{c}/data" / name), to_grey(img),
                        PNG_FAST)
            self._cam_csv[c].write(f"{int(stamp_ns)},{name}\n")

    def add_imu(self, stamps_ns: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> None:
        data = np.column_stack([gyro, accel])
        for s, row in zip(stamps_ns, data):
            self._imu.write(f"{int(s)}," + ",".join(f"{v:.9g}" for v in row) + "\n")

    def add_ground_truth(self, stamps_ns: np.ndarray, p: np.ndarray, q_xyzw: np.ndarray, v: np.ndarray,
                         bg: np.ndarray, ba: np.ndarray) -> None:
        q_wxyz = np.column_stack([q_xyzw[:, 3], q_xyzw[:, :3]])
        data = np.column_stack([p, q_wxyz, v, bg, ba])
        for s, row in zip(stamps_ns, data):
            self._gt.write(f"{int(s)}," + ",".join(f"{x:.9g}" for x in row) + "\n")

    def close(self) -> None:
        for f in (*self._cam_csv, self._imu, self._gt):
            f.close()
        if self.target.exists():
            shutil.rmtree(self.target)
        os.replace(self.tmp, self.target)

    def abort(self) -> None:
        for f in (*self._cam_csv, self._imu, self._gt):
            f.close()
        shutil.rmtree(self.tmp, ignore_errors=True)
