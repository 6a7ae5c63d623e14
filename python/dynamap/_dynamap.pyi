"""Type stubs of dynamap's extension module (see the package's docstring)."""

from os import PathLike
from typing import Any, Callable, Dict, List, Optional, Tuple, Union
from typing import Sequence as Seq

import numpy as np
import numpy.typing as npt

__version__: str

ArrayLike = npt.ArrayLike
Vector = npt.NDArray[np.float64]
Matrix = npt.NDArray[np.float64]
Path = Union[str, "PathLike[str]"]
Kernel = Union[str, Tuple[str, float]]
Poses = Dict[int, Vector]

class DynamapError(Exception):
    """The base of every error dynamap raises."""

class InputError(DynamapError):
    """A file or array that cannot be read as asked: the message names the file, line or frame."""

class ProblemError(DynamapError):
    """A problem that cannot be built as asked (a value off its manifold, a residual of the wrong arity)."""

class SolveError(DynamapError):
    """A solve that could not proceed (an untouched variable, a rank-deficient start, a non-finite initial cost)."""

class Options:
    """The solver's settings (Ceres' Solver::Options); every field is a keyword of the constructor."""

    algorithm: str
    """"levenberg_marquardt" (default), "gauss_newton" or "dogleg"."""
    max_iterations: int
    """Largest number of iterations (default 100)."""
    max_seconds: float
    """Wall-clock limit in seconds (default inf)."""
    gradient_tolerance: float
    """Stop when max |g_i| falls to this (default 1e-10)."""
    step_tolerance: float
    """Stop when |δ| <= tol (|x| + tol) (default 1e-10)."""
    function_tolerance: float
    """Stop when an accepted step lowers the cost by less than this fraction (default 1e-10)."""
    initial_damping_tau: float
    """Levenberg-Marquardt's τ (default 1e-4)."""
    damping: str
    """"identity" (μI, default) or "diagonal" (μ diag(H), Ceres')."""
    initial_trust_radius: float
    """The dogleg's initial trust-region radius (default 1e4)."""
    linear_solver: str
    """"auto", "dense", "sparse", "schur", "schur_dense", "schur_sparse" or "schur_iterative"."""
    dense_threshold: int
    """Unknowns up to which "auto" takes the dense solver (default 200)."""
    check_rank: bool
    """Look for a gauge freedom before solving (default True)."""
    pcg_tolerance: float
    """Conjugate gradients stop at |S y - b| <= tol |b| (default 1e-6)."""
    pcg_max_iterations: int
    """Most conjugate-gradient iterations per step (default 500)."""
    pcg_forcing: float
    """The truncated-Newton forcing η of conjugate gradients (default 0.1)."""
    def __init__(self, **kwargs: Any) -> None: ...

class Summary:
    """What a solve reports: costs, why it stopped, each iteration, where the time went."""

    initial_cost: float
    final_cost: float
    termination: str
    converged: bool
    """True when the solve stopped on a convergence test; False at a limit or without progress."""
    num_iterations: int
    iterations: List[Dict[str, Any]]
    """One dict per iteration (iteration 0 is the start): iteration, cost, cost_change,
    gradient_norm, step_norm, damping, accepted, evaluate_seconds, solve_seconds, total_seconds."""
    total_seconds: float
    timing: Dict[str, float]
    """setup, evaluate, assemble, factorise and step, in seconds."""
    unknowns: int
    linear_solver: str
    linear_iterations: int
    non_finite_steps: int
    def table(self) -> str:
        """The iteration table with its closing lines, as the command-line tools print it."""

class Residual:
    """A built-in residual block (between_se3(...), bal_reprojection(...), ...)."""

    dim: int
    arity: int

PythonResidual = Callable[..., Any]

