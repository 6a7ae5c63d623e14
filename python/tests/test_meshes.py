"""Meshes from numpy arrays: written and read back, and registered non-rigidly as the
`nonrigid_register meshes` tool registers them."""

import json
import subprocess

import numpy as np
import pytest

import dynamap
from conftest import binary


def sheet(columns=21, rows=13, width=0.5):
    """A flat grid in the plane z = 0 with two triangles per cell."""
    xs, ys = np.meshgrid(np.linspace(0, width, columns), np.linspace(0, 0.6 * width, rows))
    vertices = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
    faces = []
    for r in range(rows - 1):
        for c in range(columns - 1):
            i = r * columns + c
            faces += [[i, i + 1, i + columns], [i + 1, i + columns + 1, i + columns]]
    return vertices, np.array(faces)


def bent(vertices, width=0.5, depth=0.12):
    """The sheet bent along x into a parabola, moved 2 cm along y: the same vertex order."""
    out = vertices.copy()
    u = out[:, 0] / width
    out[:, 2] = depth * (2 * u - 1) ** 2
    out[:, 1] += 0.02
    return out


def off_surface(points, width=0.5, depth=0.12, columns=None):
    """Each point's height above or below the bent sheet (no closer to the surface than that);
    with `columns`, above or below the bent mesh of that many columns, whose triangles cut
    under the parabola between its vertices."""
    height = lambda x: depth * (2 * x / width - 1) ** 2
    if columns is None:
        return np.abs(points[:, 2] - height(points[:, 0]))
    xs = np.linspace(0, width, columns)
    return np.abs(points[:, 2] - np.interp(points[:, 0], xs, height(xs)))


def test_python_registers_a_sheet_as_the_tool_does(tmp_path):
    v, f = sheet()
    t = bent(v)
    result = dynamap.register_meshes(v, t, source_faces=f, target_faces=f)
    dynamap.write_mesh(tmp_path / "source.ply", v, f)
    dynamap.write_mesh(tmp_path / "target.ply", t, f)
    out = subprocess.run(
        [binary("nonrigid_register"), "meshes", str(tmp_path / "source.ply"), str(tmp_path / "target.ply"), "--output", str(tmp_path / "warped.ply"), "-q"],
        check=True, capture_output=True, text=True,
    )
    tool = json.loads(out.stdout.strip().splitlines()[-1])
    warped = dynamap.read_mesh(tmp_path / "warped.ply")
    # the tool writes single precision; both computed the same double-precision points
    np.testing.assert_allclose(result["vertices"], warped["vertices"], rtol=0, atol=1e-6)
    assert result["nodes"] == tool["nodes"] and result["iterations"] == tool["iterations"]
    assert result["matched_fraction"] > 0.9
    assert result["registered"] and tool["registered"]
    assert result["fit"] == pytest.approx(tool["fit"], rel=1e-9)
    assert result["fit"]["on_target"] == 1.0 and result["fit"]["covered"] > 0.99
    # a flat sheet slides along itself, but its boundary holds it
    slip = tool["slippage"]
    assert result["slippage"] == pytest.approx([slip["source"], slip["target"]], rel=1e-9)
    assert min(result["slippage"]) > 10 * slip["limit"], slip
    # the sheet registered back comes back where it started, the same way in both
    trip = tool["round_trip"]
    assert result["round_trip"] == pytest.approx({k: trip[k] for k in ("error", "moved", "ratio")}, rel=1e-9)
    assert result["round_trip"]["ratio"] < trip["limit"], trip
    # a bent sheet is laid by no affine map or rigid motion (NOTES 195, 197, 199); both say so
    assert result["placed_affine"] is False and tool["placed_affine"] is False
    assert result["placed_rigid"] is False and tool["placed_rigid"] is False
    assert result["maps_apart"] is None and tool["maps_apart"] is None
    # nor does it slide under a stretch: both give the same affine slippage, far above its limit
    affine = tool["affine_slippage"]
    assert result["affine_slippage"] == pytest.approx([affine["source"], affine["target"]], rel=1e-9)
    assert min(result["affine_slippage"]) > 10 * affine["limit"], affine
    assert result["departure_from_rigid"] == pytest.approx(affine["departure_from_rigid"], rel=1e-9)
    # the warped sheet lies on the bent mesh (a plain sheet may slide along itself, and the
    # points land between the target's vertices: issue 26, NOTES 84)
    before, after = off_surface(v, columns=21), off_surface(result["vertices"], columns=21)
    assert after.mean() < 1e-3 * before.mean() and after.max() < 1e-4, (before.mean(), after.max())


def sphere(rings=12, radius=0.2):
    """A UV sphere about the origin: poles and `rings - 1` circles of `2 rings` vertices,
    wound with its normals out."""
    segments = 2 * rings
    polar = np.linspace(0, np.pi, rings + 1)[1:-1]
    azimuth = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    t, a = np.meshgrid(polar, azimuth, indexing="ij")
    ring = np.column_stack([np.sin(t).ravel() * np.cos(a).ravel(), np.sin(t).ravel() * np.sin(a).ravel(), np.cos(t).ravel()])
    vertices = radius * np.vstack([[0, 0, 1], ring, [0, 0, -1]])
    at = lambda r, s: 1 + r * segments + s % segments
    south = len(vertices) - 1
    faces = [[0, at(0, s), at(0, s + 1)] for s in range(segments)]
    for r in range(rings - 2):
        for s in range(segments):
            faces += [[at(r, s), at(r + 1, s), at(r + 1, s + 1)], [at(r, s), at(r + 1, s + 1), at(r, s + 1)]]
    faces += [[south, at(rings - 2, s + 1), at(rings - 2, s)] for s in range(segments)]
    return vertices, np.array(faces)


