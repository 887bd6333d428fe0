"""TUM / EuRoC I/O and the Trajectory type."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eval.errors import EvalInputError
from eval.trajectory import Trajectory, format_tum, parse_euroc_gt, parse_tum, read_euroc_gt, read_tum


def _traj(n: int = 20, seed: int = 0) -> Trajectory:
    rng = np.random.default_rng(seed)
    return Trajectory(1_500_000_000.0 + np.cumsum(rng.uniform(0.05, 0.1, n)), rng.normal(0, 10, (n, 3)),
                      Rotation.random(n, rng=rng).as_quat())


def test_tum_round_trip_crlf_comments(tmp_path) -> None:
    traj = _traj()
    text = format_tum(traj, header="estimate\nsecond line")
    assert text.startswith("# estimate\n# second line\n")
    crlf = "# leading comment\r\n\r\n" + text.replace("\n", "\r\n") + "   \r\n# trailing\r\n"
    path = tmp_path / "est.tum"
    path.write_bytes(crlf.encode())
    back = read_tum(path)
    assert back.has_orientation
    np.testing.assert_allclose(back.stamps_s, traj.stamps_s, atol=1e-9, rtol=0)
    np.testing.assert_allclose(back.positions, traj.positions, atol=1e-9)
    # the same rotation (q and -q are equal rotations)
    dots = np.abs(np.sum(back.quats_xyzw * traj.quats_xyzw, axis=1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-8)
    # writing again gives the same text (deterministic)
    assert format_tum(back) == format_tum(read_tum(path))


def test_tum_trailing_comment_and_tabs() -> None:
    traj = parse_tum("1.0\t0 0 0 0 0 0 1 # a note\n2.0 1 2 3 0 0 0 1\n")
    assert len(traj) == 2 and traj.positions[1].tolist() == [1.0, 2.0, 3.0]


def test_identity_quaternions_mean_position_only() -> None:
    text = "1.0 0 0 0 0 0 0 1\n2.0 1 0 0 0 0 0 1\n3.0 2 0 0 0 0 0 -1\n"
    assert not parse_tum(text).has_orientation
    assert parse_tum("1.0 0 0 0 0 0 0.1 0.995\n2.0 1 0 0 0 0 0 1\n").has_orientation


def test_malformed_line_names_file_and_line(tmp_path) -> None:
    path = tmp_path / "gt.txt"
    path.write_bytes(b"# header\r\n1.0 0 0 0 0 0 0 1\r\n2.0 1 0 0 0 0 0 1\r\n3.0 oops 0 0 0 0 0 1\r\n")
    with pytest.raises(EvalInputError, match=rf"{path}:4: not a number"):
        read_tum(path)
    path.write_text("1.0 0 0 0 0 0 0 1\n2.0 1 0 0 0 0 1\n")
    with pytest.raises(EvalInputError, match=rf"{path}:2: expected 8 numbers.*got 7"):
        read_tum(path)
    path.write_text("1.0 0 0 0 0 0 0 1\n1.0 1 0 0 0 0 0 1\n")
    with pytest.raises(EvalInputError, match=rf"{path}:2: time stamp"):
        read_tum(path)
    path.write_text("1.0 0 0 0 0 0 0 0\n")
    with pytest.raises(EvalInputError, match="zero quaternion"):
        read_tum(path)
    path.write_text("1.0 nan 0 0 0 0 0 1\n")
    with pytest.raises(EvalInputError, match=":1: NaN"):
        read_tum(path)


def test_empty_missing_and_binary_files(tmp_path) -> None:
    empty = tmp_path / "empty.tum"
    empty.write_text("# nothing\n\n")
    with pytest.raises(EvalInputError, match="no poses"):
        read_tum(empty)
    with pytest.raises(EvalInputError, match="no such file"):
        read_tum(tmp_path / "missing.tum")
    binary = tmp_path / "bin.tum"
    binary.write_bytes(b"\xff\xfe\x00\x01")
    with pytest.raises(EvalInputError, match="not a text file"):
        read_tum(binary)
    assert issubclass(EvalInputError, ValueError)


def test_euroc_ground_truth(tmp_path) -> None:
    text = ("#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], "
            "v_x, v_y, v_z, bwx, bwy, bwz, bax, bay, baz\r\n"
            "1403636579758555392,4.688319,-1.786938,0.783338,0.534108,-0.153029,-0.827383,-0.082152,"
            "0,0,0,0,0,0,0,0,0\r\n"
            "1403636579763555584,4.688177,-1.786770,0.787350,0.534640,-0.152990,-0.826976,-0.082863,"
            "0,0,0,0,0,0,0,0,0\r\n")
    path = tmp_path / "data.csv"
    path.write_text(text)
    traj = read_euroc_gt(path)
    assert len(traj) == 2 and traj.has_orientation
    # float64 seconds near 1.4e9 s resolve ~0.24 µs; the stamp is the nearest double to the exact ns value
    assert traj.stamps_s[0] == 1403636579.758555392
    assert traj.stamps_s[1] - traj.stamps_s[0] == pytest.approx(0.005000192, abs=3e-7)
    q = np.array([-0.153029, -0.827383, -0.082152, 0.534108])
    np.testing.assert_allclose(traj.quats_xyzw[0], q / np.linalg.norm(q), atol=1e-12)
    with pytest.raises(EvalInputError, match=r"<x>:2: expected at least 8"):
        parse_euroc_gt("1,2,3,4,1,0,0,0\n2,3,4\n", source="<x>")


def test_trajectory_validation_and_copy_semantics() -> None:
    stamps = np.array([0.0, 1.0, 2.0])
    pos = np.zeros((3, 3))
    traj = Trajectory.from_positions(stamps, pos)
    assert not traj.has_orientation
    pos[0, 0] = 5.0  # the trajectory holds its own copy
    assert traj.positions[0, 0] == 0.0
    with pytest.raises(EvalInputError, match="increase strictly"):
        Trajectory.from_positions(np.array([0.0, 2.0, 1.0]), pos)
    with pytest.raises(EvalInputError, match="shape"):
        Trajectory.from_positions(stamps, np.zeros((2, 3)))
    with pytest.raises(EvalInputError, match="NaN"):
        Trajectory.from_positions(stamps, np.full((3, 3), np.nan))


def test_transformed_and_distances() -> None:
    traj = _traj(10, seed=3)
    rot = Rotation.from_euler("zyx", [30, 10, -5], degrees=True)
    moved = traj.transformed(rot.as_matrix(), np.array([1.0, 2.0, 3.0]), scale=2.0)
    np.testing.assert_allclose(moved.positions, 2.0 * rot.apply(traj.positions) + [1, 2, 3], atol=1e-12)
    expect = (rot * traj.rotations).as_matrix()
    np.testing.assert_allclose(moved.rotations.as_matrix(), expect, atol=1e-12)
    d = traj.distances_m()
    assert d[0] == 0.0 and d[-1] == pytest.approx(traj.path_length_m())
    assert np.all(np.diff(d) >= 0)
