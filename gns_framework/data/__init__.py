"""Trajectories, dataset metadata, training windows and batching."""
