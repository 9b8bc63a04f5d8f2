"""Images to bearings (DESIGN section 4): one KLT tracker per camera (:mod:`.tracker`), cross-camera
matching of overlapping pairs (:mod:`.stereo`), all cameras of the rig (:mod:`.multi_camera`), the
worker process that runs them beside the backend (:mod:`.worker`) and the sequences that turn a
dataset into a stream of :class:`~ampc_vo.observations.FrameObservations` (:mod:`.sources`,
``open_sequence``)."""
