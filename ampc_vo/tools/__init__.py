"""Everything around the estimator: evaluation against ground truth, Rerun recordings, the runner
behind ``scripts/run_odometry.py``, the demo, experiments and the KITTI peer baseline. Tools may use
the simulator; nothing in the estimator imports a tool."""
