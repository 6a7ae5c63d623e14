//! Evaluation (thesis eq. 3.26-3.27): absolute trajectory error after Horn/Umeyama alignment, relative
//! pose error, scene-flow end-point error and point-to-surface mesh distances; a non-rigid
//! registration against a ground-truth vertex map ([`VertexMap`]) and a scene flow against its
//! ground truth ([`flow_scores`]).
//!
//! Association and statistics follow evo (Grupp, 2017) so that the figures agree with
//! `evo_ape tum GT EST -a` and `evo_rpe`: each stamp of the shorter trajectory is matched to the
//! nearest stamp of the longer within 0.01 s; the estimate is aligned onto the ground truth.

mod flow_score;
mod vertex_map;

pub use flow_score::{flow_scores, FlowScores};
pub use vertex_map::{MapError, VertexMap};

use crate::io::trajectory::Trajectory;
use crate::mesh::Mesh;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Isometry3, Matrix3, Point3, Translation3, UnitQuaternion, Vector3};

/// evo's default maximum stamp difference for associating two trajectories, seconds.
pub const MAX_STAMP_DIFFERENCE: f64 = 0.01;

/// Summary statistics of a set of errors.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stats {
    /// Root mean square.
    pub rmse: f64,
    /// Mean.
    pub mean: f64,
    /// Median (mean of the middle two for an even count, as numpy).
    pub median: f64,
    /// Largest.
    pub max: f64,
    /// Smallest.
    pub min: f64,
    /// Standard deviation (population).
    pub std: f64,
    /// Number of values.
    pub count: usize,
}

impl Stats {
    /// Statistics of `values` (all zero for an empty set).
    pub fn of(values: &[f64]) -> Self {
        let n = values.len();
        if n == 0 {
            return Self {
                rmse: 0.0,
                mean: 0.0,
                median: 0.0,
                max: 0.0,
                min: 0.0,
                std: 0.0,
                count: 0,
            };
        }
        let mean = values.iter().sum::<f64>() / n as f64;
        let rmse = (values.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt();
        let std = (values.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n as f64).sqrt();
        let mut s = values.to_vec();
        s.sort_by(f64::total_cmp);
        let median = if n % 2 == 1 {
            s[n / 2]
        } else {
            0.5 * (s[n / 2 - 1] + s[n / 2])
        };
        Self {
            rmse,
            mean,
            median,
            max: s[n - 1],
            min: s[0],
            std,
            count: n,
        }
    }
}

/// How the estimate is aligned onto the ground truth before the ATE.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Alignment {
    /// No alignment.
    None,
    /// Rotation and translation (Horn 1987).
    Se3,
    /// Rotation, translation and scale (Umeyama 1991).
    Sim3,
}

/// A similarity transform y = s R x + t.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Similarity {
    /// Scale.
    pub scale: f64,
    /// Rotation and translation.
    pub isometry: Isometry3<f64>,
}

impl Similarity {
    /// Applies the transform to a point.
    pub fn apply(&self, p: &Point3<f64>) -> Point3<f64> {
        self.isometry.rotation * (p * self.scale) + self.isometry.translation.vector
    }
}

