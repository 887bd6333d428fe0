"""The rosbags type store for Rosario ROS1 bags (``Stores.ROS1_NOETIC`` plus ``tf2_msgs/msg/TFMessage``)."""

from __future__ import annotations

from functools import lru_cache

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from pipeline.rosario_layout import MSG_TF, TF_MESSAGE_DEFINITION


@lru_cache(maxsize=1)
def rosario_typestore() -> Typestore:
    """ROS1 Noetic type store with ``tf2_msgs/msg/TFMessage`` registered if missing.

    ``Stores.LATEST`` must not be used for ROS1 bags: its Header has no ``seq``, so md5sums come out wrong
    (apis.md §2.1). The returned store is shared; do not register further types on it.
    """
    ts = get_typestore(Stores.ROS1_NOETIC)
    if MSG_TF not in ts.types:
        ts.register(get_types_from_msg(TF_MESSAGE_DEFINITION, MSG_TF))
    return ts
