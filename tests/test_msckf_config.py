"""MsckfConfig as a composition of option groups: the flat-key table, nested keys, errors, round trips."""

from __future__ import annotations

import dataclasses

import pytest

from msckf.config import FLAT_KEYS, GROUPS, MsckfConfig, load_config
from msckf.errors import MsckfInputError
from msckf.frontend_config import FrontendConfig
from msckf.options import DepthOptions, UpdateOptions


def test_table_covers_every_group_field_exactly_once():
    """Every field of every group has one flat key (so every parameter enters the run key), and no key more."""
    fields = {(g, f.name) for g, cls in GROUPS.items() if cls is not FrontendConfig for f in dataclasses.fields(cls)}
    assert {(g, name) for name, g in FLAT_KEYS.items()} == fields
    assert len(FLAT_KEYS) == len(fields) == 67
    assert not set(FLAT_KEYS) & set(GROUPS)        # no flat key shadows a group name


def test_flat_and_nested_keys_build_the_same_config(tmp_path):
    flat = load_config({"feature_noise": 0.0003, "depth_row": False, "max_cam_state_size": 12,
                        "frontend": {"grid_row": 3}})
    nested = load_config({"update": {"feature_noise": 0.0003}, "depth": {"depth_row": False},
                          "window": {"max_cam_state_size": 12}, "frontend": {"grid_row": 3}})
    assert flat == nested
    assert flat.update.feature_noise == 0.0003 and flat.depth.depth_row is False and flat.frontend.grid_row == 3
    p = tmp_path / "c.yaml"
    p.write_text("feature_noise: 0.0003\ndepth:\n  depth_row: false\nwindow: {max_cam_state_size: 12}\n"
                 "frontend: {grid_row: 3}\n")
    assert load_config(p) == flat
    assert load_config(flat.to_flat_dict()) == flat
    assert load_config(flat.to_grouped_dict()) == flat
    mixed = load_config({"update": UpdateOptions(chi2_quantile=0.9), "feature_noise": 0.01,
                         "depth": DepthOptions(depth_seed=False)})
    assert (mixed.update.chi2_quantile, mixed.update.feature_noise, mixed.depth.depth_seed) == (0.9, 0.01, False)


def test_flat_dict_is_the_former_flat_mapping():
    d = MsckfConfig().to_flat_dict()
    assert list(d) == [*FLAT_KEYS, "frontend"]
    assert d["initial_velocity"] == [0.0, 0.0, 0.0] and d["frontend"] == FrontendConfig().to_dict()
    assert MsckfConfig().to_dict() == d


def test_errors_name_the_key_and_the_file(tmp_path):
    p = tmp_path / "vio.yaml"
    p.write_text("update:\n  feature_nois: 0.01\n")
    with pytest.raises(MsckfInputError, match=r"vio.yaml.*update\.feature_nois"):
        load_config(p)
    with pytest.raises(MsckfInputError, match=r"config mapping.*update\.depth_row"):
        load_config({"update": {"depth_row": True}})   # a real key, but of another group
    with pytest.raises(MsckfInputError, match="feature_noise given twice"):
        load_config({"feature_noise": 0.01, "update": {"feature_noise": 0.02}})
    with pytest.raises(MsckfInputError, match="'depth' must be a mapping"):
        load_config({"depth": 3})
    p.write_text("gyro_noise: 0\n")
    with pytest.raises(MsckfInputError, match=r"vio.yaml: msckf config: gyro_noise=0.0 must be > 0"):
        load_config(p)
    with pytest.raises(MsckfInputError, match="initial_velocity"):
        load_config({"initial_velocity": [1, 2]})
    with pytest.raises(MsckfInputError, match="window must be a WindowOptions"):
        MsckfConfig(window=UpdateOptions())
