"""Localization (paper Sec. 4): where the robot is.

Front end, per scan and from the scan alone: ``scanmatch`` (ICP against a local map, with
the match's information), ``corners`` (the landmark observations), ``frontend`` (both: each
scan's measurement, read ahead by dynslam_cli.readahead). The filter: ``ekf`` (EKF-SLAM
maths) and ``cornerslam`` (association, the tentative stage and Table 3 over the EKF). Back
end: ``graph`` (the pose graph and its sparse solve) and ``loops`` (loop closure:
correlative search, ICP, consistency). Each compiled kernel (``_match``, ``_corners``,
``_loops``, ``_graph``) sits beside the module it serves.
"""
