"""Per-keyframe fitting targets: hair mask (:mod:`.mask`), 2D orientation (:mod:`.orientation`),
relative depth (:mod:`.depth`); assembled and written by :mod:`.build`."""
