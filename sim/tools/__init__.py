"""Rigid forming tools: SDF programs with exact derivatives (sdf) and display meshes (meshes)."""

from .meshes import tool_mesh
from .sdf import (
    blank_holder,
    box,
    die_ring,
    extruded_polygon,
    intersect,
    moved,
    plane,
    punch,
    revolved,
    rotation,
    rounded_box,
    sdf_distance,
    sdf_eval,
    sdf_world,
    sdf_world_distance,
    star,
    star_die,
    subtract,
    to_local,
    transform,
    union,
)

__all__ = [
    "blank_holder", "box", "die_ring", "extruded_polygon", "intersect", "moved", "plane",
    "punch", "revolved", "rotation", "rounded_box", "sdf_distance", "sdf_eval", "sdf_world",
    "sdf_world_distance", "star", "star_die", "subtract", "to_local", "transform", "union",
    "tool_mesh",
]
