"""Pose graphs from Python: the same optimum as the `pose_graph` tool, files in and out, and the
faults of published graphs."""

import json
import subprocess

import numpy as np
import pytest

import dynamap
from conftest import binary, write_graph_2d, write_graph_3d


def tool_json(path, *flags):
    out = subprocess.run([binary("pose_graph"), str(path), "--quiet", *flags], check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("dims,seed", [(2, 3), (3, 4), (2, 17)])
def test_python_reaches_the_chi2_of_the_pose_graph_tool(tmp_path, dims, seed):
    path = tmp_path / "graph.g2o"
    (write_graph_2d if dims == 2 else write_graph_3d)(path, 300, seed)
    expected = tool_json(path)
    poses, summary = dynamap.solve_pose_graph(str(path))
    chi2 = dynamap.PoseGraph.read(path).chi2(poses)
    assert summary.converged and expected["converged"]
    assert abs(chi2 - expected["chi2_final"]) <= 1e-9 * expected["chi2_final"], (chi2, expected["chi2_final"])
    assert chi2 < 0.5 * expected["chi2_initial"]
    assert abs(2 * summary.final_cost - chi2) <= 1e-9 * chi2
    assert summary.num_iterations == expected["iterations"]


def test_chordal_start_and_a_robust_kernel_match_the_tool(tmp_path):
    path = tmp_path / "graph.g2o"
    write_graph_3d(path, 200, 9)
    expected = tool_json(path, "--init", "chordal", "--kernel", "huber:1")
    poses, summary = dynamap.solve_pose_graph(path, init="chordal", kernel=("huber", 1.0))
    assert abs(summary.final_cost - expected["cost_final"]) <= 1e-9 * expected["cost_final"]
    chi2 = dynamap.PoseGraph.read(path).chi2(poses)
    assert abs(chi2 - expected["chi2_final"]) <= 1e-9 * expected["chi2_final"]


def test_an_optimised_graph_written_and_read_back_keeps_its_poses(tmp_path):
    path, out = tmp_path / "graph.g2o", tmp_path / "out.g2o"
    write_graph_2d(path, 100, 5)
    graph = dynamap.PoseGraph.read(path)
    poses, _ = graph.solve()
    graph.write(out, poses)
    back = dynamap.PoseGraph.read(out)
    assert back.num_vertices == graph.num_vertices == 100
    assert back.num_edges == graph.num_edges
    for k, p in back.vertices().items():
        np.testing.assert_allclose(p, poses[k], rtol=0, atol=1e-12)
    assert abs(back.chi2() - graph.chi2(poses)) <= 1e-12 * graph.chi2(poses)


def test_edges_hold_the_measurements_and_information_in_tangent_order(tmp_path):
    path = tmp_path / "g.g2o"
    path.write_text(
        "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 0 1\n"
        "EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 1 0 0 0 0 0 2 0 0 0 0 3 0 0 0 4 0 0 5 0 6\n"
    )
    graph = dynamap.PoseGraph.read(path)
    (i, j, z, info), = graph.edges()
    assert (i, j) == (0, 1) and graph.dimension == 3
    np.testing.assert_allclose(z, [1, 0, 0, 0, 0, 0, 1])
    # g2o lists translation first; the tangent order is [ω; v]
    np.testing.assert_allclose(np.diag(info), [4, 5, 6, 1, 2, 3])


def test_an_indefinite_information_matrix_is_repaired_with_a_warning_and_refused_when_strict(tmp_path):
    path = tmp_path / "cubicle.g2o"
    write_graph_2d(path, 30, 2, loops=0)
    lines = path.read_text().splitlines()
    bad = len(lines)  # the last edge, on this 1-based line
    fields = lines[-1].split()
    fields[6:12] = ["100", "0", "0", "-1", "0", "100"]
    lines[-1] = " ".join(fields)
    path.write_text("\n".join(lines) + "\n")
    with pytest.warns(UserWarning, match=f"cubicle.g2o: line {bad} \\(edge 28 -> 29\\)"):
        poses, summary = dynamap.solve_pose_graph(path)
    assert summary.converged and len(poses) == 30
    with pytest.raises(dynamap.InputError, match=f"cubicle.g2o:{bad}"):
        dynamap.solve_pose_graph(path, strict=True)


def test_bad_files_raise_input_errors_that_name_file_and_line(tmp_path):
    with pytest.raises(dynamap.InputError, match="nowhere.g2o"):
        dynamap.PoseGraph.read(tmp_path / "nowhere.g2o")
    path = tmp_path / "corrupt.g2o"
    path.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 x 1 0 0 1 0 1\n")
    with pytest.raises(dynamap.InputError, match="corrupt.g2o:3"):
        dynamap.PoseGraph.read(path)
    empty = tmp_path / "empty.g2o"
    empty.write_text("")
    with pytest.raises(dynamap.InputError, match="empty.g2o"):
        dynamap.solve_pose_graph(empty)
    with pytest.raises(ValueError, match="init='nonsense'"):
        dynamap.solve_pose_graph(_tiny(tmp_path), init="nonsense")


def _tiny(tmp_path):
    path = tmp_path / "tiny.g2o"
    path.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    return path


def test_a_vertex_no_edge_touches_is_named_by_its_id(tmp_path):
    path = tmp_path / "island.g2o"
    path.write_text(
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 7 2 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n"
    )
    with pytest.raises(dynamap.SolveError, match="vertex 7"):
        dynamap.solve_pose_graph(path)


def test_chi2_of_poses_with_a_missing_vertex_is_refused(tmp_path):
    graph = dynamap.PoseGraph.read(_tiny(tmp_path))
    poses = graph.vertices()
    del poses[1]
    with pytest.raises(ValueError, match="vertex 1"):
        graph.chi2(poses)
