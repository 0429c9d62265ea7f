"""Canopy ground truth from the geometry, LiDAR estimators, and their comparison (issue #10).

The voxel grid and its NetCDF format are in :mod:`simlidar_mi.truth.grid`.
"""
