"""Random forests: Poisson placement, parameters and seeds, the stand, its files and the command."""
