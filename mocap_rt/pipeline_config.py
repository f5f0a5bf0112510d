"""The capture pipeline's settings file: ``[perception]`` and ``[fusion]`` tables in one TOML.

Owns ``PipelineConfig`` (a ``PerceptionConfig`` and a ``FusionConfig``) and its reader, used by
``mocap-rt perceive`` / ``mocap-rt process --config FILE``. Example::

    [perception]
    roi_margin_px = 24
    [perception.skin_blobs]
    min_area_px = 12.0
    [fusion]
    views = "pair"
    [fusion.filter]
    gate_m = 0.3

A missing table keeps its defaults; unknown tables and keys are errors naming file and key.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from mocap_rt.config import load_dataclass
from mocap_rt.fusion.config import FusionConfig
from mocap_rt.perception.pipeline import PerceptionConfig


@dataclass(frozen=True)
class PipelineConfig:
    """Settings of perception (per camera) and fusion (``fusion.fps`` is the recording's
    or the trigger's frame rate wherever one is known)."""

    perception: PerceptionConfig = field(default_factory=PerceptionConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)


def load_pipeline_config(path: str | Path) -> PipelineConfig:
    """Read a ``PipelineConfig`` TOML file (module docstring); ``FileFormatError`` naming
    the file and the key on unknown keys or bad values."""
    return load_dataclass(PipelineConfig, path)