/// Umeyama's closed-form least-squares alignment of `src` onto `dst` (IEEE TPAMI 1991, eq. 40-42):
/// minimises Σ‖dst_i − (s R src_i + t)‖²; with `with_scale` false, s = 1 (Horn's absolute orientation).
/// `None` for fewer than 3 points or a degenerate (collinear) configuration.
pub fn umeyama(src: &[Point3<f64>], dst: &[Point3<f64>], with_scale: bool) -> Option<Similarity> {
    let n = src.len();
    if n < 3 || dst.len() != n {
        return None;
    }
    let mx = src.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n as f64;
    let my = dst.iter().map(|p| p.coords).sum::<Vector3<f64>>() / n as f64;
    let mut cov = Matrix3::zeros();
    let mut var_x = 0.0;
    for (x, y) in src.iter().zip(dst) {
        let (dx, dy) = (x.coords - mx, y.coords - my);
        cov += dy * dx.transpose();
        var_x += dx.norm_squared();
    }
    cov /= n as f64;
    var_x /= n as f64;
    // coordinates so large that their products overflow give no alignment (and would keep the
    // SVD iterating for ever)
    if !cov.iter().all(|v| v.is_finite()) || !var_x.is_finite() {
        return None;
    }
    let svd = cov.try_svd(true, true, f64::EPSILON, 1000)?;
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut s = Matrix3::identity();
    if u.determinant() * vt.determinant() < 0.0 {
        s[(2, 2)] = -1.0;
    }
    let r = u * s * vt;
    let scale = if with_scale {
        if var_x <= 0.0 {
            return None;
        }
        (Matrix3::from_diagonal(&svd.singular_values) * s).trace() / var_x
    } else {
        1.0
    };
    let t = my - r * mx * scale;
    if !r.iter().all(|v| v.is_finite()) {
        return None;
    }
    // R = U S Vᵀ is orthonormal by construction: take it in closed form (nalgebra's iterative
    // `from_matrix` never returns on some ill-conditioned inputs)
    let rot = UnitQuaternion::from_rotation_matrix(&nalgebra::Rotation3::from_matrix_unchecked(r));
    Some(Similarity {
        scale,
        isometry: Isometry3::from_parts(Translation3::from(t), rot),
    })
}

/// Pairs of indices (ground truth, estimate) matched as evo does: each stamp of the shorter
/// trajectory to the nearest stamp of the longer, kept when at most `max_difference` apart.
pub fn associate(gt: &Trajectory, est: &Trajectory, max_difference: f64) -> Vec<(usize, usize)> {
    let est_longer = est.len() > gt.len();
    let (short, long) = if est_longer {
        (&gt.stamps, &est.stamps)
    } else {
        (&est.stamps, &gt.stamps)
    };
    let mut order: Vec<usize> = (0..long.len()).collect();
    order.sort_by(|&a, &b| long[a].total_cmp(&long[b]));
    let sorted: Vec<f64> = order.iter().map(|&i| long[i]).collect();
    let mut out = Vec::new();
    for (i, &s) in short.iter().enumerate() {
        if sorted.is_empty() {
            break;
        }
        let k = sorted.partition_point(|&v| v <= s).min(sorted.len() - 1);
        let mut best = k;
        if k > 0 && (s - sorted[k - 1]).abs() <= (sorted[k] - s).abs() {
            best = k - 1;
        }
        if (sorted[best] - s).abs() <= max_difference {
            let j = order[best];
            out.push(if est_longer { (i, j) } else { (j, i) });
        }
    }
    out
}

/// The result of an ATE evaluation.
#[derive(Clone, Debug, PartialEq)]
pub struct AteResult {
    /// Translational error statistics, metres.
    pub stats: Stats,
    /// The alignment applied to the estimate.
    pub alignment: Similarity,
    /// Associated (ground truth, estimate) index pairs.
    pub pairs: Vec<(usize, usize)>,
}

/// Absolute trajectory error: associate, align, and take ‖t_gt − align(t_est)‖ per pair.
pub fn ate(
    gt: &Trajectory,
    est: &Trajectory,
    alignment: Alignment,
    max_difference: f64,
) -> Result<AteResult, String> {
    let pairs = associate(gt, est, max_difference);
    if pairs.is_empty() {
        return Err(format!(
            "no pose of the estimate is within {max_difference} s of a ground-truth pose"
        ));
    }
    let g: Vec<Point3<f64>> = pairs
        .iter()
        .map(|&(i, _)| gt.poses[i].translation.vector.into())
        .collect();
    let e: Vec<Point3<f64>> = pairs
        .iter()
        .map(|&(_, j)| est.poses[j].translation.vector.into())
        .collect();
    let align = match alignment {
        Alignment::None => Similarity {
            scale: 1.0,
            isometry: Isometry3::identity(),
        },
        Alignment::Se3 | Alignment::Sim3 => umeyama(&e, &g, alignment == Alignment::Sim3)
            .ok_or_else(|| {
                format!(
                    "cannot align {} associated poses (need 3 not on a line)",
                    pairs.len()
                )
            })?,
    };
    let errors: Vec<f64> = g
        .iter()
        .zip(&e)
        .map(|(g, e)| (g - align.apply(e)).norm())
        .collect();
    Ok(AteResult {
        stats: Stats::of(&errors),
        alignment: align,
        pairs,
    })
}

