"""o3d_terrain."""
