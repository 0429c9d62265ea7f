"""Writers and readers: EXR, LAS, PNG, PLY/OBJ, CSV; outputs written whole or not at all."""
