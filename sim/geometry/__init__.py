"""The sheet's geometry: triangle meshes of its mid-surface (trimesh), their extrusion into a layer
of prisms (shell), quadrature rules, and the rigid-body modes of a free part (rigid)."""
