"""Grasp stage: MuJoCo trials of a modelled hand grasping, lifting and holding an object."""
