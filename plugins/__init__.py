"""Mitsuba plugins: the LiDAR sensors and the range and coverage integrators."""
