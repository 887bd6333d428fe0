"""The Rosario v1 bag layout: topic names, message types, frame ids and fixed sizes.

Everything here is copied from the dataset authors' bag generator (``CIFASIS/dataset-processing``
``create_bagfile.py``) as summarised in ``shared/references/rosario.md`` §2–§3. Writer, reader and simulator use
these constants so that a simulated bag is indistinguishable in layout from a real one.

Message type names use rosbags' normalised spelling (``pkg/msg/Name``), which it uses for ROS1 bags too.
"""

from __future__ import annotations

from typing import Final

# ---- topics (exact strings as written in the bags) ------------------------------------------------------------
TOPIC_LEFT_IMAGE: Final = "/stereo/left/image_raw"
TOPIC_RIGHT_IMAGE: Final = "/stereo/right/image_raw"
TOPIC_LEFT_INFO: Final = "/stereo/left/camera_info"
TOPIC_RIGHT_INFO: Final = "/stereo/right/camera_info"
TOPIC_IMU: Final = "/imu"
TOPIC_GPS_FIX: Final = "/gps/fix"
TOPIC_GPS_VEL: Final = "/gps/vel"
TOPIC_ODOM: Final = "/odom"
#: No leading slash: the authors' code writes the literal ``"tf_static"``. Readers match with or without it.
TOPIC_TF_STATIC: Final = "tf_static"

# ---- message types (rosbags names) -----------------------------------------------------------------------------
MSG_IMAGE: Final = "sensor_msgs/msg/Image"
MSG_CAMERA_INFO: Final = "sensor_msgs/msg/CameraInfo"
MSG_IMU: Final = "sensor_msgs/msg/Imu"
MSG_NAVSATFIX: Final = "sensor_msgs/msg/NavSatFix"
MSG_TWIST_STAMPED: Final = "geometry_msgs/msg/TwistStamped"
MSG_ODOMETRY: Final = "nav_msgs/msg/Odometry"
MSG_TF: Final = "tf2_msgs/msg/TFMessage"
#: Definition used to register ``tf2_msgs/msg/TFMessage`` (absent from rosbags' ROS1_NOETIC store in 0.11.9).
TF_MESSAGE_DEFINITION: Final = "geometry_msgs/TransformStamped[] transforms"

#: topic → message type, in the order the bags list them.
TOPIC_TYPES: Final[dict[str, str]] = {
    TOPIC_LEFT_IMAGE: MSG_IMAGE,
    TOPIC_RIGHT_IMAGE: MSG_IMAGE,
    TOPIC_LEFT_INFO: MSG_CAMERA_INFO,
    TOPIC_RIGHT_INFO: MSG_CAMERA_INFO,
    TOPIC_IMU: MSG_IMU,
    TOPIC_GPS_FIX: MSG_NAVSATFIX,
    TOPIC_GPS_VEL: MSG_TWIST_STAMPED,
    TOPIC_ODOM: MSG_ODOMETRY,
    TOPIC_TF_STATIC: MSG_TF,
}

#: Topics a bag must hold for the pipeline to run (stereo depth + VIO + calibration).
REQUIRED_TOPICS: Final = (TOPIC_LEFT_IMAGE, TOPIC_RIGHT_IMAGE, TOPIC_LEFT_INFO, TOPIC_RIGHT_INFO, TOPIC_IMU)

# ---- header.frame_id values -------------------------------------------------------------------------------------
FRAME_LEFT_IMAGE: Final = "/stereo/left"
FRAME_RIGHT_IMAGE: Final = "/stereo/right"
#: camera_info frame ids have no slash (the authors' code notes that it breaks the ROS convention).
FRAME_LEFT_INFO: Final = "left"
FRAME_RIGHT_INFO: Final = "right"
FRAME_IMU: Final = "imu"
FRAME_GPS: Final = "gps"
FRAME_ODOM: Final = "odom"
FRAME_BASE_LINK: Final = "base_link"
#: Child frames of the camera static transforms (``imu→left``, ``imu→right``): chosen to match the camera_info
#: frame ids; the exact names in the served bags are unverified (rosario.md §3 lists the four transforms only).
FRAME_TF_LEFT: Final = "left"
FRAME_TF_RIGHT: Final = "right"

# ---- image format -------------------------------------------------------------------------------------------------
IMAGE_WIDTH: Final = 672
IMAGE_HEIGHT: Final = 376
IMAGE_ENCODING: Final = "bgr8"
DISTORTION_MODEL: Final = "plumb_bob"

# ---- nominal rates (Hz) -------------------------------------------------------------------------------------------
RATE_CAMERA_HZ: Final = 15.0
RATE_IMU_HZ: Final = 142.0
RATE_GPS_HZ: Final = 5.0
RATE_ODOM_HZ: Final = 10.0

# ---- NavSatFix constants (sensor_msgs) --------------------------------------------------------------------------
GPS_STATUS_NO_FIX: Final = -1
GPS_STATUS_FIX: Final = 0
GPS_STATUS_SBAS_FIX: Final = 1
GPS_STATUS_GBAS_FIX: Final = 2  # RTK fixed / float in the Rosario bags
GPS_SERVICE_GPS: Final = 1
GPS_COVARIANCE_TYPE_APPROXIMATED: Final = 1


def normalize_topic(topic: str) -> str:
    """Topic name with exactly one leading slash, so ``tf_static`` and ``/tf_static`` compare equal."""
    return "/" + topic.lstrip("/")
