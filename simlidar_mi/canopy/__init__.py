"""canopy"""
