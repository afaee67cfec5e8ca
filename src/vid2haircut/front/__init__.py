"""Front stages of the pipeline: keyframes, head pose fitting and per-keyframe targets.

- :mod:`.keyframes` — keyframe selection (``keyframes.json``)
- :mod:`.landmarks`, :mod:`.facemesh_ibug` — iBUG-68 landmarks from files or MediaPipe Face Mesh
- :mod:`.pose` — robust PnP + joint shape/pose refinement; :mod:`.headfile` — ``head.npz``
- :mod:`.targets` — hair mask, Gabor orientation, relative depth (``frame_<t>.npz``)
- :mod:`.figures` — contact sheet, head overlay, orientation colour maps
- :mod:`.stages` — one function per pipeline stage (called by the CLI)
"""
