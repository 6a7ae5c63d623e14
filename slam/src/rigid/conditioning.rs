//! How well a frame's geometry fixes its pose, whatever the pose: the conditioning of the
//! point-to-plane term's information, Σ [p × n; n][p × n; n]ᵀ, after Gelfand et al.,
//! *Geometrically stable sampling for the ICP algorithm* (3DIM 2003). A plane leaves three
//! motions free, two planes one.
//!
//! The normals are those of planes fitted to patches of the level ([`PATCHES_ACROSS`] across),
//! not the level's own per-pixel ones. A depth sensor's noise tilts each pixel's normal at
//! random, and those tilts fill the free directions: renders of a textured wall 2.5–3 m from a
//! Kinect, over a strip of floor, read 3·10⁻³–2·10⁻² per pixel, and with λ = 0 all 300 frames
//! of one were reported tracked with an ATE of 651 mm (NOTES 155, 156). A patch's plane
//! averages the noise away and keeps the surface's shape. The patches are large, because a
//! structured-light sensor's depth comes in steps (z² / 348 m: 21 mm at 2.7 m, 72 mm at 5 m):
//! a small patch on one step of a slanted wall fits the step, not the wall, and the steps' tilts
//! grow with the depth. With 16 patches across, the far walls read up to 3.5·10⁻³ at 2.5–3 m
//! and 1.1·10⁻² with their depth doubled and re-stepped; with 6 across, 2.1·10⁻³ and 2.6·10⁻³.
//! Real frames read 4.4·10⁻³–1.9·10⁻², our generator's rooms and fast sweep 1.1·10⁻²–4.6·10⁻²
//! (NOTES 157).

use crate::image::valid;
use crate::preprocess::Level;
use nalgebra::{Matrix3, Matrix6, Vector3};

/// Fewer points with a normal than the six a pose has degrees of freedom measure nothing.
pub(super) const MIN_CONSTRAINT_POINTS: usize = 6;

/// Patches across the level's width (square, so 4–5 down a 4:3 frame): 26 px on the coarsest
/// level of 640×480 (104 px at full resolution), 13 px at 320×240.
const PATCHES_ACROSS: usize = 6;

/// λ_min / λ_max of Σ [p × n; n][p × n; n]ᵀ over a level's valid points, each with the normal of
/// its patch's plane, the rotation part divided by the mean depth so both parts are in metres
/// (0 when there are too few points); and the number of valid points with a normal.
pub(super) fn geometric_conditioning(level: &Level) -> (f64, usize) {
    let (w, h) = (level.vertices.width, level.vertices.height);
    let points = level
        .vertices
        .data
        .iter()
        .zip(&level.normals.data)
        .filter(|(p, n)| valid(p) && valid(n))
        .count();
    if points < MIN_CONSTRAINT_POINTS {
        return (0.0, points);
    }
    let side = (w / PATCHES_ACROSS).max(2);
    let mut c = Matrix6::<f64>::zeros();
    let (mut depth, mut n) = (0.0, 0usize);
    for y0 in (0..h).step_by(side) {
        for x0 in (0..w).step_by(side) {
            let m = Moments::of_patch(level, (x0, y0), side);
            let Some(normal) = m.plane_normal(side * side / 4) else {
                continue;
            };
            m.add_constraint(&normal, &mut c);
            depth += m.sum.z;
            n += m.count;
        }
    }
    if n < MIN_CONSTRAINT_POINTS {
        return (0.0, points);
    }
    (ratio(c, n as f64 / depth.max(1e-6)), points)
}

/// λ_min / λ_max of `c` with its rotation rows and columns scaled by `k` (1 / mean depth).
fn ratio(mut c: Matrix6<f64>, k: f64) -> f64 {
    for i in 0..6 {
        for j in 0..6 {
            c[(i, j)] *= if i < 3 { k } else { 1.0 } * if j < 3 { k } else { 1.0 };
        }
    }
    let e = c.symmetric_eigenvalues();
    if e.max() > 0.0 {
        (e.min() / e.max()).max(0.0)
    } else {
        0.0
    }
}

/// The zeroth, first and second moments of a patch's valid points (camera frame): all that the
/// plane fit and the patch's share of the information need, gathered in one pass.
struct Moments {
    count: usize,
    /// Σ p.
    sum: Vector3<f64>,
    /// Σ p pᵀ.
    outer: Matrix3<f64>,
}

impl Moments {
    /// The moments of the square of `side` pixels of `level` from `(x0, y0)`, clipped to it.
    fn of_patch(level: &Level, (x0, y0): (usize, usize), side: usize) -> Self {
        let v = &level.vertices;
        let mut m = Self {
            count: 0,
            sum: Vector3::zeros(),
            outer: Matrix3::zeros(),
        };
        for y in y0..(y0 + side).min(v.height) {
            for p in &v.data[y * v.width + x0..y * v.width + (x0 + side).min(v.width)] {
                if valid(p) {
                    let p = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
                    m.count += 1;
                    m.sum += p;
                    m.outer += p * p.transpose();
                }
            }
        }
        m
    }

    /// The unit normal (facing the camera) of the plane fitted to the points: the least
    /// eigenvector of their scatter Σ p pᵀ − n p̄ p̄ᵀ; `None` below `min_count` points (or 3).
    fn plane_normal(&self, min_count: usize) -> Option<Vector3<f64>> {
        if self.count < min_count.max(3) {
            return None;
        }
        let mean = self.sum / self.count as f64;
        let scatter = self.outer - self.sum * mean.transpose();
        let eig = scatter.symmetric_eigen();
        let normal = eig.eigenvectors.column(eig.eigenvalues.imin()).into_owned();
        Some(if normal.dot(&mean) > 0.0 {
            -normal
        } else {
            normal
        })
    }

    /// Adds Σ [p × n; n][p × n; n]ᵀ over the points, all with the normal `n`, to `c`. With
    /// p × n = A p, A = [n]ₓᵀ: the blocks A (Σ p pᵀ) Aᵀ, A (Σ p) nᵀ and count · n nᵀ.
    fn add_constraint(&self, n: &Vector3<f64>, c: &mut Matrix6<f64>) {
        let a = n.cross_matrix().transpose();
        let rot_trans = (a * self.sum) * n.transpose();
        let mut block = |r: usize, k: usize, m: Matrix3<f64>| {
            let mut view = c.fixed_view_mut::<3, 3>(r, k);
            view += m;
        };
        block(0, 0, a * self.outer * a.transpose());
        block(0, 3, rot_trans);
        block(3, 0, rot_trans.transpose());
        block(3, 3, n * n.transpose() * self.count as f64);
    }
}
