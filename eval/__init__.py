"""Trajectory evaluation: TUM/EuRoC I/O, association, alignment, ATE/RPE, run records, statistics, reports.

Modules (import what you need; this package imports nothing eagerly): ``trajectory`` (``Trajectory``,
``read_tum``, ``format_tum``), ``association``, ``alignment``, ``metrics``, ``evaluate`` (``evaluate``,
``EvalOptions``), ``records`` (``RunRecord``, ``config_hash``), ``statistics``, ``compare``, ``plots``,
``report`` (``build_report``), ``synthetic`` (test data), ``depth_metrics`` (hole-pixel depth metrics),
``gate_calibration`` (the χ² noise scale of a filter's gate statistics).
"""
