"""The MSCKF part of a run's input key must not move when the config code is reorganised.

The pinned hashes were computed from the flat ``MsckfConfig`` of commit e3efd1d (before the config was grouped into
option types): a change here would silently invalidate every cached run record. A new parameter changes them on
purpose (it enters the key): ``depth_track_bias`` (issue 17) moved them from 1c8db5cba7e9d24e / f7db3973c980b9ab,
``depth_fallback`` (issue 17) from 8a3ac494bea3776b / 3573a898843efcdc, its default turned on (stop 25) from
b0361905f190c692 / 5d6195b13573cdac, ``gate_noise`` (issue 17, stop 26) from d0fd4320c2ff2890 /
167539a90d36ccf4, ``stereo_gate_noise`` (on by default, stop 26) from 0f0ab2d474ac9d7e / 1878cb1caddbe816, and
``depth_fallback_measured`` (issue 17, stop 33) from 77057be89b7ed8cc / 20b8d5e46530d155, and
``gate_depth_scale`` (issue 17, stop 34) from ee50e97f37739dc3 / e06ed8280159a524, and ``depth_keep_mono``
(issue 17, stop 34, off by default: monocular observations ignored) from d3fa1b5a259bbd9e / 60409072592004ca, and
the depth front end's tight gate (``gate_noise`` 0.0005 + ``gate_depth_scale`` 0.1 by default, stop 35) from
764a6c51980062fc / 7c4ba0c8b1c25055, and ``depth_sigma_at_prediction`` (stop 35, off) from 66600821a1f038fb /
4ba30d7e99b0836a, and ``depth_shared_rel_sigma`` (stop 40, off) from 3be352d36cc9280c / 0e3b5d7e170fff13, and
``stereo_feature_noise`` / ``stereo_track_drift_psd`` (stop 40, on) from 3eaf00189941e3c7 / 754befe52ccf5ad5, and
``depth_fills_only_unmeasured`` (stop 41, off) from ba2dc77ce0aa2753 / 6dffeb4866423741, and its default turned on
(stop 41) from eb145e291d11ca40 / 3e1cce0ee7ef4dea, and ``depth_sigma_scale`` (stop 42, 1 = off) from
818c24d0a25cbc79 / b479da2117abe716, and ``gate_depth_scale`` 0.1 → 0.03 by default (stop 43) from
65ee772b8395b1d4 / 981d481161a82396, and the front end's ``klt_fb_max_px`` (stop 45, 0 = off) from
911d0e7895695d16 / 24cd55104d428aa3, and ``depth_min_rel_sigma`` (stop 46, 0 = off) from 7a0bdb88a6532eda /
a6d0fc094c81d1cb, and the static initialisation's measured covariance (``static_bias_from_window``,
``static_velocity_cov``, ``static_tilt_from_acc_bias``; stop 47, on: every run changes) from 15ae15411194b075 /
f61e193028f9361d, and ``retriangulate`` (stop 47, on) from 62c258e6667236ff / bbafdd7217e3e782, and the
zero-velocity update (``zupt_max_flow``, ``zupt_velocity_sigma``; stop 47, first on, then off by default) from
e03acdc461132ca8 / c07badf395c7e08f (on: 3781e088578e56db / 00fb73258abeb0cc), and ``zupt_only_at_start`` with the
zero-velocity update on (stop 48) from 8862fa15199afecc / afd7e85b17b66a49, and ``extrinsics_after_motion`` (stop
49, off) from 29378ac9b91ae437 / af54a6b71128b0b1.
"""

from __future__ import annotations

from eval.records import config_hash
from pipeline.run_key import input_key, job_key_parts, sequence_key_parts
from pipeline.validate import check_msckf_config

#: config_hash of the default MSCKF config as it enters the run key (pipeline.validate.check_msckf_config(None)).
DEFAULT_MSCKF_HASH = "346405744df0c581"
#: input_key of a stereo job built from fixed, made-up sequence parts and the default MSCKF config.
DEFAULT_JOB_KEY = "d45f922be53d07ba"


def _job_key(msckf: dict) -> str:
    parts = sequence_key_parts("bag-id", None, __file__, 100, {"lever_arm_imu": [0, 0, 0]}, msckf, "dkey", None, "v1")
    parts["camchain"] = None  # the digest of this test file would change with every edit of it
    return input_key(job_key_parts(parts, "stereo", 0))


def test_default_msckf_key_is_pinned():
    flat = check_msckf_config(None)
    assert config_hash(flat) == DEFAULT_MSCKF_HASH
    assert _job_key(flat) == DEFAULT_JOB_KEY


def test_overridden_msckf_key_changes(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("feature_noise: 0.0003\n")
    assert config_hash(check_msckf_config(p)) != DEFAULT_MSCKF_HASH
