"""Rigid forming tools: SDF programs (sdf) and their display meshes (meshes)."""
