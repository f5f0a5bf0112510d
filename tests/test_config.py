"""mocap_rt.config: TOML round trips (stdlib tomllib is the oracle), settings dataclasses from
files, and errors that name the file and the key."""

import math
import tomllib
from dataclasses import dataclass, field, replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap_rt.body.skeleton import BoneLengths, read_bone_lengths, write_bone_lengths
from mocap_rt.config import FileFormatError, dataclass_to_dict, dumps_toml, load_dataclass, read_toml
from mocap_rt.fusion.config import FusionConfig
from mocap_rt.fusion.filter import FilterConfig
from mocap_rt.pipeline_config import PipelineConfig, load_pipeline_config

finite = st.floats(allow_nan=False, allow_infinity=True, width=64)
scalars = st.one_of(st.booleans(), st.integers(-2**62, 2**62), finite, st.text(max_size=12))
keys = st.from_regex(r"[a-z][a-z0-9_]{0,8}", fullmatch=True)


@settings(max_examples=60, deadline=None)
@given(st.dictionaries(keys, st.dictionaries(keys, st.one_of(scalars, st.lists(finite, max_size=4)), max_size=6),
                       min_size=1, max_size=3))
def test_dumps_toml_reads_back_bit_identical_with_tomllib(tables):
    back = tomllib.loads(dumps_toml(tables))
    assert set(back) == set(tables)
    for t, entries in tables.items():
        for k, v in entries.items():
            got = back[t][k]
            if isinstance(v, float):
                assert np.float64(got).tobytes() == np.float64(v).tobytes()
            else:
                assert got == v


def test_dumps_toml_writes_nan_inf_arrays_and_sub_tables():
    text = dumps_toml({"a": {"x": math.nan, "y": -math.inf, "m": np.eye(2), "sub": {"z": 1}}})
    doc = tomllib.loads(text)
    assert math.isnan(doc["a"]["x"]) and doc["a"]["y"] == -math.inf
    assert doc["a"]["m"] == [[1.0, 0.0], [0.0, 1.0]] and doc["a"]["sub"] == {"z": 1}


def test_read_toml_names_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nope\.toml: no such rig file"):
        read_toml(tmp_path / "nope.toml", "rig file")
    bad = tmp_path / "bad.toml"
    bad.write_text("[a\n")
    with pytest.raises(FileFormatError, match=r"bad\.toml: not valid TOML"):
        read_toml(bad)


def test_pipeline_config_round_trips_through_its_file(tmp_path):
    cfg = PipelineConfig(fusion=FusionConfig(views="pair", ik="ccd", bone_lengths=BoneLengths().scaled(1.1),
                                             filter=FilterConfig(gate_m=0.2)))
    cfg = replace(cfg, perception=replace(cfg.perception, roi_margin_px=7,
                                          skin_blobs=replace(cfg.perception.skin_blobs, min_area_px=3.5)))
    path = tmp_path / "c.toml"
    path.write_text(dumps_toml(dataclass_to_dict(cfg)))
    assert load_pipeline_config(path) == cfg


def test_a_partial_sub_table_keeps_the_parents_defaults(tmp_path):
    """FusionConfig's ccd default is CcdConfig(angle_tolerance_deg=20, max_iterations=30), not
    CcdConfig(): a [fusion.ccd] table changes only the keys it names."""
    path = tmp_path / "c.toml"
    path.write_text("[fusion.ccd]\npolish = false\n")
    got = load_pipeline_config(path)
    assert got.fusion.ccd == replace(FusionConfig().ccd, polish=False)
    assert got.perception == PipelineConfig().perception


@pytest.mark.parametrize("text, message", [
    ("[fusion]\nviwes = 'pair'\n", r"c\.toml \[fusion\]: unknown key\(s\) \['viwes'\]"),
    ("[fusoin]\nviews = 'pair'\n", r"c\.toml: unknown key\(s\) \['fusoin'\]"),
    ("[fusion.filter]\ngate = 1.0\n", r"c\.toml \[fusion\] \[filter\]: unknown key\(s\) \['gate'\]"),
    ("[fusion]\nviews = 'pairs'\n", r"c\.toml \[fusion\]: FusionConfig.views must be one of"),
    ("[fusion]\nsilhouettes = 1\n", r"c\.toml \[fusion\]: silhouettes = 1 is not a boolean"),
    ("[perception]\nroi_margin_px = 2.5\n", r"c\.toml \[perception\]: roi_margin_px = 2.5 is not an integer"),
    ("[perception]\nskin_blobs = 3\n", r"c\.toml \[perception\]: skin_blobs must be a table"),
])
def test_bad_settings_name_file_and_key(tmp_path, text, message):
    path = tmp_path / "c.toml"
    path.write_text(text)
    with pytest.raises(FileFormatError, match=message):
        load_pipeline_config(path)


