"""The rerun replay writer: the .rrd loads back with rerun's own reader and holds the expected entities."""

import numpy as np

from pipeline.replay import ReplayFrame, ReplayRun, recorded_entities, write_replay


def _run(name: str, n: int, rng: np.random.Generator) -> ReplayRun:
    t = np.arange(n) / 15.0
    pos = np.stack([t, 0.1 * t, np.zeros(n)], axis=1)
    feats = {i: (rng.uniform(0, 600, (30, 2)), rng.integers(1, 30, 30), rng.integers(0, 3, 30)) for i in range(n)}
    return ReplayRun(name=name, stamps_s=t, positions=pos, quats_xyzw=np.tile([0, 0, 0, 1.0], (n, 1)),
                     T_imu_cam=np.eye(4), ate_m=np.linspace(0, 0.1, n), frame_stamps_s=t,
                     n_features=np.full(n, 30), frame_ms=np.full(n, 12.0), features=feats)


def test_replay_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    n, h, w = 6, 48, 64
    runs = [_run("depth-raw seed0", n, rng), _run("depth-inpainted seed0", n, rng)]
    depth = rng.uniform(1, 10, (h, w)).astype(np.float32)
    holes = rng.random((h, w)) < 0.2
    raw = np.where(holes, np.nan, depth).astype(np.float32)
    frames = (ReplayFrame(i, i / 15.0, rng.integers(0, 255, (h, w, 3), dtype=np.uint8), raw, depth, holes)
              for i in range(n))
    K = np.array([[50.0, 0, 32], [0, 50.0, 24], [0, 0, 1]])
    out = write_replay(tmp_path / "run.rrd", runs, frames, gt_positions=runs[0].positions, K_left=K,
                       image_size=(w, h))
    rows = recorded_entities(out)
    for entity in ("/camera/left", "/camera/depth_raw", "/camera/depth_inpainted", "/camera/holes", "/world/gt",
                   "/world/depth-raw_seed0/trajectory", "/world/depth-inpainted_seed0/camera",
                   "/camera/left/features/depth-raw_seed0", "/metrics/depth-inpainted_seed0/ate_m",
                   "/metrics/hole_ratio"):
        assert entity in rows, f"{entity} missing from {sorted(rows)}"
    assert rows["/camera/left"] == n
    assert rows["/world/depth-raw_seed0/trajectory"] == n
    assert not list(tmp_path.glob(".run.rrd*")), "temporary file left behind"
