"""Tests of ampc_vo.config: defaults, the shipped YAML, and errors naming file and field."""
from __future__ import annotations

from pathlib import Path

import pytest

from ampc_vo.config import MODES, VoConfig, config_from_dict, load_config, save_config
from ampc_vo.errors import ConfigError

DEFAULT = Path(__file__).resolve().parents[1] / "configs" / "vo" / "default.yaml"


def test_default_file_equals_dataclass_defaults():
    assert load_config(DEFAULT) == VoConfig()
    assert load_config(None) == VoConfig()


def test_partial_override_and_round_trip(tmp_path):
    config = config_from_dict({"mode": "separate", "smoother": {"lag_s": 5}, "scale": {"smooth_speed_sigma_mps2": None}})
    assert config.mode == "separate" and config.smoother.lag_s == 5.0
    assert config.scale.smooth_speed_sigma_mps2 is None
    assert config.keyframes == VoConfig().keyframes
    save_config(config, tmp_path / "c.yaml")
    assert load_config(tmp_path / "c.yaml") == config


@pytest.mark.parametrize(
    "raw, field",
    [
        ({"mode": "both"}, "mode"),
        ({"smoother": {"lag_s": -1}}, "smoother.lag_s"),
        ({"smoother": {"lagg_s": 1}}, "smoother.lagg_s"),
        ({"colour": 1}, "colour"),
        ({"ransac": {"confidence": 1.5}}, "ransac.confidence"),
        ({"ransac": {"max_iterations": 2.5}}, "ransac.max_iterations"),
        ({"keyframes": {"min_distance_m": "far"}}, "keyframes.min_distance_m"),
        ({"smoother": {"marginals": "yes"}}, "smoother.marginals"),
        ({"output": {"log_level": "LOUD"}}, "output.log_level"),
        ({"keyframes": [1, 2]}, "keyframes"),
        ({"rerun": {"jpeg_quality": 0}}, "rerun.jpeg_quality"),
        ({"rerun": {"image_every": -1}}, "rerun.image_every"),
        ({"frontend_worker": "gpu"}, "frontend_worker"),
        ({"smoother": {"camera_mount_sigma_deg": -0.1}}, "smoother.camera_mount_sigma_deg"),
        ({"smoother": {"camera_mount_sigma_deg_per_mps": -0.01}}, "smoother.camera_mount_sigma_deg_per_mps"),
    ],
)
def test_errors_name_file_and_field(tmp_path, raw, field):
    import yaml

    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(raw))
    with pytest.raises(ConfigError) as error:
        load_config(path)
    assert str(path) in str(error.value) and f": {field}:" in str(error.value)


def test_missing_and_invalid_yaml(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "none.yaml")
    (tmp_path / "x.yaml").write_text("mode: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(tmp_path / "x.yaml")
    (tmp_path / "binary.yaml").write_bytes(b"\xff\xfe\x00garbage\x89")  # used to be a UnicodeDecodeError traceback
    with pytest.raises(ConfigError, match="binary.yaml: not valid YAML"):
        load_config(tmp_path / "binary.yaml")
    (tmp_path / "list.yaml").write_text("- mode\n- full\n")
    with pytest.raises(ConfigError, match="list.yaml: top level: expected a mapping"):
        load_config(tmp_path / "list.yaml")


def test_with_mode():
    for mode in MODES:
        assert VoConfig().with_mode(mode).mode == mode
    with pytest.raises(ConfigError, match="mode"):
        VoConfig().with_mode("fast")


def test_a_moved_key_says_where_it_went():
    from ampc_vo.config import config_from_dict

    with pytest.raises(ConfigError, match="scale.ground_z_m: replaced by hitch_height in rig.yaml"):
        config_from_dict({"scale": {"ground_z_m": -1.2}}, "vo.yaml")


def test_first_line_of_an_error_skips_the_empty_lines_gtsam_begins_with() -> None:
    """One-line logs and batch summaries (``ampc_vo.errors.first_line``): GTSAM's indeterminant-system
    message starts with a newline, which gave an empty "()" in the marginals' warning, and names the
    variable on its second line."""
    from ampc_vo.errors import first_line

    gtsam_like = RuntimeError("\nIndeterminant linear system detected while working near variable\n8070450532247928832 (Symbol: p0).\n\nThought: ...")
    assert first_line(gtsam_like) == "Indeterminant linear system detected while working near variable 8070450532247928832 (Symbol: p0)."
    assert first_line(RuntimeError("")) == "RuntimeError"
    assert first_line(ValueError("one\n\ntwo")) == "one"
