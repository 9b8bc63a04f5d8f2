"""Frames in, keyframe estimates out (DESIGN section 4): motion initialisation from the solvers and
scale sources (:mod:`.motion_init`), the fixed-lag smoother over the custom factors
(:mod:`.smoother`) and the keyframe pipeline that writes the outputs (:mod:`.pipeline`,
``OdometryPipeline``)."""
