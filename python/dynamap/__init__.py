"""dynamap: sparse non-linear least squares on manifolds, and dense RGB-D SLAM, from Python.

The solver (``Problem``, ``Options``, ``Summary``), the library's residuals (pose-graph between
and prior factors, BAL's reprojection, point-to-plane) and residuals written in Python, g2o pose
graphs (``PoseGraph``, ``solve_pose_graph``), BAL problems (``BalProblem``, ``solve_bal``), and
dense rigid SLAM (``RigidSlam``, ``Sequence``, ``generate_sequence``), and meshes (``read_mesh``,
``write_mesh``, non-rigid ``register_meshes``) and RGB-D frames (non-rigid ``register_frames``),
with numpy arrays in and out. Every error is a ``DynamapError`` (``InputError`` for files and
arrays, ``ProblemError`` for a problem built wrongly, ``SolveError`` for a solve that cannot
proceed), or a ``ValueError`` / ``TypeError`` for an argument of the wrong kind.
"""

from ._dynamap import (
    BalProblem,
    DynamapError,
    InputError,
    Options,
    PoseGraph,
    Problem,
    ProblemError,
    Residual,
    RigidSlam,
    Sequence,
    SolveError,
    Summary,
    __version__,
    bal_reprojection,
    between_se2,
    between_se3,
    check_jacobians,
    generate_sequence,
    point_to_plane,
    prior_se2,
    prior_se3,
    read_mesh,
    register_frames,
    register_meshes,
    solve_bal,
    solve_pose_graph,
    write_mesh,
)

__all__ = [
    "BalProblem",
    "DynamapError",
    "InputError",
    "Options",
    "PoseGraph",
    "Problem",
    "ProblemError",
    "Residual",
    "RigidSlam",
    "Sequence",
    "SolveError",
    "Summary",
    "__version__",
    "bal_reprojection",
    "between_se2",
    "between_se3",
    "check_jacobians",
    "generate_sequence",
    "point_to_plane",
    "prior_se2",
    "prior_se3",
    "read_mesh",
    "register_frames",
    "register_meshes",
    "solve_bal",
    "solve_pose_graph",
    "write_mesh",
]
