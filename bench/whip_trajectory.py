#!/usr/bin/env python3
"""A camera turning on the spot with two whips: the trajectory behind NOTES 124's defect (a frame
tracked 25 cm off at the first frame of a whip, reported as tracked).

usage (numpy, scipy): ~/.cache/dynamap-peers/bin/python bench/whip_trajectory.py OUT.txt
then:  ~/.cache/dynamap-peers/bin/python ../shared/bench/render_sequence.py OUT.txt SEQ \\
           --frames 235 --sensor kinect --seed 5
       target/release/rigid_slam SEQ --output est.txt -v

The camera stays at the first pose of TUM's fr1/xyz ground truth and turns about the world's z
axis: 15 deg/s * sin(2 pi t / 4 s), except +360 deg/s over 2.5-3.0 s and -360 deg/s over 5.5-6.0 s.
Written at 100 Hz for 8 s in TUM's format (timestamp tx ty tz qx qy qz qw).
"""
import os, sys
import numpy as np
from scipy.spatial.transform import Rotation as R

FR1 = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "data", "rgbd",
                   "tum_trajectories", "freiburg1_xyz-groundtruth.txt")


def rate(s):
    """Turn rate about world z at time s, deg/s."""
    if 2.5 <= s < 3.0:
        return 360.0
    if 5.5 <= s < 6.0:
        return -360.0
    return 15.0 * np.sin(2 * np.pi * s / 4)


def main():
    base = np.loadtxt(FR1, comments="#")[0]
    p0, q0 = base[1:4], R.from_quat(base[4:8])
    t = np.arange(0, 8.0, 1 / 100)
    yaw = np.cumsum([rate(s) for s in t]) / 100
    with open(sys.argv[1], "w") as f:
        f.write("# timestamp tx ty tz qx qy qz qw\n")
        for s, a in zip(t, yaw):
            q = (R.from_euler("z", a, degrees=True) * q0).as_quat()
            f.write("%.4f %.6f %.6f %.6f %.8f %.8f %.8f %.8f\n" % (s + base[0], *p0, *q))


if __name__ == "__main__":
    main()