def test_load_dataclass_table_rules(tmp_path):
    @dataclass(frozen=True)
    class S:
        a: float = 1.0
        names: tuple[str, ...] = ("x",)
        inner: FilterConfig = field(default_factory=FilterConfig)

    p = tmp_path / "s.toml"
    p.write_text("a = 2\nnames = ['p', 'q']\n")                # top-level fields
    assert load_dataclass(S, p, "s") == S(a=2.0, names=("p", "q"))
    p.write_text("[s]\na = 3\n")                                # its table
    assert load_dataclass(S, p, "s") == S(a=3.0)
    p.write_text("[s]\na = 3\n[t]\nb = 1\n")                    # something beside it
    with pytest.raises(FileFormatError, match=r"s\.toml: unknown key\(s\) \['t'\] beside \[s\]"):
        load_dataclass(S, p, "s")
    p.write_text("a = 3\n")
    with pytest.raises(FileFormatError, match=r"s\.toml: missing \[s\] table"):
        load_dataclass(S, p, "s", required=True)


def test_bone_lengths_file_is_read_by_the_common_loader(tmp_path):
    path = tmp_path / "bones.toml"
    L = BoneLengths().scaled(0.93)
    write_bone_lengths(L, path)
    assert read_bone_lengths(path) == L
    path.write_text("[bones]\nthigh_m = 0.4\n[extra]\nx = 1\n")
    with pytest.raises(FileFormatError, match=r"bones\.toml: unknown key\(s\) \['extra'\]"):
        read_bone_lengths(path)


def test_every_reader_error_is_a_file_format_error():
    from mocap_rt.geometry.rig import RigFileError
    from mocap_rt.io.bvh import BvhError
    from mocap_rt.io.recording import RecordingError
    from mocap_rt.markers.io import MarkerFileError
    from mocap_rt.markers.segments import SegmentError
    from mocap_rt.perception.colour_model import ColourModelError
    from mocap_rt.studio.body_map import SkeletonMapError

    for cls in (RigFileError, BvhError, RecordingError, MarkerFileError, SegmentError, ColourModelError,
                SkeletonMapError):
        assert issubclass(cls, FileFormatError) and issubclass(cls, ValueError)


def _settings_dataclasses():
    """Every settings dataclass of the library (``*Config``, ``*Params``, ``*Thresholds``,
    ``BoneLengths``, ``StudioScene``), found by walking the package."""
    import dataclasses
    import importlib
    import pkgutil

    import mocap_rt

    found = {}
    for m in pkgutil.walk_packages(mocap_rt.__path__, "mocap_rt."):
        mod = importlib.import_module(m.name)
        for name, obj in vars(mod).items():
            if (isinstance(obj, type) and dataclasses.is_dataclass(obj) and obj.__module__ == mod.__name__
                    and (name.endswith(("Config", "Params", "Thresholds")) or name in ("BoneLengths", "StudioScene"))):
                found[f"{mod.__name__}.{name}"] = obj
    return found


def test_every_settings_dataclass_is_loadable_from_its_file(tmp_path):
    found = _settings_dataclasses()
    assert {"mocap_rt.fusion.config.FusionConfig", "mocap_rt.perception.pipeline.PerceptionConfig",
            "mocap_rt.studio.render.RenderConfig", "mocap_rt.studio.scene.StudioScene"} <= set(found)
    for name, cls in found.items():
        default = cls()
        path = tmp_path / f"{name}.toml"
        path.write_text(dumps_toml({"t": dataclass_to_dict(default)}))
        assert load_dataclass(cls, path, "t") == default, name


def test_tuples_of_settings_are_checked_element_by_element(tmp_path):
    from mocap_rt.studio.scene import StudioScene

    path = tmp_path / "s.toml"
    path.write_text("lights = [{ direction = [0.0, 0.0, 1.0], intensity = 0.5, colour = 1 }]\n")
    with pytest.raises(FileFormatError, match=r"s\.toml lights\[0\]: unknown key\(s\) \['colour'\]"):
        load_dataclass(StudioScene, path)
    path.write_text("ceiling_bgr = [0.2, 0.2]\n")
    with pytest.raises(FileFormatError, match=r"s\.toml: ceiling_bgr = \[0.2, 0.2\] is not a list of 3"):
        load_dataclass(StudioScene, path)
