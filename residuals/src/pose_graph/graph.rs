//! The pose graph: vertices, edges and the least-squares problem they define.

use super::factors::{sqrt_information, Between2, Between3};
use dynamap_solver::lie::{se2, se3};
use dynamap_solver::robust::NamedKernel;
use dynamap_solver::{Problem, ResidualId, RobustKernel, SolveError, VarId, SE2, SE3};
use nalgebra::{Isometry2, Isometry3, Matrix3, Matrix6};
use std::collections::{BTreeMap, BTreeSet};

/// Planar (SE(2)) or spatial (SE(3)) graph.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dimension {
    /// SE(2) poses.
    Two,
    /// SE(3) poses.
    Three,
}

/// A pose of either dimension.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Pose {
    /// Planar pose.
    Se2(Isometry2<f64>),
    /// Spatial pose.
    Se3(Isometry3<f64>),
}

impl Pose {
    /// The identity of a dimension.
    pub fn identity(d: Dimension) -> Self {
        match d {
            Dimension::Two => Pose::Se2(Isometry2::identity()),
            Dimension::Three => Pose::Se3(Isometry3::identity()),
        }
    }
    /// `self * other`.
    ///
    /// # Panics
    /// If the dimensions differ (the graph never mixes them).
    pub fn compose(&self, other: &Pose) -> Pose {
        match (self, other) {
            (Pose::Se2(a), Pose::Se2(b)) => Pose::Se2(a * b),
            (Pose::Se3(a), Pose::Se3(b)) => Pose::Se3(a * b),
            _ => panic!("composing poses of different dimensions"),
        }
    }
    /// The inverse pose.
    pub fn inverse(&self) -> Pose {
        match self {
            Pose::Se2(a) => Pose::Se2(a.inverse()),
            Pose::Se3(a) => Pose::Se3(a.inverse()),
        }
    }
    /// Stored coordinates: `[x, y, θ]` or `[tx, ty, tz, qx, qy, qz, qw]`.
    pub fn coordinates(&self) -> Vec<f64> {
        match self {
            Pose::Se2(a) => se2::coordinates(a).as_slice().to_vec(),
            Pose::Se3(a) => {
                let mut s = vec![0.0; 7];
                se3::to_slice(a, &mut s);
                s
            }
        }
    }
}

/// A relative measurement with its information matrix (in the solver's tangent order).
#[derive(Clone, Debug, PartialEq)]
#[allow(clippy::large_enum_variant)] // a graph holds one kind; boxing would cost an allocation per edge
pub enum Measurement {
    /// SE(2): Ω in `[x, y, θ]` order.
    Se2 {
        /// Measured relative pose.
        z: Isometry2<f64>,
        /// Information matrix.
        information: Matrix3<f64>,
    },
    /// SE(3): Ω in `[ω; v]` order.
    Se3 {
        /// Measured relative pose.
        z: Isometry3<f64>,
        /// Information matrix.
        information: Matrix6<f64>,
    },
}

impl Measurement {
    /// The measured relative pose.
    pub fn pose(&self) -> Pose {
        match self {
            Measurement::Se2 { z, .. } => Pose::Se2(*z),
            Measurement::Se3 { z, .. } => Pose::Se3(*z),
        }
    }
}

/// An edge `from → to` measuring `X_from⁻¹ X_to`.
#[derive(Clone, Debug, PartialEq)]
pub struct Edge {
    /// Vertex i.
    pub from: usize,
    /// Vertex j.
    pub to: usize,
    /// Z_ij and Ω.
    pub measurement: Measurement,
    /// Line of the file it came from (0 when built in code).
    pub line: usize,
}

/// A pose graph as read from a file or built in code.
#[derive(Clone, Debug)]
pub struct PoseGraph {
    /// Where it came from, for messages.
    pub source: String,
    /// SE(2) or SE(3).
    pub dimension: Dimension,
    /// Initial poses by vertex id.
    pub vertices: BTreeMap<usize, Pose>,
    /// The edges, in file order.
    pub edges: Vec<Edge>,
    /// Vertices held fixed (g2o's FIX).
    pub fixed: BTreeSet<usize>,
}

/// A pose graph turned into a solver problem, with the map from vertex ids to variables.
pub struct PoseGraphProblem {
    /// The least-squares problem (cost = ½ chi2).
    pub problem: Problem,
    /// Vertex ids, in variable order.
    pub ids: Vec<usize>,
    /// Variables, parallel to `ids`.
    pub vars: Vec<VarId>,
    /// Each edge's residual block, parallel to the graph's edges.
    pub residuals: Vec<ResidualId>,
    dimension: Dimension,
}

impl PoseGraphProblem {
    /// The current poses of all vertices.
    pub fn poses(&self) -> BTreeMap<usize, Pose> {
        self.ids
            .iter()
            .zip(&self.vars)
            .map(|(&id, &v)| {
                let x = self.problem.value(v);
                let p = match self.dimension {
                    Dimension::Two => Pose::Se2(se2::from_coordinates(x)),
                    Dimension::Three => Pose::Se3(se3::from_slice(x)),
                };
                (id, p)
            })
            .collect()
    }