class Problem:
    """Variables on manifolds and residual blocks, solved in place; both are named by the
    integers add_variable and add_residual return."""

    num_variables: int
    num_residuals: int
    def __init__(self) -> None: ...
    def add_variable(self, value: ArrayLike, manifold: str = "euclidean") -> int:
        """Adds a variable on "euclidean", "so2", "se2", "so3", "se3" or "quaternion"."""
    def value(self, variable: int) -> Vector:
        """The variable's current value (ambient coordinates)."""
    def set_value(self, variable: int, value: ArrayLike) -> None: ...
    def set_fixed(self, variable: int, fixed: bool = True) -> None: ...
    def is_fixed(self, variable: int) -> bool: ...
    def set_bounds(self, variable: int, lower: ArrayLike, upper: ArrayLike) -> None:
        """Box constraints on a Euclidean variable, honoured at every iterate."""
    def add_residual(
        self,
        residual: Union[Residual, PythonResidual],
        variables: Seq[int],
        kernel: Optional[Kernel] = None,
        dim: Optional[int] = None,
        jacobians: str = "analytic",
    ) -> int:
        """A built-in Residual, or a callable f(*values) returning (r, [J_1, ..., J_k]) with
        J_k of shape (dim, tangent_dim_k) ("analytic"), or r alone ("numeric": central
        differences on each manifold)."""
    def cost(self) -> float: ...
    def residual(self, block: int) -> Vector: ...
    def solve(self, options: Optional[Options] = None, verbose: bool = False) -> Summary:
        """Minimises from the current values; check summary.converged."""
    def covariance(self, variables: Seq[int]) -> List[Matrix]:
        """Marginal covariances (tangent coordinates) at the current values."""

def between_se2(measurement: ArrayLike, information: ArrayLike) -> Residual:
    """r = U Log(Z^-1 X_i^-1 X_j) on two SE(2) variables; Z as [x, y, θ], Ω in [v_x, v_y, ω] order."""

def between_se3(measurement: ArrayLike, information: ArrayLike) -> Residual:
    """r = U Log(Z^-1 X_i^-1 X_j) on two SE(3) variables; Z as [t, q], Ω in [ω; v] order."""

def prior_se2(measurement: ArrayLike, information: ArrayLike) -> Residual:
    """r = U Log(Z^-1 X) on one SE(2) variable."""

def prior_se3(measurement: ArrayLike, information: ArrayLike) -> Residual:
    """r = U Log(Z^-1 X) on one SE(3) variable."""

def bal_reprojection(u: float, v: float) -> Residual:
    """BAL's reprojection error on a camera (R^9) and a point (R^3)."""

def point_to_plane(source: ArrayLike, target: ArrayLike, normal: ArrayLike) -> Residual:
    """r = n^T (T p - q) on one SE(3) variable T."""

class PoseGraph:
    """A pose graph (SE(2) or SE(3)) as read from a g2o file."""

    dimension: int
    source: str
    num_vertices: int
    num_edges: int
    anchors: List[int]
    @staticmethod
    def read(path: Path, strict: bool = False) -> "PoseGraph":
        """Reads a g2o file; an indefinite information matrix is repaired with a UserWarning
        unless strict (then InputError)."""
    def vertices(self) -> Poses: ...
    def edges(self) -> List[Tuple[int, int, Vector, Matrix]]: ...
    def chi2(self, poses: Optional[Poses] = None) -> float: ...
    def solve(self, init: str = "file", options: Optional[Options] = None, kernel: Optional[Kernel] = None) -> Tuple[Poses, Summary]:
        """Optimises as the pose_graph tool does: (poses, summary)."""
    def write(self, path: Path, poses: Optional[Poses] = None) -> None: ...

def solve_pose_graph(
    path: Path,
    init: str = "file",
    options: Optional[Options] = None,
    kernel: Optional[Kernel] = None,
    strict: bool = False,
) -> Tuple[Poses, Summary]:
    """Reads a g2o file and optimises it as the pose_graph tool does."""

