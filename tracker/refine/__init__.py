"""Pose refinement after the filter: dense-depth Gauss-Newton, ICP, loss detection and recovery."""
