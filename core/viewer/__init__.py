"""Run replay and live view: a self-contained HTML page of the tree, map and trajectories."""