    /// A solve's error with its variables named by vertex id, the file first (`source`), or
    /// `None` when the error names no vertex (it is then the solver's own message).
    pub fn describe(&self, e: &SolveError, source: &str) -> Option<String> {
        match e {
            SolveError::UntouchedVariable(v) => Some(format!(
                "{source}: vertex {} is touched by no edge",
                self.ids[*v]
            )),
            SolveError::RankDeficient {
                message, variables, ..
            } => {
                let names: Vec<String> = variables
                    .iter()
                    .take(12)
                    .map(|&v| self.ids[v].to_string())
                    .collect();
                Some(format!(
                    "{source}: {message} (vertices {})",
                    names.join(", ")
                ))
            }
            _ => None,
        }
    }
}

impl PoseGraph {
    /// An empty graph.
    pub fn new(dimension: Dimension) -> Self {
        Self {
            source: String::from("<memory>"),
            dimension,
            vertices: BTreeMap::new(),
            edges: Vec::new(),
            fixed: BTreeSet::new(),
        }
    }

    /// The vertices that fix the gauge, sorted: the FIX ones, and the lowest id of every
    /// connected piece of the graph (its vertices joined by edges) that holds no FIX vertex.
    /// A graph in several pieces (a SLAM run's maps that no loop joined) is free to move each
    /// piece on its own; each is held where the file puts its lowest vertex, as g2o holds the
    /// first vertex of a graph in one piece. A graph whose only vertex no edge touches has that
    /// vertex as its anchor; otherwise such a vertex is in no piece and the solve refuses it.
    pub fn anchors(&self) -> Vec<usize> {
        let pieces = self.pieces();
        let mut anchors = self.fixed.clone();
        let held: BTreeSet<usize> = self.fixed.iter().filter_map(|v| pieces.of(*v)).collect();
        anchors.extend(
            pieces
                .lowest
                .iter()
                .enumerate()
                .filter(|(piece, _)| !held.contains(piece))
                .map(|(_, &v)| v),
        );
        if anchors.is_empty() {
            anchors.extend(pieces.ids.first());
        }
        anchors.into_iter().collect()
    }

    /// The number of connected pieces the edges join the vertices into (a vertex that no edge
    /// touches is in none).
    pub fn components(&self) -> usize {
        self.pieces().lowest.len()
    }

    /// The connected pieces of the graph, by union-find over the edges.
    fn pieces(&self) -> Pieces {
        let ids = self.all_ids();
        // ids numbered 0..n (as most files are) are their own slots, offset by the first
        let first = ids.first().copied().unwrap_or(0);
        let contiguous = ids.last().is_none_or(|&last| last - first + 1 == ids.len());
        let slot = |v: usize| match contiguous {
            true => v - first,
            false => ids
                .binary_search(&v)
                .expect("every edge's ends are in all_ids"),
        };
        let mut parent: Vec<usize> = (0..ids.len()).collect();
        let mut touched = vec![false; ids.len()];
        for e in &self.edges {
            let (a, b) = (slot(e.from), slot(e.to));
            touched[a] = true;
            touched[b] = true;
            let (ra, rb) = (root(&mut parent, a), root(&mut parent, b));
            // the lower slot is the root, so each piece's root is its lowest id
            parent[ra.max(rb)] = ra.min(rb);
        }
        let mut piece_of_root = vec![usize::MAX; ids.len()];
        let mut lowest = Vec::new();
        for k in 0..ids.len() {
            if touched[k] && root(&mut parent, k) == k {
                piece_of_root[k] = lowest.len();
                lowest.push(ids[k]);
            }
        }
        Pieces {
            ids,
            parent,
            piece_of_root,
            lowest,
        }
    }

    /// Every vertex id named by a vertex or an edge, sorted.
    pub fn all_ids(&self) -> Vec<usize> {
        let mut ids: BTreeSet<usize> = self.vertices.keys().copied().collect();
        for e in &self.edges {
            ids.insert(e.from);
            ids.insert(e.to);
        }
        ids.into_iter().collect()
    }

    /// Edges naming a vertex that has no pose in `poses`: (edge line, vertex).
    pub fn missing_in(&self, poses: &BTreeMap<usize, Pose>) -> Vec<(usize, usize)> {
        let mut out = Vec::new();
        for e in &self.edges {
            for v in [e.from, e.to] {
                if !poses.contains_key(&v) {
                    out.push((e.line, v));
                }
            }
        }
        out
    }

    /// chi2 = Σ eᵀ Ω e over all edges at `poses`.
    ///
    /// # Panics
    /// If a pose an edge needs is missing (check with [`Self::missing_in`]).
    pub fn chi2(&self, poses: &BTreeMap<usize, Pose>) -> f64 {
        self.edges
            .iter()
            .map(|e| match (&e.measurement, &poses[&e.from], &poses[&e.to]) {
                (Measurement::Se2 { z, information }, Pose::Se2(a), Pose::Se2(b)) => {
                    let r = se2::log(&(z.inverse() * a.inverse() * b));
                    (r.transpose() * information * r)[0]
                }
                (Measurement::Se3 { z, information }, Pose::Se3(a), Pose::Se3(b)) => {
                    let r = se3::log(&(z.inverse() * a.inverse() * b));
                    (r.transpose() * information * r)[0]
                }
                _ => panic!("pose and measurement dimensions differ"),
            })
            .sum()
    }

