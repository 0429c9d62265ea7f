"""Plant generators: scene parameters -> plain geometry (Branches, Leaves), no Mitsuba."""
