"""Geometry -> Mitsuba shapes: meshes, curves, instancing and the float64 scene origin."""
