"""Cameras, rigs, calibration and triangulation."""

from mocap_rt.geometry.camera import Camera, look_at
from mocap_rt.geometry.rig import Rig, RigFileError, read_rig, ring_rig, write_rig

__all__ = ["Camera", "Rig", "RigFileError", "look_at", "read_rig", "ring_rig", "write_rig"]
