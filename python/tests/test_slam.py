"""Rigid SLAM from numpy arrays: the same trajectory as the `rigid_slam` tool, the generator,
the mesh, and frames that cannot be tracked or read."""

import filecmp
import subprocess

import numpy as np
import pytest

import dynamap
from conftest import binary


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    path = tmp_path_factory.mktemp("seq") / "orbit"
    written = dynamap.generate_sequence(path, frames=20, width=320, height=240, seed=3)
    assert written == 20
    return path


def start_pose(seq):
    """The ground truth at the first frame, as `rigid_slam` starts."""
    stamps, poses = seq.groundtruth()
    t0 = seq.frame(0)[2]
    k = int(np.argmin(np.abs(stamps - t0)))
    assert abs(stamps[k] - t0) < 0.01
    return poses[k]


def run(seq, depth_as=None, limit=None):
    c = seq.camera
    slam = dynamap.RigidSlam(c["fx"], c["fy"], c["cx"], c["cy"], c["width"], c["height"], c["depth_scale"], initial_pose=start_pose(seq))
    reports = []
    for i in range(len(seq) if limit is None else limit):
        depth, color, t, tc = seq.frame(i)
        if depth_as is not None:
            depth = depth_as(depth, c["depth_scale"])
        reports.append(slam.process(depth, color, timestamp=t, color_timestamp=tc))
    return slam, reports


def test_python_tracks_the_trajectory_of_the_rigid_slam_tool(sequence, tmp_path):
    out = tmp_path / "tool.txt"
    subprocess.run([binary("rigid_slam"), str(sequence), "--quiet", "--output", str(out)], check=True, capture_output=True)
    expected = np.loadtxt(out)
    seq = dynamap.Sequence(sequence)
    slam, reports = run(seq)
    stamps, poses = slam.trajectory()
    assert all(r["tracked"] for r in reports) and reports[0]["outcome"] == "started"
    # a textured room: every tracked frame's texture matches the model's
    assert all(r["correlation"] > 0.9 for r in reports[1:]), [r["correlation"] for r in reports]
    # ... and its points lie near the model, however the sensor's steps tilt their normals
    assert all(r["proximity"] > 0.9 for r in reports[1:]), [r["proximity"] for r in reports]
    assert len(stamps) == len(expected) == len(seq)
    np.testing.assert_allclose(stamps, expected[:, 0], rtol=0, atol=1e-6)
    np.testing.assert_allclose(poses, expected[:, 1:], rtol=0, atol=1e-9)
    np.testing.assert_allclose(reports[-1]["pose"][:3, 3], poses[-1, :3], atol=1e-12)


def test_the_generator_writes_what_the_generate_tool_writes(sequence, tmp_path):
    tool = tmp_path / "tool"
    subprocess.run([binary("generate"), "rigid", str(tool), "--frames", "20", "--width", "320", "--height", "240", "--seed", "3"], check=True, capture_output=True)
    for name in ["groundtruth.txt", "depth.txt", "rgb.txt", "intrinsics.txt"]:
        assert filecmp.cmp(sequence / name, tool / name, shallow=False), name
    depth = sorted((sequence / "depth").iterdir())
    assert len(depth) > 0 and all(filecmp.cmp(d, tool / "depth" / d.name, shallow=False) for d in depth)


def test_depth_in_metres_tracks_as_depth_in_sensor_units(sequence):
    seq = dynamap.Sequence(sequence)
    _, units = run(seq, limit=6)
    metres = lambda d, scale: np.where(d > 0, d / scale, np.nan).astype(np.float32)
    _, floats = run(seq, depth_as=metres, limit=6)
    for a, b in zip(units, floats):
        np.testing.assert_array_equal(a["pose"], b["pose"])


def test_the_mesh_is_indexed_consistently(sequence):
    slam, _ = run(dynamap.Sequence(sequence), limit=8)
    mesh = slam.mesh()
    n = len(mesh["vertices"])
    assert n > 1000 and mesh["vertices"].shape == (n, 3) and mesh["normals"].shape == (n, 3)
    assert mesh["colors"].shape == (n, 3) and mesh["colors"].dtype == np.uint8
    assert mesh["faces"].dtype == np.uint32 and mesh["faces"].max() < n
    assert np.isfinite(mesh["vertices"]).all()


def test_a_blank_frame_is_reported_not_tracked_and_the_pose_is_kept(sequence):
    seq = dynamap.Sequence(sequence)
    slam, reports = run(seq, limit=4)
    depth, color, t, tc = seq.frame(4)
    blank = slam.process(np.zeros_like(depth), color, timestamp=t, color_timestamp=tc)
    assert not blank["tracked"] and not blank["fused"] and blank["outcome"] == "not_tracked"
    assert blank["failure"]
    np.testing.assert_array_equal(blank["pose"], reports[-1]["pose"])
    assert len(slam.trajectory()[0]) == 4


def test_malformed_frames_and_sequences_raise_clear_errors(sequence, tmp_path):
    seq = dynamap.Sequence(sequence)
    slam = dynamap.RigidSlam(262.5, 262.5, 159.5, 119.5, 320, 240)
    with pytest.raises(ValueError, match=r"frame 0: depth has shape \[240, 321\]"):
        slam.process(np.zeros((240, 321), np.uint16))
    with pytest.raises(ValueError, match="frame 0: depth must be uint16"):
        slam.process(np.zeros((240, 320), np.int8))
    with pytest.raises(ValueError, match=r"frame 0: colour has shape"):
        slam.process(np.zeros((240, 320), np.uint16), np.zeros((240, 320, 4), np.uint8))
    with pytest.raises(ValueError, match="not a rotation"):
        dynamap.RigidSlam(262.5, 262.5, 159.5, 119.5, 320, 240, initial_pose=np.ones((4, 4)))
    with pytest.raises(ValueError, match="not a rotation"):  # a reflection
        dynamap.RigidSlam(262.5, 262.5, 159.5, 119.5, 320, 240, initial_pose=np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(ValueError, match="quaternion"):
        dynamap.RigidSlam(262.5, 262.5, 159.5, 119.5, 320, 240, initial_pose=[0, 0, 0, 0, 0, 0, 0])
    with pytest.raises(dynamap.InputError, match="nowhere"):
        dynamap.Sequence(tmp_path / "nowhere")
    with pytest.raises(IndexError, match="frame 99"):
        seq.frame(99)
    with pytest.raises(ValueError, match="motion='loop'"):
        dynamap.generate_sequence(tmp_path / "x", motion="loop")
    # a frame the renderer cannot hold, and a voxel whose ray march would take minutes a frame,
    # are refused before anything is allocated or run (NOTES 169)
    with pytest.raises(ValueError, match="at most 16777216 pixels"):
        dynamap.generate_sequence(tmp_path / "y", width=100000, height=100000)
    with pytest.raises(ValueError, match="voxel_size must lie between 0.0001 and 1"):
        dynamap.RigidSlam(262.5, 262.5, 159.5, 119.5, 320, 240, voxel_size=1e-5)
    dynamap.RigidSlam(262.5, 262.5, 159.5, 119.5, 320, 240, voxel_size=1e-4)
