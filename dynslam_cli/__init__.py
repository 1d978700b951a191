"""dynslam: 2D laser SLAM in dynamic environments (Wolf & Sukhatme 2005) over recorded logs."""

__version__ = "0.1.0"
