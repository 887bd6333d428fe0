"""IMU measurements from the true kinematics: bias random walk, white noise and structural vibration.

Measurement model (IMU axes, Rosario x ≈ up, y ≈ right, z ≈ forward):

* ``gyro  = ω_I + b_g + n_g + v_g``, ``accel = R_FI^T (a_I − g) + b_a + n_a + v_a``;
* ``n``: white, per-sample σ = noise density · √rate; ``b``: initial N(0, bias_std) plus a random walk with
  per-sample σ = random-walk density · √dt;
* ``v``: engine/structure vibration, a few sinusoids between 25 and 65 Hz with slowly drifting amplitude,
  proportional to the speed. It is zero-mean and carries micrometre displacements, so it is left out of the
  trajectory; sampled at 142 Hz it aliases into broadband noise, as on the real robot.

Noise is drawn in fixed blocks of samples, each from its own ``SeedSequence([seed, stream, block])``, so the
output does not depend on how the caller chunks the stream.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.sim.config import ImuConfig
from pipeline.sim.trajectory import RobotTrajectory

_BLOCK = 1024


def block_normals(seed: int, stream: int, start: int, count: int, dims: int) -> np.ndarray:
    """Standard normals for sample indices ``start .. start+count`` (count, dims), chunking-independent."""
    out = np.empty((count, dims))
    if count <= 0:
        return out
    b0, b1 = start // _BLOCK, (start + count - 1) // _BLOCK
    pos = 0
    for b in range(b0, b1 + 1):
        block = np.random.default_rng([seed, stream, b]).standard_normal((_BLOCK, dims))
        lo = max(start - b * _BLOCK, 0)
        hi = min(start + count - b * _BLOCK, _BLOCK)
        out[pos:pos + hi - lo] = block[lo:hi]
        pos += hi - lo
    return out


@dataclass
class ImuChunk:
    """IMU samples: stamps (seconds since start), gyro (N, 3) rad/s, accel (N, 3) m/s², and the true biases."""

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    bias_gyro: np.ndarray
    bias_accel: np.ndarray


class ImuSimulator:
    """Streams IMU samples at ``t_k = k / rate`` (call :meth:`next` with increasing, contiguous index ranges).

    Args:
        cfg: noise parameters (``cfg.ideal()`` for a perfect IMU).
        trajectory: the true motion.
        seed: noise seed.
    """

    def __init__(self, cfg: ImuConfig, trajectory: RobotTrajectory, seed: int) -> None:
        self.cfg = cfg
        self.traj = trajectory
        self.seed = int(seed)
        self.dt = 1.0 / cfg.rate_hz
        rng = np.random.default_rng([seed, 600])
        self._bg = rng.normal(0.0, cfg.gyro_bias_std, 3)
        self._ba = rng.normal(0.0, cfg.acc_bias_std, 3)
        self._next = 0
        f = rng.uniform(25.0, 65.0, (2, 3, 3))  # (gyro/acc, axis, component) Hz
        self._vib_f = f
        self._vib_phase = rng.uniform(0, 2 * np.pi, f.shape)
        self._vib_amp = rng.uniform(0.5, 1.0, f.shape)
        self._vib_amp /= np.sqrt((self._vib_amp ** 2).sum(-1, keepdims=True) / 2.0)  # unit RMS per axis

    @property
    def initial_biases(self) -> tuple[np.ndarray, np.ndarray]:
        return self._bg.copy(), self._ba.copy()

    def next(self, count: int) -> ImuChunk:
        """The next ``count`` samples."""
        k0 = self._next
        idx = np.arange(k0, k0 + count)
        t = idx * self.dt
        kin = self.traj.kinematics(t)
        c = self.cfg
        sq = np.sqrt(self.dt)
        # bias random walk (the bias of sample k includes the steps of samples 1..k)
        wg = block_normals(self.seed, 601, k0, count, 3) * (c.gyro_random_walk * sq)
        wa = block_normals(self.seed, 602, k0, count, 3) * (c.acc_random_walk * sq)
        if k0 == 0:
            wg[0] = 0.0
            wa[0] = 0.0
        bg = self._bg + np.cumsum(wg, axis=0)
        ba = self._ba + np.cumsum(wa, axis=0)
        self._bg, self._ba = bg[-1].copy(), ba[-1].copy()
        ng = block_normals(self.seed, 603, k0, count, 3) * (c.gyro_noise_density / sq)
        na = block_normals(self.seed, 604, k0, count, 3) * (c.acc_noise_density / sq)
        speed = np.clip(self.traj.planned_speed(t), 0.0, None)[:, None]
        drift = 0.75 + 0.25 * np.sin(2 * np.pi * 0.13 * t)[:, None]
        vib = [(np.sin(2 * np.pi * self._vib_f[j][None] * t[:, None, None] + self._vib_phase[j][None])
                * self._vib_amp[j][None]).sum(-1) * speed * drift for j in (0, 1)]
        gyro = kin.gyro + bg + ng + vib[0] * c.vibration_gyro_rms
        accel = kin.specific_force + ba + na + vib[1] * c.vibration_acc_rms
        self._next += count
        return ImuChunk(t, gyro, accel, bg, ba)