def test_a_sphere_fits_but_is_not_registered_for_it_turns_along_itself(tmp_path):
    v, f = sphere()
    t = v * np.array([1.0, 0.85, 0.7]) + [0.01, 0.0, 0.0]
    result = dynamap.register_meshes(v, t, source_faces=f, target_faces=f)
    assert result["fit"]["on_target"] > 0.99 and result["fit"]["covered"] > 0.99, result["fit"]
    assert not result["registered"]
    assert result["slippage"][0] < 1e-4 < result["slippage"][1], result["slippage"]
    dynamap.write_mesh(tmp_path / "ball.ply", v, f)
    dynamap.write_mesh(tmp_path / "egg.ply", t, f)
    out = subprocess.run([binary("nonrigid_register"), "meshes", str(tmp_path / "ball.ply"), str(tmp_path / "egg.ply")], capture_output=True, text=True)
    assert out.returncode == 1, out.stderr
    assert json.loads(out.stdout.strip().splitlines()[-1])["registered"] is False
    assert "slides along itself" in out.stderr


def test_a_point_cloud_with_normals_registers_by_closest_point():
    v, f = sheet(columns=25, rows=15)
    t = bent(v, depth=0.06)
    normals = np.tile([0.0, 0.0, 1.0], (len(v), 1))
    result = dynamap.register_meshes(v, t, source_normals=normals, target_faces=f)
    before, after = off_surface(v, depth=0.06), off_surface(result["vertices"], depth=0.06)
    assert after.mean() < 1e-3 * before.mean() and after.max() < 1e-4, (before.mean(), after.max())
    assert result["matched"] > 0.9 * len(v)
    assert result["slippage"] is None  # a cloud has no faces to measure


def test_a_source_wound_against_itself_registers_as_the_consistent_one():
    """Normals computed from faces some of which are wound the other way come from the faces
    turned alike first (NOTES 141): the registration is the same as with the consistent ones."""
    v, f = sheet()
    t = bent(v)
    mixed = f.copy()
    mixed[::4] = mixed[::4, ::-1]
    consistent = dynamap.register_meshes(v, t, source_faces=f, target_faces=f)
    result = dynamap.register_meshes(v, t, source_faces=mixed, target_faces=mixed)
    np.testing.assert_allclose(result["vertices"], consistent["vertices"], rtol=0, atol=1e-9)
    assert result["registered"]


def test_a_sheet_onto_a_third_of_its_copy_is_fully_matched_but_not_registered(tmp_path):
    v, f = sheet()
    t = bent(v)
    kept = v[:, 0] <= v[:, 0].max() / 3 + 1e-9
    index = np.cumsum(kept) - 1
    part = np.array([index[face] for face in f if kept[face].all()])
    result = dynamap.register_meshes(v, t[kept], source_faces=f, target_faces=part)
    assert result["matched_fraction"] > 0.9
    assert not result["registered"], result["fit"]
    dynamap.write_mesh(tmp_path / "source.ply", v, f)
    dynamap.write_mesh(tmp_path / "part.ply", t[kept], part)
    out = subprocess.run(
        [binary("nonrigid_register"), "meshes", str(tmp_path / "source.ply"), str(tmp_path / "part.ply")],
        capture_output=True, text=True,
    )
    assert out.returncode == 1, out.stderr
    assert json.loads(out.stdout.strip().splitlines()[-1])["registered"] is False
    assert "not registered" in out.stderr


def test_a_mesh_written_and_read_back_is_the_same(tmp_path):
    v, f = sheet()
    colors = np.tile(np.array([[200, 10, 30]], np.uint8), (len(v), 1))
    path = tmp_path / "m.ply"
    dynamap.write_mesh(path, v, f, normals=np.tile([0, 0, 1.0], (len(v), 1)), colors=colors)
    m = dynamap.read_mesh(path)
    np.testing.assert_allclose(m["vertices"], v, atol=1e-7)
    np.testing.assert_array_equal(m["faces"], f)
    np.testing.assert_array_equal(m["colors"], colors)
    np.testing.assert_allclose(m["normals"], np.tile([0, 0, 1.0], (len(v), 1)))


def test_bad_meshes_raise_clear_errors(tmp_path):
    v, f = sheet()
    bad = f.copy()
    bad[3, 1] = len(v)
    with pytest.raises(ValueError, match=f"source faces: face 3 names vertex {len(v)}, outside 0..{len(v)}"):
        dynamap.register_meshes(v, v, source_faces=bad, target_faces=f)
    with pytest.raises(ValueError, match="a point cloud needs normals"):
        dynamap.register_meshes(v, v, target_faces=f)
    nan = v.copy()
    nan[7, 2] = np.nan
    with pytest.raises(ValueError, match="target vertices: row 7"):
        dynamap.register_meshes(v, nan, source_faces=f, target_faces=f)
    line = v.copy()
    line[:, 1:] = 0.0
    with pytest.raises(ValueError, match="the target's faces have no area"):
        dynamap.register_meshes(v, line, source_faces=f, target_faces=f)
    with pytest.raises(ValueError, match="expected n x 3"):
        dynamap.write_mesh(tmp_path / "x.ply", v[:, :2])
    with pytest.raises(dynamap.InputError, match="nowhere.ply"):
        dynamap.read_mesh(tmp_path / "nowhere.ply")
