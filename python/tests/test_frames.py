"""RGB-D frames from numpy arrays registered non-rigidly, as `nonrigid_register frames` registers
them: the flow, the verdict, the colour and outline checks, and arrays of the wrong shape
refused."""

import numpy as np
import pytest

import dynamap

INTRINSICS = dict(fx=150.0, fy=150.0, cx=79.5, cy=59.5)


def wall(nearer=0.0):
    """A wall 1 m away with a bump in the middle (160 x 120, millimetres), `nearer` metres
    closer."""
    y, x = np.mgrid[0:120, 0:160]
    bump = 60.0 * np.exp(-((x - 80.0) ** 2 + (y - 60.0) ** 2) / 800.0)
    return (1000.0 - bump - 1000.0 * nearer).astype(np.uint16)


def colours():
    """Smooth waves of red against blue, the same in both frames (160 x 120 x 3, uint8)."""
    y, x = np.mgrid[0:120, 0:160]
    c = 0.15 * np.sin(x / 9.0) + 0.12 * np.cos(y / 7.0)
    rgb = np.stack([100 + 150 * c, np.full_like(c, 100.0), 100 - 150 * c], axis=-1)
    return rgb.round().astype(np.uint8)


def test_a_wall_moved_nearer_is_registered_with_its_flow():
    result = dynamap.register_frames(wall(), wall(0.01), **INTRINSICS)
    assert result["registered"] and result["verdict"] == "registered"
    assert result["colour_check"] is None
    # no colour, and a wall filling the view has no outline to search by: its own place
    assert result["start"] == "none"
    assert result["points"].shape == result["warped"].shape
    assert len(result["pixels"]) == len(result["points"])
    flow = result["flow"]
    assert flow.shape == (120, 160, 3)
    moved = flow[np.isfinite(flow[..., 2])]
    assert len(moved) == 160 * 120
    # every pixel of the wall comes 1 cm nearer: within a pixel's footprint (6.7 mm at 1 m)
    error = np.linalg.norm(moved - np.array([0.0, 0.0, -0.01]), axis=1)
    assert np.median(error) < 0.006 and abs(np.median(moved[:, 2]) + 0.01) < 0.002


def test_with_colour_the_colour_is_checked_and_agrees():
    c = colours()
    result = dynamap.register_frames(
        wall(), wall(0.01), **INTRINSICS, source_color=c, target_color=c
    )
    check = result["colour_check"]
    assert result["verdict"] == "registered", check
    assert check["aligned"] > 0 and check["off"] == 0, check
    assert check["correlation"] > 0.9 and check["contrast"] > 4.0, check
    metres = dynamap.register_frames(
        wall().astype(np.float64) / 1000.0, wall(0.01).astype(np.float64) / 1000.0, **INTRINSICS
    )
    assert metres["registered"]


def test_a_mask_keeps_the_object_only():
    mask = np.zeros((120, 160), dtype=bool)
    mask[30:90, 40:120] = True
    result = dynamap.register_frames(wall(), wall(0.01), **INTRINSICS, mask=mask)
    assert result["registered"]
    assert len(result["points"]) == mask.sum()


def test_a_plate_that_became_part_of_a_wall_is_not_registered():
    """A plate 1 m away before a wall 2 m away; the target shows a plain wall at 1 m filling the
    view. Every point of the plate lies on it, but its outline, which stood before the far wall,
    lies flush in the near one: not registered, by the outline."""
    source = np.full((120, 160), 2000, dtype=np.uint16)
    source[30:90, 40:120] = 1000
    target = np.full((120, 160), 1000, dtype=np.uint16)
    result = dynamap.register_frames(source, target, **INTRINSICS, mask=source == 1000)
    check = result["outline_check"]
    assert not result["registered"] and result["verdict"] == "outline", check
    assert check["seen"] >= 20 and check["flush"] > 0.9 * check["seen"], check
    # the same plate in front of the same far wall: it stands, and is registered
    kept = dynamap.register_frames(source, source, **INTRINSICS, mask=source == 1000)
    assert kept["registered"] and kept["outline_check"]["flush"] == 0, kept["outline_check"]
    # a plate flush with its own background has no outline to check
    flat = dynamap.register_frames(target, target, **INTRINSICS, mask=source == 1000)
    assert flat["registered"] and flat["outline_check"] is None


def test_arrays_of_the_wrong_shape_are_refused():
    with pytest.raises(ValueError, match="frame 1"):
        dynamap.register_frames(wall(), wall()[:, :100], **INTRINSICS)
    with pytest.raises(ValueError, match="colour"):
        dynamap.register_frames(
            wall(), wall(), **INTRINSICS, source_color=colours()[:, :100], target_color=colours()
        )
    with pytest.raises(ValueError, match="mask"):
        dynamap.register_frames(wall(), wall(), **INTRINSICS, mask=np.ones((10, 10), dtype=bool))
    with pytest.raises(ValueError, match="focal"):
        dynamap.register_frames(wall(), wall(), fx=0.0, fy=150.0, cx=79.5, cy=59.5)
    with pytest.raises(ValueError):
        dynamap.register_frames([[1, 2], [3, 4]], wall(), **INTRINSICS)
