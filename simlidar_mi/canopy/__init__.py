"""Gap fraction: renders of virtual canopies, photo classifiers, virtual vs measured, synthetic photos."""
