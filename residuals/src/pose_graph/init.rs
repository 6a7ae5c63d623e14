//! Initial guesses for pose graphs.
//!
//! - [`odometry`]: compose measurements along a breadth-first spanning tree from the anchor.
//! - [`chordal`]: chordal relaxation (Martinec & Pajdla, CVPR 2007; Carlone et al., *Initialization
//!   Techniques for 3D SLAM*, ICRA 2015): rotations as unconstrained matrices by linear least squares
//!   `R_j ≈ R_i Z_ij`, projected onto SO(n), then translations by linear least squares
//!   `t_j − t_i ≈ R_i t_ij`. Both linear problems are solved by the dynamap solver itself.

use super::graph::{Dimension, Pose, PoseGraph};
use dynamap_solver::lie::so3;
use dynamap_solver::{Algorithm, EuclideanDyn, Jacobians, Options, Problem, Residual, Solver, Var};
use nalgebra::{
    DMatrix, DVector, Isometry2, Isometry3, Matrix3, Rotation3, Translation3, UnitComplex,
    UnitQuaternion, Vector2,
};
use std::borrow::Cow;
use std::collections::{BTreeMap, VecDeque};

/// Where a solve starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Start {
    /// The vertices as read.
    File,
    /// [`odometry`].
    Odometry,
    /// [`chordal`].
    Chordal,
}

/// The poses a solve from `from` begins at: the graph's own (borrowed, not copied), or computed.
pub fn start(graph: &PoseGraph, from: Start) -> Result<Cow<'_, BTreeMap<usize, Pose>>, String> {
    Ok(match from {
        Start::File => Cow::Borrowed(&graph.vertices),
        Start::Odometry => Cow::Owned(odometry(graph)?),
        Start::Chordal => Cow::Owned(chordal(graph)?),
    })
}

/// Poses by composing edge measurements along breadth-first spanning trees rooted at the
/// anchors ([`PoseGraph::anchors`]: one per connected piece, each at its pose from the file, or
/// the identity). Every other vertex is recomputed.
pub fn odometry(graph: &PoseGraph) -> Result<BTreeMap<usize, Pose>, String> {
    let ids = graph.all_ids();
    let anchors = graph.anchors();
    if anchors.is_empty() {
        return Err(format!("{}: the graph has no vertices", graph.source));
    }
    let mut adjacency: BTreeMap<usize, Vec<(usize, usize)>> = BTreeMap::new();
    for (k, e) in graph.edges.iter().enumerate() {
        adjacency.entry(e.from).or_default().push((k, e.to));
        adjacency.entry(e.to).or_default().push((k, e.from));
    }
    let mut poses = BTreeMap::new();
    for &root in &anchors {
        let start = graph
            .vertices
            .get(&root)
            .copied()
            .unwrap_or_else(|| Pose::identity(graph.dimension));
        poses.insert(root, start);
    }
    let mut queue = VecDeque::from(anchors);
    while let Some(v) = queue.pop_front() {
        let here = poses[&v];
        for &(k, w) in adjacency.get(&v).map(Vec::as_slice).unwrap_or(&[]) {
            if poses.contains_key(&w) {
                continue;
            }
            let e = &graph.edges[k];
            let z = e.measurement.pose();
            let next = if e.from == v {
                here.compose(&z)
            } else {
                here.compose(&z.inverse())
            };
            poses.insert(w, next);
            queue.push_back(w);
        }
    }
    if let Some(v) = ids.iter().find(|v| !poses.contains_key(v)) {
        return Err(format!(
            "{}: vertex {v} is touched by no edge",
            graph.source
        ));
    }
    Ok(poses)
}

/// The linear residual `r = x_j + A x_i − b`.
struct LinearPair {
    a: DMatrix<f64>,
    b: DVector<f64>,
}

