"""Studies of the engines' numerics: how their outputs change with the settings that buy speed.

Each study reruns the same seeded work under several settings, compares every result with a fine
reference run, and writes the comparison (CSV, plot, markdown) next to the cost of each setting.
Studies only call the engines' public functions; they never change an engine's defaults.
"""