class BalProblem:
    """Cameras [ω, t, f, k1, k2] (n x 9), points (m x 3) and pixel observations."""

    cameras: Matrix
    points: Matrix
    observations: Tuple[npt.NDArray[np.int64], npt.NDArray[np.int64], Matrix]
    def __init__(self, cameras: ArrayLike, points: ArrayLike, camera_index: ArrayLike, point_index: ArrayLike, uv: ArrayLike) -> None: ...
    @staticmethod
    def read(path: Path) -> "BalProblem": ...
    def write(self, path: Path) -> None: ...
    def cost(self) -> float: ...
    def solve(self, kernel: Optional[Kernel] = None, linear_solver: str = "auto", max_iterations: int = 50, options: Optional[Options] = None) -> Summary:
        """Bundle adjustment as the bundle_adjustment tool runs it, in place."""

def solve_bal(path: Path, kernel: Optional[Kernel] = None, linear_solver: str = "auto", max_iterations: int = 50) -> Tuple[Matrix, Matrix, Summary]:
    """Reads a BAL file and solves it: (cameras, points, summary)."""

class RigidSlam:
    """Dense rigid RGB-D SLAM: feed frames, read each frame's outcome and pose, the trajectory and the mesh."""

    pose: Matrix
    """The current camera-to-world pose, 4 x 4."""
    def __init__(
        self,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        width: int,
        height: int,
        depth_scale: float = 5000.0,
        initial_pose: Optional[ArrayLike] = None,
        voxel_size: Optional[float] = None,
    ) -> None: ...
    def process(
        self,
        depth: npt.NDArray[Any],
        color: Optional[npt.NDArray[np.uint8]] = None,
        timestamp: Optional[float] = None,
        color_timestamp: Optional[float] = None,
    ) -> Dict[str, Any]:
        """One frame (depth uint16 sensor units or float metres, colour h x w x 3 uint8): a dict
        with index, outcome, tracked, fused, failure, pose (4 x 4), inliers, inlier_fraction,
        agreement, proximity (the agreement without the normal test), correlation. A frame that
        cannot be tracked is reported so, never fused with a wrong pose."""
    def trajectory(self) -> Tuple[Vector, Matrix]:
        """The tracked frames' stamps (n,) and poses (n x 7, [t, q], camera to world)."""
    def write_trajectory(self, path: Path) -> None:
        """The tracked trajectory in TUM's format."""
    def mesh(self) -> Dict[str, npt.NDArray[Any]]:
        """vertices (n x 3), normals (n x 3), colors (n x 3 uint8), faces (m x 3 uint32)."""

class Sequence:
    """A recorded RGB-D sequence (TUM, ICL-NUIM or a plain folder), frame by frame."""

    camera: Dict[str, float]
    def __init__(self, path: Path) -> None: ...
    def __len__(self) -> int: ...
    def frame(self, i: int) -> Tuple[npt.NDArray[np.uint16], Optional[npt.NDArray[np.uint8]], float, float]:
        """(depth, colour or None, timestamp, color_timestamp); InputError for a frame that cannot be read."""
    def groundtruth(self) -> Optional[Tuple[Vector, Matrix]]:
        """(stamps, poses n x 7) or None."""

def generate_sequence(
    path: Path,
    frames: int = 60,
    motion: str = "orbit",
    width: int = 640,
    height: int = 480,
    fps: float = 30.0,
    sensor: str = "kinect",
    seed: int = 1,
) -> int:
    """Renders a rigid sequence with ground truth (TUM layout), as `generate rigid` does; returns the frames written."""

def read_mesh(path: Path) -> Dict[str, npt.NDArray[Any]]:
    """A PLY, OFF or OBJ mesh: vertices (n x 3), normals, colors (uint8), faces (m x 3 uint32)."""

