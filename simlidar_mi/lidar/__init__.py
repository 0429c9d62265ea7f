"""LiDAR: platforms and beam patterns, the scan, surveys (scene -> scan -> files), the §5 study, a float64 reference."""