    /// Builds the least-squares problem from `poses` (one per vertex), anchors held fixed.
    pub fn build_problem(&self, poses: &BTreeMap<usize, Pose>) -> Result<PoseGraphProblem, String> {
        self.build_robust_problem(poses, None)
    }

    /// As [`Self::build_problem`], with `kernel` on every edge if given (cost ½ Σ ρ(eᵀΩe), as g2o's
    /// `-robustKernel` and a Ceres `LossFunction` on every residual block give it).
    pub fn build_robust_problem(
        &self,
        poses: &BTreeMap<usize, Pose>,
        kernel: Option<NamedKernel>,
    ) -> Result<PoseGraphProblem, String> {
        self.build_problem_with(poses, |_| kernel)
    }

    /// As [`Self::build_problem`], with the kernel `kernel_of(edge)` on each edge: e.g. plain
    /// odometry beside loop closures under DCS (Agarwal et al. 2013), so that a wrong loop is
    /// switched off without weakening the odometry.
    pub fn build_problem_with(
        &self,
        poses: &BTreeMap<usize, Pose>,
        kernel_of: impl Fn(&Edge) -> Option<NamedKernel>,
    ) -> Result<PoseGraphProblem, String> {
        if let Some((line, v)) = self.missing_in(poses).first() {
            return Err(format!(
                "{}:{line}: the edge refers to vertex {v}, which has no pose \
                 (no VERTEX line; initialise with odometry or chordal to compute it)",
                self.source
            ));
        }
        let mut problem = Problem::new();
        problem.reserve(poses.len(), self.edges.len());
        let mut index = BTreeMap::new();
        let (mut ids, mut vars) = (
            Vec::with_capacity(poses.len()),
            Vec::with_capacity(poses.len()),
        );
        for (&id, pose) in poses {
            let value = pose.coordinates();
            let var = match pose {
                Pose::Se2(_) => problem.add_variable(&value, SE2),
                Pose::Se3(_) => problem.add_variable(&value, SE3),
            }
            .map_err(|e| format!("{}: vertex {id}: {e}", self.source))?;
            index.insert(id, var);
            ids.push(id);
            vars.push(var);
        }
        for a in self.anchors() {
            if let Some(&v) = index.get(&a) {
                problem.set_fixed(v, true).map_err(|e| e.to_string())?;
            }
        }
        let mut residuals = Vec::with_capacity(self.edges.len());
        for e in &self.edges {
            let pair = [index[&e.from], index[&e.to]];
            let added = match &e.measurement {
                Measurement::Se2 { z, information } => {
                    let u = sqrt_information(information).ok_or_else(|| {
                        format!(
                            "{}:{}: information matrix is not positive definite",
                            self.source, e.line
                        )
                    })?;
                    let r = Box::new(Between2::new(*z, u));
                    problem.add_block(r, kernel_of(e).map(boxed), &pair)
                }
                Measurement::Se3 { z, information } => {
                    let u = sqrt_information(information).ok_or_else(|| {
                        format!(
                            "{}:{}: information matrix is not positive definite",
                            self.source, e.line
                        )
                    })?;
                    let r = Box::new(Between3::new(*z, u));
                    problem.add_block(r, kernel_of(e).map(boxed), &pair)
                }
            };
            residuals.push(added.map_err(|err| format!("{}:{}: {err}", self.source, e.line))?);
        }
        Ok(PoseGraphProblem {
            problem,
            ids,
            vars,
            residuals,
            dimension: self.dimension,
        })
    }
}

/// The connected pieces of a graph ([`PoseGraph::pieces`]).
struct Pieces {
    /// Every vertex id, sorted (the union-find's slots).
    ids: Vec<usize>,
    /// Union-find parents by slot, each path ending at its piece's lowest slot.
    parent: Vec<usize>,
    /// The piece numbered by its root's slot (`usize::MAX` for a slot that is no root, or a
    /// vertex no edge touches).
    piece_of_root: Vec<usize>,
    /// Each piece's lowest vertex id, in the order of those ids.
    lowest: Vec<usize>,
}

impl Pieces {
    /// The piece of vertex `v`, if an edge touches it.
    fn of(&self, v: usize) -> Option<usize> {
        let k = self.ids.binary_search(&v).ok()?;
        let mut r = k;
        while self.parent[r] != r {
            r = self.parent[r];
        }
        Some(self.piece_of_root[r]).filter(|&p| p != usize::MAX)
    }
}

/// The root of slot `k` in the union-find `parent`, halving the path on the way.
fn root(parent: &mut [usize], mut k: usize) -> usize {
    while parent[k] != k {
        parent[k] = parent[parent[k]];
        k = parent[k];
    }
    k
}

fn boxed(kernel: NamedKernel) -> Box<dyn RobustKernel> {
    Box::new(kernel)
}