def write_mesh(
    path: Path,
    vertices: ArrayLike,
    faces: Optional[ArrayLike] = None,
    normals: Optional[ArrayLike] = None,
    colors: Optional[npt.NDArray[np.uint8]] = None,
) -> None:
    """Binary PLY, through a temporary file renamed into place."""

def register_meshes(
    source_vertices: ArrayLike,
    target_vertices: ArrayLike,
    source_faces: Optional[ArrayLike] = None,
    target_faces: Optional[ArrayLike] = None,
    source_normals: Optional[ArrayLike] = None,
    target_normals: Optional[ArrayLike] = None,
    seeded_passes: Optional[int] = None,
    principal_axes: bool = False,
) -> Dict[str, Any]:
    """The source registered onto the target with the deformation graph, as `nonrigid_register
    meshes` does: vertices and normals warped (source order), nodes, iterations, data_cost,
    regulariser_cost, matched, matched_fraction, seconds (both ways), registered (bool: most of
    the source on the target and most of the target covered, facing its way, areas within 1.5x,
    neither mesh sliding along itself, and the round trip coming back), target_normals_turned,
    fit (on_target, covered, facing, area_ratio, source_area_ratio, median_distance, tolerance),
    slippage ([source, target]: the share of each mesh's least-constrained rigid motion that
    moves it off itself, under 1e-3 for a symmetry; None for a point cloud), round_trip (the
    target registered back onto the source: error, moved and their ratio; not
    registered over 0.35; None where it was not run), placed_back (whether the vertices are
    where the way back placed them), placed_rigid and placed_affine (whether they are the source
    carried by a rigid motion, or else a global affine map, that lays it on the target as closely
    as the warp did; for an open mesh, an affine map only where it lays every vertex within a
    tenth of the node spacing; round_trip is then None), affine_slippage ([source, target]: the share of each mesh's least-constrained affine motion that moves it off itself;
    under 1e-3, an ellipsoid, registered is False unless the vertices are rigid) and
    departure_from_rigid (the vertices' root-mean-square distance from the source's nearest
    rigid motion; None where not measured), maps_apart ([apart, limit]: where several rigid
    motions, or else affine maps, fitted from different starts lay the source as closely as the
    warp, how far apart they carry it and the tenth of the node spacing within which they are
    one; further apart, as for a box or an ellipsoid turned onto itself or a flat rectangle
    stretched, registered is False; for an open mesh an affine map that fits as closely but not
    exactly is also set against the warp's vertices;
    None otherwise)."""

def register_frames(
    source_depth: ArrayLike,
    target_depth: ArrayLike,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    depth_scale: float = 1000.0,
    source_color: Optional[ArrayLike] = None,
    target_color: Optional[ArrayLike] = None,
    mask: Optional[ArrayLike] = None,
) -> Dict[str, Any]:
    """The source RGB-D frame registered onto the target with the deformation graph, as
    `nonrigid_register frames` does: depth as uint16 sensor units (depth_scale per metre) or
    float metres, colour height x width x 3 uint8, the source's object as a bool mask. Gives
    points and warped (n x 3), pixels (row-major source pixel of each point), flow (height x
    width x 3, NaN off the object), nodes, matched, data_points, iterations, seconds,
    registered (bool), verdict ("registered", "depth", "outline" or "colour"), start
    ("features", "outline" or "none"), colour_check (aligned, off, flat, floor, correlation,
    contrast; None without colour) and outline_check (outline, seen, flush; None when the object has no outline before
    its background in the source). An array of the wrong shape or type raises
    ValueError naming it (the source's images are frame 0, the target's frame 1)."""

def check_jacobians(
    residual: Union[Residual, PythonResidual],
    values: Seq[ArrayLike],
    manifolds: Optional[Seq[str]] = None,
    dim: Optional[int] = None,
) -> Dict[str, Any]:
    """The residual's Jacobians at `values` against central differences on each manifold:
    max_abs_error, max_rel_error, worst_entry (variable, row, column), analytic, numeric."""
