"""Aligning an estimate to a reference: Umeyama SE(3) / Sim(3), position + yaw (4-DoF), or none.

All alignments are fitted on *positions* only (as evo and rpg_trajectory_evaluation do), so they work with a
position-only reference such as Rosario's GPS ground truth; orientations of the estimate follow the fitted
rotation. The fitted transform maps estimate-world points into the reference world:
``p_ref ≈ s · R · p_est + t``, i.e. it is ``T_refworld_estworld`` (with scale ``s`` for Sim(3)).

The lever arm: the reference may track a point other than the estimate's body origin (Rosario: the GPS antenna).
:func:`apply_lever_arm` expresses the estimate at that point, ``p_antenna = p + R_world_body · t_body_antenna``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from eval.errors import EvalInputError
from eval.quat import qrotate
from eval.trajectory import Trajectory

__all__ = ["ALIGN_METHODS", "Alignment", "umeyama", "align_yaw", "fit_alignment", "apply_lever_arm"]

#: Names accepted by :func:`fit_alignment`.
ALIGN_METHODS = ("se3", "sim3", "posyaw", "none")

_RANK_TOL = 1e-10  # relative: second singular value / first of the centred points below this = collinear


@dataclass(frozen=True)
class Alignment:
    """A similarity transform ``p' = scale · R · p + t`` (R (3,3), t (3,) metres), and how it was obtained.

    Attributes:
        method: one of :data:`ALIGN_METHODS`.
        rotation: (3, 3) float64 rotation matrix.
        translation: (3,) float64, metres.
        scale: 1.0 except for ``sim3``.
        n_pairs: number of position pairs the fit used.
    """

    method: str
    rotation: np.ndarray
    translation: np.ndarray
    scale: float = 1.0
    n_pairs: int = 0

    @classmethod
    def identity(cls, n_pairs: int = 0) -> Alignment:
        return cls("none", np.eye(3), np.zeros(3), 1.0, n_pairs)

    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous Sim(3) matrix ``[[s·R, t], [0, 1]]``."""
        out = np.eye(4)
        out[:3, :3] = self.scale * self.rotation
        out[:3, 3] = self.translation
        return out

    def apply(self, traj: Trajectory) -> Trajectory:
        """The trajectory with positions ``s·R·p + t`` and orientations ``R·R_world_body``."""
        return traj.transformed(self.rotation, self.translation, self.scale)

    def apply_points(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) points → ``s·R·p + t``."""
        return self.scale * np.asarray(points, dtype=np.float64) @ self.rotation.T + self.translation

    def yaw_deg(self) -> float:
        """Heading of the rotation about z (degrees), for reports."""
        return float(np.degrees(np.arctan2(self.rotation[1, 0], self.rotation[0, 0])))

    def to_dict(self) -> dict:
        """JSON-able summary (rotation row-major)."""
        return {"method": self.method, "rotation": self.rotation.tolist(), "translation_m": self.translation.tolist(),
                "scale": float(self.scale), "n_pairs": int(self.n_pairs)}


def _check_pairs(src: np.ndarray, dst: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray]:
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.ndim != 2 or src.shape[1] != 3 or src.shape != dst.shape:
        raise EvalInputError(f"{what} alignment needs two (N, 3) position arrays of equal shape, got "
                             f"{src.shape} and {dst.shape}")
    if src.shape[0] < 3:
        raise EvalInputError(f"{what} alignment needs at least 3 associated poses, got {src.shape[0]} "
                             f"(check the time overlap and --max-diff)")
    return src, dst


def _spread(points_centred: np.ndarray) -> np.ndarray:
    """Singular values of centred points (descending), scaled by sqrt(N)."""
    return np.linalg.svd(points_centred, compute_uv=False) / np.sqrt(points_centred.shape[0])


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = False) -> Alignment:
    """Least-squares similarity (Umeyama 1991) with ``dst ≈ s·R·src + t``.

    Args:
        src: (N, 3) estimate positions, metres.
        dst: (N, 3) reference positions, metres (same order).
        with_scale: fit the scale (Sim(3)); otherwise s = 1 (SE(3)).

    Raises:
        EvalInputError: fewer than 3 pairs, or positions (of either trajectory) all on one line or one point,
            for which the rotation about that line is undetermined.
    """
    what = "Sim(3)" if with_scale else "SE(3)"
    src, dst = _check_pairs(src, dst, what)
    n = src.shape[0]
    mu_s = src.mean(axis=0)
    mu_d = dst.mean(axis=0)
    xs = src - mu_s
    xd = dst - mu_d
    for name, pts in (("estimate", xs), ("reference", xd)):
        sv = _spread(pts)
        if sv[0] <= 1e-12 or sv[1] <= _RANK_TOL * sv[0]:
            raise EvalInputError(f"{what} alignment is degenerate: the {name} positions lie on one line "
                                 f"(or one point), so the rotation about it is undetermined; use --align posyaw "
                                 f"or --align none")
    sigma = xd.T @ xs / n
    u, d, vt = np.linalg.svd(sigma)
    s_fix = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0.0:
        s_fix[2] = -1.0
    rot = (u * s_fix) @ vt
    scale = 1.0
    if with_scale:
        var_s = float(np.sum(xs * xs) / n)
        scale = float(np.sum(d * s_fix) / var_s)
    t = mu_d - scale * rot @ mu_s
    return Alignment("sim3" if with_scale else "se3", rot, t, scale, n)


def align_yaw(src: np.ndarray, dst: np.ndarray) -> Alignment:
    """Position + yaw (4-DoF) least squares: rotation about z only, translation, no scale.

    ``dst ≈ Rz(θ)·src + t`` with θ = atan2(Σ(eₓg_y − e_yg_ₓ), Σ(eₓgₓ + e_yg_y)) over the centred positions —
    the closed form used by rpg_trajectory_evaluation's ``posyaw`` for visual-inertial estimates (gravity makes
    roll and pitch observable, so only yaw and translation are free). Assumes both worlds are z-up.

    Raises:
        EvalInputError: fewer than 3 pairs, or positions whose horizontal (x, y) spread is zero (a vertical line
            or a single point), for which the yaw is undetermined. A straight horizontal line is fine.
    """
    src, dst = _check_pairs(src, dst, "position+yaw")
    mu_s = src.mean(axis=0)
    mu_d = dst.mean(axis=0)
    xs = src - mu_s
    xd = dst - mu_d
    a = float(np.sum(xs[:, 0] * xd[:, 0] + xs[:, 1] * xd[:, 1]))
    b = float(np.sum(xs[:, 0] * xd[:, 1] - xs[:, 1] * xd[:, 0]))
    norm = float(np.sqrt(np.sum(xs[:, :2] ** 2) * np.sum(xd[:, :2] ** 2)))
    if norm <= 1e-24 or np.hypot(a, b) <= _RANK_TOL * norm:
        raise EvalInputError("position+yaw alignment is degenerate: the horizontal positions do not move (or the "
                             "two trajectories' horizontal motions are uncorrelated), so the yaw is undetermined; "
                             "use --align none")
    theta = np.arctan2(b, a)
    c, s = np.cos(theta), np.sin(theta)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    t = mu_d - rot @ mu_s
    return Alignment("posyaw", rot, t, 1.0, src.shape[0])


def fit_alignment(ref: Trajectory, est: Trajectory, method: str = "se3", first_n: int | None = None) -> Alignment:
    """Fit the alignment of associated trajectories (pose i of ``est`` pairs with pose i of ``ref``).

    Args:
        method: ``se3`` | ``sim3`` | ``posyaw`` | ``none``.
        first_n: fit on the first ``first_n`` pairs only (evo's ``--n_to_align``); None = all.
    """
    if method not in ALIGN_METHODS:
        raise EvalInputError(f"unknown alignment {method!r}; choose one of {', '.join(ALIGN_METHODS)}")
    if len(ref) != len(est):
        raise EvalInputError(f"alignment needs associated trajectories of equal length, got {len(ref)} and {len(est)}")
    n = len(est) if first_n is None else int(first_n)
    if n < 1:
        raise EvalInputError(f"first_n must be >= 1, got {first_n}")
    src = est.positions[:n]
    dst = ref.positions[:n]
    if method == "none":
        return Alignment.identity(src.shape[0])
    if method == "posyaw":
        return align_yaw(src, dst)
    return umeyama(src, dst, with_scale=(method == "sim3"))


def apply_lever_arm(traj: Trajectory, t_body_point: np.ndarray) -> Trajectory:
    """Express ``traj`` at a point rigidly attached to the body: ``p' = p + R_world_body · t_body_point``.

    Args:
        traj: poses ``T_world_body`` with orientation.
        t_body_point: (3,) metres, the point (e.g. the GPS antenna) in the body frame.

    Raises:
        EvalInputError: when ``traj`` has no orientation (the offset direction is then unknown).
    """
    t = np.asarray(t_body_point, dtype=np.float64).reshape(3)
    if not traj.has_orientation:
        if np.allclose(t, 0.0):
            return traj
        raise EvalInputError("a lever arm needs the estimate's orientation, but the estimate has none")
    positions = traj.positions + qrotate(traj.quats_xyzw, t)
    return Trajectory(traj.stamps_s, positions, traj.quats_xyzw, has_orientation=True)
