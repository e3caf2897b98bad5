"""Visual motion tracking of a capsule endoscope (the thesis' Chapter 3) and a capsule camera
renderer that gives it frames with exact ground truth. See docs/vision.md."""