impl Residual for LinearPair {
    fn dim(&self) -> usize {
        self.b.len()
    }
    fn arity(&self) -> Option<usize> {
        Some(2)
    }
    fn evaluate(
        &self,
        vars: &[Var<'_>],
        residual: &mut [f64],
        jacobians: Option<&mut Jacobians<'_>>,
    ) {
        let n = self.b.len();
        for (r, out) in residual.iter_mut().enumerate().take(n) {
            let mut s = vars[1].value[r] - self.b[r];
            for c in 0..n {
                s += self.a[(r, c)] * vars[0].value[c];
            }
            *out = s;
        }
        if let Some(j) = jacobians {
            j.block(0).copy_from_slice(self.a.as_slice());
            let id = j.block(1);
            id.fill(0.0);
            for i in 0..n {
                id[i * n + i] = 1.0;
            }
        }
    }
}

/// Solves `min Σ ‖x_j + A x_i − b‖²` over vectors of size `n`, `anchors` held at their values.
fn solve_linear(
    ids: &[usize],
    n: usize,
    start: impl Fn(usize) -> Vec<f64>,
    anchors: &[usize],
    edges: Vec<(usize, usize, DMatrix<f64>, DVector<f64>)>,
) -> Result<BTreeMap<usize, Vec<f64>>, String> {
    let mut problem = Problem::new();
    let mut index = BTreeMap::new();
    for &id in ids {
        let v = problem
            .add_variable(&start(id), EuclideanDyn(n))
            .map_err(|e| e.to_string())?;
        index.insert(id, v);
    }
    for a in anchors {
        problem
            .set_fixed(index[a], true)
            .map_err(|e| e.to_string())?;
    }
    for (i, j, a, b) in edges {
        problem
            .add_residual(LinearPair { a, b }, &[index[&i], index[&j]])
            .map_err(|e| e.to_string())?;
    }
    // Linear: one Gauss-Newton step solves it; a second confirms.
    let options = Options {
        algorithm: Algorithm::GaussNewton,
        max_iterations: 2,
        ..Options::default()
    };
    Solver::new(options)
        .solve(&mut problem)
        .map_err(|e| format!("chordal initialisation: {e}"))?;
    Ok(index
        .into_iter()
        .map(|(id, v)| (id, problem.value(v).to_vec()))
        .collect())
}

/// Chordal initialisation of every vertex; anchors keep their poses from the file (or identity).
pub fn chordal(graph: &PoseGraph) -> Result<BTreeMap<usize, Pose>, String> {
    // Every vertex must be reachable for the linear systems to be determined.
    odometry(graph)?;
    let ids = graph.all_ids();
    let anchors = graph.anchors();
    let d = match graph.dimension {
        Dimension::Two => 2,
        Dimension::Three => 3,
    };
    let anchor_pose = |id: usize| {
        graph
            .vertices
            .get(&id)
            .copied()
            .unwrap_or_else(|| Pose::identity(graph.dimension))
    };
    // Rotations: vec(R_j) − (Z_Rᵀ ⊗ I) vec(R_i) = 0.
    let rotation_edges = graph
        .edges
        .iter()
        .map(|e| {
            let a = rotation_edge(&rotation_of(&e.measurement.pose()), d);
            (e.from, e.to, a, DVector::zeros(d * d))
        })
        .collect();
    let identity = DMatrix::<f64>::identity(d, d);
    let rotations = solve_linear(
        &ids,
        d * d,
        |id| {
            if anchors.contains(&id) {
                rotation_of(&anchor_pose(id)).as_slice().to_vec()
            } else {
                identity.as_slice().to_vec()
            }
        },
        &anchors,
        rotation_edges,
    )?;
    let projected: BTreeMap<usize, DMatrix<f64>> = rotations
        .into_iter()
        .map(|(id, v)| (id, nearest_rotation(&DMatrix::from_column_slice(d, d, &v))))
        .collect();
    // Translations: t_j − t_i − R_i t_ij = 0.
    let translation_edges = graph
        .edges
        .iter()
        .map(|e| {
            let b = &projected[&e.from] * translation_of(&e.measurement.pose());
            (e.from, e.to, -DMatrix::identity(d, d), b)
        })
        .collect();
    let translations = solve_linear(
        &ids,
        d,
        |id| {
            if anchors.contains(&id) {
                translation_of(&anchor_pose(id)).as_slice().to_vec()
            } else {
                vec![0.0; d]
            }
        },
        &anchors,
        translation_edges,
    )?;
    Ok(ids
        .iter()
        .map(|id| (*id, compose(&projected[id], &translations[id])))
        .collect())
}

/// A pose's rotation as a d × d matrix.
fn rotation_of(p: &Pose) -> DMatrix<f64> {
    match p {
        Pose::Se2(t) => {
            DMatrix::from_column_slice(2, 2, t.rotation.to_rotation_matrix().matrix().as_slice())
        }
        Pose::Se3(t) => {
            DMatrix::from_column_slice(3, 3, t.rotation.to_rotation_matrix().matrix().as_slice())
        }
    }
}

/// A pose's translation.
fn translation_of(p: &Pose) -> DVector<f64> {
    match p {
        Pose::Se2(t) => DVector::from_column_slice(t.translation.vector.as_slice()),
        Pose::Se3(t) => DVector::from_column_slice(t.translation.vector.as_slice()),
    }
}

/// The block −(Z_Rᵀ ⊗ I) of a rotation edge's row vec(R_j) − (Z_Rᵀ ⊗ I) vec(R_i) = 0.
fn rotation_edge(rz: &DMatrix<f64>, d: usize) -> DMatrix<f64> {
    let mut a = DMatrix::zeros(d * d, d * d);
    for c in 0..d {
        for k in 0..d {
            for r in 0..d {
                a[(c * d + r, k * d + r)] = -rz[(k, c)];
            }
        }
    }
    a
}

/// The rotation nearest to a d × d matrix (d = 2 or 3).
fn nearest_rotation(m: &DMatrix<f64>) -> DMatrix<f64> {
    if m.nrows() == 3 {
        let p = so3::project(&Matrix3::from_column_slice(m.as_slice()));
        DMatrix::from_column_slice(3, 3, p.as_slice())
    } else {
        // nearest planar rotation: angle of (m00 + m11, m10 − m01)
        let a = (m[(1, 0)] - m[(0, 1)]).atan2(m[(0, 0)] + m[(1, 1)]);
        DMatrix::from_column_slice(
            2,
            2,
            UnitComplex::new(a).to_rotation_matrix().matrix().as_slice(),
        )
    }
}

/// The pose of rotation `r` (d × d) and translation `t`.
fn compose(r: &DMatrix<f64>, t: &[f64]) -> Pose {
    if r.nrows() == 3 {
        let rot = Rotation3::from_matrix_unchecked(Matrix3::from_column_slice(r.as_slice()));
        Pose::Se3(Isometry3::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            UnitQuaternion::from_rotation_matrix(&rot),
        ))
    } else {
        Pose::Se2(Isometry2::new(
            Vector2::new(t[0], t[1]),
            r[(1, 0)].atan2(r[(0, 0)]),
        ))
    }
}
