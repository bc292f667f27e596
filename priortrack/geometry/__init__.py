"""Camera models and geometric helpers (metres and radians, world Y-up, pixels for 2D)."""
