"""``spotless prepare``: what a robot brings becomes a dataset the trainer reads.

* :func:`prepare_images` — a folder of spotlit frames → COLMAP dataset (SfM on brightened copies);
* :func:`prepare_bag` — one camera of a ROS 1/2 bag → a posed dataset (odometry) or the frames through SfM;
* :func:`add_sfm_points` — a posed dataset without a point cloud → sparse points triangulated with its poses;
* :func:`add_depth_points` — a posed dataset with an RGB-D camera's depth images → a dense cloud from them.
"""

from spotlessgs.prepare.bag import prepare_bag
from spotlessgs.prepare.depth_points import DEPTH_POINTS_FILE, add_depth_points, has_depth_images
from spotlessgs.prepare.images import SUMMARY_FILE, brighten, prepare_images
from spotlessgs.prepare.points import POINTS_FILE, add_sfm_points

__all__ = ["DEPTH_POINTS_FILE", "POINTS_FILE", "SUMMARY_FILE", "add_depth_points", "add_sfm_points", "brighten",
           "has_depth_images", "prepare_bag", "prepare_images"]
