"""The names of the compared variants — their one definition (design.md, "Variants compared").

| name | what the VIO gets |
|---|---|
| ``stereo`` | the S-MSCKF front end: left/right KLT stereo matching |
| ``depth-raw`` | features on the left image, depth from the raw SGBM map |
| ``depth-inpainted`` | the same, depth from the inpainted map |
| ``odometry`` | wheel odometry + IMU dead reckoning (not a VIO) |

``eval`` orders and compares runs by these names; ``pipeline`` plans and runs them. Run records store the name
(``RunRecord.variant``); tables show :func:`eval.records.variant_display_name` of it.
"""

from __future__ import annotations

__all__ = ["STEREO", "DEPTH_RAW", "DEPTH_INPAINTED", "ODOMETRY", "VARIANTS"]

STEREO = "stereo"
DEPTH_RAW = "depth-raw"
DEPTH_INPAINTED = "depth-inpainted"
ODOMETRY = "odometry"

#: every variant, in the order tables list them
VARIANTS: tuple[str, ...] = (STEREO, DEPTH_RAW, DEPTH_INPAINTED, ODOMETRY)