/// What the RPE's δ counts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DeltaUnit {
    /// Frames (associated pose indices).
    Frames,
    /// Seconds of ground-truth time.
    Seconds,
    /// Metres of ground-truth path.
    Meters,
}

/// The result of an RPE evaluation.
#[derive(Clone, Debug, PartialEq)]
pub struct RpeResult {
    /// Translational error statistics, metres.
    pub translation: Stats,
    /// Rotational error statistics, degrees.
    pub rotation_deg: Stats,
}

/// Index pairs (i, j) of consecutive, non-overlapping intervals of at least `delta` (evo's
/// `filter_pairs_by_*` without `all_pairs`).
fn delta_pairs(
    gt: &[Isometry3<f64>],
    stamps: &[f64],
    delta: f64,
    unit: DeltaUnit,
) -> Vec<(usize, usize)> {
    match unit {
        DeltaUnit::Frames => {
            let d = delta.max(1.0) as usize;
            (0..gt.len().saturating_sub(d))
                .map(|i| (i, i + d))
                .collect()
        }
        DeltaUnit::Seconds | DeltaUnit::Meters => {
            let mut out = Vec::new();
            let (mut first, mut acc) = (0, 0.0);
            for i in 1..gt.len() {
                acc += match unit {
                    DeltaUnit::Seconds => stamps[i] - stamps[i - 1],
                    _ => (gt[i].translation.vector - gt[i - 1].translation.vector).norm(),
                };
                if acc >= delta {
                    out.push((first, i));
                    first = i;
                    acc = 0.0;
                }
            }
            out
        }
    }
}

/// Relative pose error over intervals of `delta`: E = (G_i⁻¹ G_j)⁻¹ (P_i⁻¹ P_j), translation ‖t(E)‖
/// and rotation angle(E) in degrees (Sturm et al. 2012, eq. 1).
pub fn rpe(
    gt: &Trajectory,
    est: &Trajectory,
    delta: f64,
    unit: DeltaUnit,
    max_difference: f64,
) -> Result<RpeResult, String> {
    let pairs = associate(gt, est, max_difference);
    if pairs.len() < 2 {
        return Err("fewer than 2 associated poses".into());
    }
    let g: Vec<Isometry3<f64>> = pairs.iter().map(|&(i, _)| gt.poses[i]).collect();
    let s: Vec<f64> = pairs.iter().map(|&(i, _)| gt.stamps[i]).collect();
    let p: Vec<Isometry3<f64>> = pairs.iter().map(|&(_, j)| est.poses[j]).collect();
    let ids = delta_pairs(&g, &s, delta, unit);
    if ids.is_empty() {
        return Err(format!("no pair of poses is {delta} {unit:?} apart"));
    }
    let (mut t, mut r) = (Vec::with_capacity(ids.len()), Vec::with_capacity(ids.len()));
    for (i, j) in ids {
        let e = (g[i].inverse() * g[j]).inverse() * (p[i].inverse() * p[j]);
        t.push(e.translation.vector.norm());
        r.push(e.rotation.angle().to_degrees());
    }
    Ok(RpeResult {
        translation: Stats::of(&t),
        rotation_deg: Stats::of(&r),
    })
}

