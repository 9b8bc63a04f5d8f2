"""The synthetic world (DESIGN section 6): routes, tractor-trailer kinematics, scene, renderer,
textures and the generation of bearing measurements; it writes dataset folders through
:mod:`ampc_vo.io`. The estimator never imports this package (``tests/test_layout.py``)."""
