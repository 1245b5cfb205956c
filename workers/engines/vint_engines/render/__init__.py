"""Render stage: Blender Cycles (CPU) images of the object in hand, with depth, mask and camera."""