/// Scene-flow end-point error (EPE 3D): per-point ‖flow_est − flow_gt‖ over the points where
/// `valid` holds, and the fractions below 5 cm and 10 cm (the "strict" and "relaxed" accuracies of
/// the scene-flow literature).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EpeResult {
    /// Error statistics, metres.
    pub stats: Stats,
    /// Fraction of points with error < 5 cm.
    pub within_5cm: f64,
    /// Fraction of points with error < 10 cm.
    pub within_10cm: f64,
}

/// EPE 3D of an estimated scene flow against ground truth (same length; `valid` masks points).
pub fn epe3d(est: &[Vector3<f64>], gt: &[Vector3<f64>], valid: Option<&[bool]>) -> EpeResult {
    let errors: Vec<f64> = est
        .iter()
        .zip(gt)
        .enumerate()
        .filter(|(i, _)| valid.is_none_or(|v| v[*i]))
        .map(|(_, (a, b))| (a - b).norm())
        .collect();
    let n = errors.len().max(1) as f64;
    EpeResult {
        stats: Stats::of(&errors),
        within_5cm: errors.iter().filter(|e| **e < 0.05).count() as f64 / n,
        within_10cm: errors.iter().filter(|e| **e < 0.10).count() as f64 / n,
    }
}

/// The closest point to `p` on triangle (a, b, c) (Ericson, *Real-Time Collision Detection*, 2005,
/// sec. 5.1.5).
pub(crate) fn closest_point_on_triangle(
    p: &Vector3<f64>,
    a: &Vector3<f64>,
    b: &Vector3<f64>,
    c: &Vector3<f64>,
) -> Vector3<f64> {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(&ap), ac.dot(&ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return *a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(&bp), ac.dot(&bp));
    if d3 >= 0.0 && d4 <= d3 {
        return *b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(&cp), ac.dot(&cp));
    if d6 >= 0.0 && d5 <= d6 {
        return *c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

/// Exact point-to-surface distances to a mesh, through a k-d tree over triangle centroids: the
/// nearest triangle lies within (nearest centroid distance + largest centroid-to-corner radius).
pub struct SurfaceDistance<'a> {
    mesh: &'a Mesh,
    tree: ImmutableKdTree<f64, 3>,
    radius: f64,
}

impl<'a> SurfaceDistance<'a> {
    /// Indexes a mesh; `None` when it has no faces.
    pub fn new(mesh: &'a Mesh) -> Option<Self> {
        if mesh.faces.is_empty() {
            return None;
        }
        let mut radius: f64 = 0.0;
        let centroids: Vec<[f64; 3]> = mesh
            .faces
            .iter()
            .map(|f| {
                let v = f.map(|i| mesh.vertices[i as usize].coords.cast::<f64>());
                let c = (v[0] + v[1] + v[2]) / 3.0;
                radius = radius.max(v.iter().map(|p| (p - c).norm()).fold(0.0, f64::max));
                [c.x, c.y, c.z]
            })
            .collect();
        Some(Self {
            mesh,
            tree: ImmutableKdTree::new_from_slice(&centroids),
            radius,
        })
    }

    /// Distance from `p` to the surface.
    pub fn distance(&self, p: &Point3<f64>) -> f64 {
        let q = [p.x, p.y, p.z];
        let nearest = self.tree.nearest_one::<SquaredEuclidean>(&q);
        let r = nearest.distance.sqrt() + self.radius;
        let mut best = f64::INFINITY;
        for n in self
            .tree
            .within_unsorted::<SquaredEuclidean>(&q, r * r * (1.0 + 1e-12) + 1e-18)
        {
            let f = self.mesh.faces[n.item as usize];
            let [a, b, c] = f.map(|i| self.mesh.vertices[i as usize].coords.cast::<f64>());
            best = best.min((closest_point_on_triangle(&p.coords, &a, &b, &c) - p.coords).norm());
        }
        best
    }
}

/// Distances from every vertex of `from` to the surface of `to`; `None` if `to` has no faces.
pub fn mesh_to_mesh(from: &Mesh, to: &Mesh) -> Option<Stats> {
    let index = SurfaceDistance::new(to)?;
    let d: Vec<f64> = from
        .vertices
        .iter()
        .map(|v| index.distance(&v.cast::<f64>()))
        .collect();
    Some(Stats::of(&d))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector6;
    use proptest::prelude::*;

    #[test]
    fn stats_follow_numpy() {
        let s = Stats::of(&[3.0, 1.0, 2.0, 4.0]);
        assert_eq!((s.median, s.max, s.min, s.mean), (2.5, 4.0, 1.0, 2.5));
        assert!((s.rmse - (30.0f64 / 4.0).sqrt()).abs() < 1e-15);
    }

    proptest! {
        #[test]
        fn umeyama_recovers_a_similarity(a in prop::array::uniform6(-1.0f64..1.0), scale in 0.5f64..2.0) {
            let t = dynamap_solver::lie::se3::exp(&Vector6::from_column_slice(&a));
            let src: Vec<Point3<f64>> = (0..20).map(|i| {
                let f = i as f64;
                Point3::new((f * 0.7).sin() * 3.0, (f * 1.3).cos(), f * 0.1)
            }).collect();
            let dst: Vec<Point3<f64>> = src.iter().map(|p| t * (p * scale)).collect();
            let s = umeyama(&src, &dst, true).unwrap();
            prop_assert!((s.scale - scale).abs() < 1e-9);
            for (p, q) in src.iter().zip(&dst) {
                prop_assert!((s.apply(p) - q).norm() < 1e-9);
            }
        }

        #[test]
        fn closest_point_is_no_farther_than_any_sample(p in prop::array::uniform3(-2.0f64..2.0), u in 0.0f64..1.0, v in 0.0f64..1.0) {
            let (a, b, c) = (Vector3::new(0.0, 0.0, 0.0), Vector3::new(1.0, 0.2, 0.0), Vector3::new(0.3, 1.0, 0.4));
            let p = Vector3::from(p);
            let q = closest_point_on_triangle(&p, &a, &b, &c);
            let (u, v) = if u + v > 1.0 { (1.0 - u, 1.0 - v) } else { (u, v) };
            let sample = a + (b - a) * u + (c - a) * v;
            prop_assert!((q - p).norm() <= (sample - p).norm() + 1e-12);
        }
    }

    #[test]
    fn mesh_distance_of_a_shifted_square() {
        let square = |z: f32| Mesh {
            vertices: vec![
                Point3::new(0.0, 0.0, z),
                Point3::new(1.0, 0.0, z),
                Point3::new(1.0, 1.0, z),
                Point3::new(0.0, 1.0, z),
            ],
            faces: vec![[0, 1, 2], [0, 2, 3]],
            ..Mesh::default()
        };
        let s = mesh_to_mesh(&square(0.25), &square(0.0)).unwrap();
        assert!((s.max - 0.25).abs() < 1e-7 && (s.min - 0.25).abs() < 1e-7);
        let base = square(0.0);
        let index = SurfaceDistance::new(&base).unwrap();
        assert!((index.distance(&Point3::new(2.0, 0.5, 0.0)) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn epe_counts_accuracies() {
        let gt = vec![Vector3::zeros(); 4];
        let est = vec![
            Vector3::new(0.01, 0.0, 0.0),
            Vector3::new(0.07, 0.0, 0.0),
            Vector3::new(0.2, 0.0, 0.0),
            Vector3::new(9.0, 0.0, 0.0),
        ];
        let r = epe3d(&est, &gt, Some(&[true, true, true, false]));
        assert_eq!(r.stats.count, 3);
        assert!(
            (r.within_5cm - 1.0 / 3.0).abs() < 1e-12 && (r.within_10cm - 2.0 / 3.0).abs() < 1e-12
        );
    }
}
