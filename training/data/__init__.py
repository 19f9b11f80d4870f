"""Data sets: COIL folders and class folders, the Plym-like renderer (4.5.2), the built-in scene,
seeded perturbations of test views (7.2) and augmented training views."""
