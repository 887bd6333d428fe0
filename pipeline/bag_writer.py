"""Write ROS1 bags in the exact Rosario v1 layout (rosario.md §3) with rosbags.

Used by the tests, the simulator and the interim demo. Every message's bag time equals its ``header.stamp``;
``seq`` counts from 0 per topic, and each camera_info carries the stamp and seq of its image.

Example::

    with RosarioBagWriter(path, compression="lz4") as w:
        w.set_camera_info(rig)
        w.write_stereo(t_ns, left_bgr, right_bgr)
        w.write_imu(t_ns, gyro_rad_s, accel_m_s2)
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from rosbags.interfaces import Connection
from rosbags.rosbag1 import Writer
from scipy.spatial.transform import Rotation

from msckf.camera import StereoRig
from pipeline import rosario_layout as L
from pipeline.atomic import atomic_path
from pipeline.bag_typestore import rosario_typestore

_COMPRESSIONS = {None: None, "none": None, "bz2": Writer.CompressionFormat.BZ2, "lz4": Writer.CompressionFormat.LZ4}


def _stamp(ts: Any, stamp_ns: int) -> Any:
    stamp_ns = int(stamp_ns)
    if stamp_ns < 0:
        raise ValueError(f"stamps must be non-negative nanoseconds, got {stamp_ns}")
    return ts.types["builtin_interfaces/msg/Time"](sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)


def _cov_unknown() -> np.ndarray:
    """The Rosario IMU covariance: ``[-1, 0, ..., 0]`` (aliased lists before the 2021-07 fix), shape (9,)."""
    c = np.zeros(9)
    c[0] = -1.0
    return c


class RosarioBagWriter:
    """Writes a ROS1 bag in the exact Rosario v1 layout (rosbags Writer, ``Stores.ROS1_NOETIC``).

    Atomic: writes to a temp file next to ``path`` and renames it onto ``path`` on clean exit of the context
    manager (deletes it on error). ``path`` must not exist yet (rosbags refuses to overwrite) unless
    ``overwrite=True``.

    Args:
        path: the bag to create.
        compression: ``None`` | ``"bz2"`` | ``"lz4"`` chunk compression (the served bags are BZ2; BZ2 is slow to
            write, ~50 ms per 672×376 image: prefer LZ4 or none for test fixtures).
        strict: check that each image has the size of the camera_info set by :meth:`set_camera_info`
            (turn off only to write deliberately inconsistent bags for tests).
        overwrite: replace an existing file at ``path``.
    """

    def __init__(self, path: Path | str, compression: str | None = None, *, strict: bool = True,
                 overwrite: bool = False) -> None:
        self.path = Path(path)
        if compression not in _COMPRESSIONS:
            raise ValueError(f"compression must be one of None, 'bz2', 'lz4'; got {compression!r}")
        self.compression = compression
        self.strict = strict
        self.overwrite = overwrite
        self._ts = rosario_typestore()
        self._stack: contextlib.ExitStack | None = None
        self._writer: Writer | None = None
        self._conns: dict[str, Connection] = {}
        self._seq: dict[str, int] = {}
        self._info: dict[str, Any] | None = None  # per-side CameraInfo field values
        self._info_size: tuple[int, int] | None = None  # (height, width)

    # ---- context manager -----------------------------------------------------------------------------------
    def __enter__(self) -> RosarioBagWriter:
        if self.path.exists() and not self.overwrite:
            raise FileExistsError(f"{self.path}: refusing to overwrite an existing bag")
        stack = contextlib.ExitStack()
        tmp = stack.enter_context(atomic_path(self.path, suffix=".bag"))
        writer = Writer(tmp)
        fmt = _COMPRESSIONS[self.compression]
        if fmt is not None:
            writer.set_compression(fmt)
        writer.open()
        self._stack, self._writer = stack, writer
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> bool:
        writer, stack = self._writer, self._stack
        self._writer, self._stack = None, None
        assert writer is not None and stack is not None
        if exc_type is None:
            writer.close()  # writes the index; then atomic_path renames the temp file onto the target
            stack.close()
        else:
            with contextlib.suppress(Exception):
                writer.close()
            stack.__exit__(exc_type, exc, tb)  # removes the temp file
        return False

    # ---- low level -----------------------------------------------------------------------------------------
    def _conn(self, topic: str) -> Connection:
        if self._writer is None:
            raise RuntimeError("RosarioBagWriter must be used as a context manager (with ... as w)")
        conn = self._conns.get(topic)
        if conn is None:
            conn = self._writer.add_connection(topic, L.TOPIC_TYPES[topic], typestore=self._ts)
            self._conns[topic] = conn
        return conn

    def _next_seq(self, topic: str) -> int:
        seq = self._seq.get(topic, 0)
        self._seq[topic] = seq + 1
        return seq

    def _header(self, stamp_ns: int, frame_id: str, seq: int = 0) -> Any:
        return self._ts.types["std_msgs/msg/Header"](seq=seq, stamp=_stamp(self._ts, stamp_ns), frame_id=frame_id)

    def _write(self, topic: str, stamp_ns: int, msg: Any) -> None:
        conn = self._conn(topic)
        assert self._writer is not None
        self._writer.write(conn, int(stamp_ns), self._ts.serialize_ros1(msg, L.TOPIC_TYPES[topic]))

    def _vec3(self, v: np.ndarray | Sequence[float]) -> Any:
        x, y, z = (float(c) for c in np.asarray(v, dtype=np.float64).reshape(3))
        return self._ts.types["geometry_msgs/msg/Vector3"](x=x, y=y, z=z)

    def _quat(self, q_xyzw: np.ndarray | Sequence[float]) -> Any:
        x, y, z, w = (float(c) for c in np.asarray(q_xyzw, dtype=np.float64).reshape(4))
        return self._ts.types["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)

    # ---- cameras -------------------------------------------------------------------------------------------
    def set_camera_info(self, rig: StereoRig) -> None:
        """Take K, D (plumb_bob, 5 coefficients ``k1 k2 p1 p2 k3``), R and P of both cameras from ``rig``.

        Required before the first image. Image size comes from ``rig.left`` / ``rig.right``.
        """
        infos = {}
        for side, cam, R, P in (("left", rig.left, rig.R_left, rig.P_left),
                                ("right", rig.right, rig.R_right, rig.P_right)):
            infos[side] = dict(height=int(cam.height), width=int(cam.width), D=np.asarray(cam.D, dtype=np.float64),
                               K=cam.K.reshape(9).astype(np.float64), R=np.asarray(R, np.float64).reshape(9),
                               P=np.asarray(P, np.float64).reshape(12))
        self._info = infos
        self._info_size = (int(rig.left.height), int(rig.left.width))

    def _camera_info(self, side: str, stamp_ns: int, seq: int) -> Any:
        assert self._info is not None
        T = self._ts.types
        v = self._info[side]
        frame = L.FRAME_LEFT_INFO if side == "left" else L.FRAME_RIGHT_INFO
        return T["sensor_msgs/msg/CameraInfo"](
            header=self._header(stamp_ns, frame, seq), height=v["height"], width=v["width"],
            distortion_model=L.DISTORTION_MODEL, D=v["D"], K=v["K"], R=v["R"], P=v["P"], binning_x=0, binning_y=0,
            roi=T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))

    def _write_image(self, side: str, stamp_ns: int, bgr: np.ndarray) -> None:
        if self._info is None:
            raise RuntimeError("call set_camera_info(rig) before writing images")
        img = np.asarray(bgr)
        if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
            raise ValueError(f"{side} image must be HxWx3 uint8 BGR, got {img.dtype} {img.shape}")
        if self.strict and img.shape[:2] != self._info_size:
            raise ValueError(f"{side} image is {img.shape[1]}x{img.shape[0]} but camera_info says "
                             f"{self._info_size[1]}x{self._info_size[0]}")
        img = np.ascontiguousarray(img)
        h, w = img.shape[:2]
        img_topic = L.TOPIC_LEFT_IMAGE if side == "left" else L.TOPIC_RIGHT_IMAGE
        info_topic = L.TOPIC_LEFT_INFO if side == "left" else L.TOPIC_RIGHT_INFO
        frame = L.FRAME_LEFT_IMAGE if side == "left" else L.FRAME_RIGHT_IMAGE
        seq = self._next_seq(img_topic)
        msg = self._ts.types["sensor_msgs/msg/Image"](
            header=self._header(stamp_ns, frame, seq), height=h, width=w, encoding=L.IMAGE_ENCODING,
            is_bigendian=0, step=w * 3, data=img.reshape(-1))
        self._write(img_topic, stamp_ns, msg)
        self._write(info_topic, stamp_ns, self._camera_info(side, stamp_ns, seq))

    def write_stereo(self, stamp_ns: int, left_bgr: np.ndarray, right_bgr: np.ndarray) -> None:
        """Write a stereo pair (both HxWx3 uint8 BGR raw images, 376×672 for Rosario) and their camera_info."""
        self._write_image("left", stamp_ns, left_bgr)
        self._write_image("right", stamp_ns, right_bgr)

    def write_left(self, stamp_ns: int, left_bgr: np.ndarray) -> None:
        """Write a left image alone (+ its camera_info), e.g. to test a missing right partner."""
        self._write_image("left", stamp_ns, left_bgr)

    def write_right(self, stamp_ns: int, right_bgr: np.ndarray) -> None:
        """Write a right image alone (+ its camera_info)."""
        self._write_image("right", stamp_ns, right_bgr)

    # ---- other sensors -------------------------------------------------------------------------------------
    def write_imu(self, stamp_ns: int, gyro_rad_s: np.ndarray, accel_m_s2: np.ndarray) -> None:
        """Write one ``sensor_msgs/Imu``: angular velocity (rad/s) and specific force (m/s², gravity included)
        in the Rosario IMU frame (x up, y right, z forward). Orientation is identity with all three covariance
        arrays ``[-1, 0, ..., 0]``, as in the regenerated Rosario bags."""
        msg = self._ts.types["sensor_msgs/msg/Imu"](
            header=self._header(stamp_ns, L.FRAME_IMU, self._next_seq(L.TOPIC_IMU)),
            orientation=self._quat((0.0, 0.0, 0.0, 1.0)), orientation_covariance=_cov_unknown(),
            angular_velocity=self._vec3(gyro_rad_s), angular_velocity_covariance=_cov_unknown(),
            linear_acceleration=self._vec3(accel_m_s2), linear_acceleration_covariance=_cov_unknown())
        self._write(L.TOPIC_IMU, stamp_ns, msg)

    def write_gps_fix(self, stamp_ns: int, lat_deg: float, lon_deg: float, alt_m: float, status: int = 2,
                      hdop: float = 0.8) -> None:
        """Write one ``sensor_msgs/NavSatFix``: latitude/longitude in degrees (S, W negative), ellipsoidal
        altitude in metres, ``status`` a NavSatStatus value (2 = GBAS_FIX, RTK), covariance
        ``diag(hdop², hdop², (2·hdop)²)`` m² with type APPROXIMATED, as the authors' converter writes it."""
        T = self._ts.types
        cov = np.zeros(9)
        cov[0], cov[4], cov[8] = hdop ** 2, hdop ** 2, (2.0 * hdop) ** 2
        msg = T["sensor_msgs/msg/NavSatFix"](
            header=self._header(stamp_ns, L.FRAME_GPS, self._next_seq(L.TOPIC_GPS_FIX)),
            status=T["sensor_msgs/msg/NavSatStatus"](status=int(status), service=L.GPS_SERVICE_GPS),
            latitude=float(lat_deg), longitude=float(lon_deg), altitude=float(alt_m), position_covariance=cov,
            position_covariance_type=L.GPS_COVARIANCE_TYPE_APPROXIMATED)
        self._write(L.TOPIC_GPS_FIX, stamp_ns, msg)

    def write_gps_vel(self, stamp_ns: int, v_east: float, v_north: float) -> None:
        """Write one ``geometry_msgs/TwistStamped``: ``linear.x`` east, ``linear.y`` north, m/s; rest 0."""
        T = self._ts.types
        msg = T["geometry_msgs/msg/TwistStamped"](
            header=self._header(stamp_ns, L.FRAME_GPS, self._next_seq(L.TOPIC_GPS_VEL)),
            twist=T["geometry_msgs/msg/Twist"](linear=self._vec3((v_east, v_north, 0.0)),
                                               angular=self._vec3((0.0, 0.0, 0.0))))
        self._write(L.TOPIC_GPS_VEL, stamp_ns, msg)

    def write_odom(self, stamp_ns: int, x: float, y: float, yaw: float, v: float, yaw_rate: float) -> None:
        """Write one ``nav_msgs/Odometry`` (frame ``odom``, child ``base_link``): planar pose x, y (m), yaw (rad,
        as a yaw-only quaternion), z = 0; ``twist.linear.x`` = signed speed (m/s), ``twist.angular.z`` = yaw rate
        (rad/s); covariances 0."""
        T = self._ts.types
        q = Rotation.from_euler("z", float(yaw)).as_quat()
        pose = T["geometry_msgs/msg/PoseWithCovariance"](
            pose=T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0),
                                             orientation=self._quat(q)), covariance=np.zeros(36))
        twist = T["geometry_msgs/msg/TwistWithCovariance"](
            twist=T["geometry_msgs/msg/Twist"](linear=self._vec3((v, 0.0, 0.0)),
                                               angular=self._vec3((0.0, 0.0, yaw_rate))), covariance=np.zeros(36))
        msg = T["nav_msgs/msg/Odometry"](
            header=self._header(stamp_ns, L.FRAME_ODOM, self._next_seq(L.TOPIC_ODOM)),
            child_frame_id=L.FRAME_BASE_LINK, pose=pose, twist=twist)
        self._write(L.TOPIC_ODOM, stamp_ns, msg)

    def write_tf_static(self, stamp_ns: int, transforms: Sequence[tuple[str, str, np.ndarray]]) -> None:
        """Write one ``tf2_msgs/TFMessage`` on the literal topic ``tf_static``.

        Args:
            transforms: ``(parent, child, T_parent_child)`` with ``T_parent_child`` a 4×4 transform mapping
                child-frame points into the parent frame (metres), which is what a ROS TransformStamped holds.
        """
        T = self._ts.types
        items = []
        for parent, child, mat in transforms:
            mat = np.asarray(mat, dtype=np.float64)
            if mat.shape != (4, 4):
                raise ValueError(f"transform {parent}->{child} must be 4x4, got {mat.shape}")
            q = Rotation.from_matrix(mat[:3, :3]).as_quat()
            items.append(T["geometry_msgs/msg/TransformStamped"](
                header=self._header(stamp_ns, parent, 0), child_frame_id=child,
                transform=T["geometry_msgs/msg/Transform"](translation=self._vec3(mat[:3, 3]),
                                                           rotation=self._quat(q))))
        self._write(L.TOPIC_TF_STATIC, stamp_ns, T[L.MSG_TF](transforms=items))
