"""Sources of metric scale (DESIGN section 3): the ground plane seen by a calibrated camera
(:mod:`.ground`), an overlapping stereo pair (:mod:`.stereo`) and wheel odometry (:mod:`.wheel`).
Which source sets a keyframe chord is decided in :mod:`ampc_vo.backend.motion_init`."""
