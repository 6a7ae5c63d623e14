//! Information matrices that are not positive definite, as published graphs carry them (SE-Sync's
//! cubicle graph has one with a negative eigenvalue): the nearest positive-definite matrix whose
//! eigenvalues are at least [`REPAIR_FLOOR`] times the largest (Higham, *Computing a nearest
//! symmetric positive semidefinite matrix*, 1988: clamping the eigenvalues of the symmetric
//! matrix is nearest in the Frobenius norm; the floor keeps its square root finite).

use nalgebra::{DMatrix, SMatrix, SymmetricEigen};

/// Eigenvalues below this fraction of the largest are raised to it.
pub const REPAIR_FLOOR: f64 = 1e-9;

/// What was done to one edge's information matrix on reading.
#[derive(Clone, Debug, PartialEq)]
pub struct InformationRepair {
    /// Line of the edge in its file.
    pub line: usize,
    /// Its first vertex.
    pub from: usize,
    /// Its second vertex.
    pub to: usize,
    /// The smallest eigenvalue of the matrix as written.
    pub smallest_eigenvalue: f64,
    /// Eigenvalues raised.
    pub raised: usize,
    /// The value they were raised to.
    pub floor: f64,
}

impl std::fmt::Display for InformationRepair {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "line {} (edge {} -> {}): the information matrix is not positive definite (smallest \
             eigenvalue {:.3e}); {} eigenvalue(s) raised to {:.3e} ({:e} of the largest), the \
             nearest positive-definite matrix",
            self.line,
            self.from,
            self.to,
            self.smallest_eigenvalue,
            self.raised,
            self.floor,
            REPAIR_FLOOR
        )
    }
}

/// `m` with its eigenvalues raised to at least [`REPAIR_FLOOR`] times the largest, with the
/// smallest eigenvalue of `m`, the number raised and the floor; `None` when `m` has no positive
/// eigenvalue (or is not finite), so nothing is left to keep.
#[allow(clippy::type_complexity)]
pub fn repair<const N: usize>(
    m: &SMatrix<f64, N, N>,
) -> Option<(SMatrix<f64, N, N>, f64, usize, f64)> {
    if !m.iter().all(|v| v.is_finite()) {
        return None;
    }
    // dynamic-size eigen-decomposition: N is 3 or 6, read once per edge
    let symmetric = DMatrix::from_column_slice(N, N, ((m + m.transpose()) * 0.5).as_slice());
    let eigen = SymmetricEigen::new(symmetric);
    let largest = eigen.eigenvalues.max();
    if largest.is_nan() || largest <= 0.0 {
        return None;
    }
    let floor = REPAIR_FLOOR * largest;
    let raised = eigen.eigenvalues.iter().filter(|l| **l < floor).count();
    let clamped = eigen.eigenvalues.map(|l| l.max(floor));
    let v = &eigen.eigenvectors;
    let out = v * DMatrix::from_diagonal(&clamped) * v.transpose();
    let out = SMatrix::<f64, N, N>::from_fn(|r, c| 0.5 * (out[(r, c)] + out[(c, r)]));
    Some((out, eigen.eigenvalues.min(), raised, floor))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix3;

    /// An indefinite matrix becomes positive definite, keeps the eigenvectors and the eigenvalues
    /// above the floor, and is nearer to the original than any other clamp would leave it; a
    /// matrix with no positive eigenvalue cannot be repaired.
    #[test]
    fn an_indefinite_matrix_is_raised_to_the_floor_and_nothing_else_moves() {
        let m = Matrix3::new(4.0, 1.0, 0.0, 1.0, 3.0, 0.0, 0.0, 0.0, -0.5);
        assert!(nalgebra::Cholesky::new(m).is_none());
        let (r, smallest, raised, floor) = repair(&m).unwrap();
        assert_eq!(raised, 1);
        assert!((smallest + 0.5).abs() < 1e-12);
        assert!(nalgebra::Cholesky::new(r).is_some());
        let before = SymmetricEigen::new(m).eigenvalues;
        let after = SymmetricEigen::new(r).eigenvalues;
        let mut b: Vec<f64> = before.iter().copied().collect();
        let mut a: Vec<f64> = after.iter().copied().collect();
        b.sort_by(f64::total_cmp);
        a.sort_by(f64::total_cmp);
        assert!((a[0] - floor).abs() < 1e-12, "{a:?}");
        assert!((a[1] - b[1]).abs() < 1e-12 && (a[2] - b[2]).abs() < 1e-12);
        // the repaired block is the original's, the third coordinate floored
        assert!((r - Matrix3::new(4.0, 1.0, 0.0, 1.0, 3.0, 0.0, 0.0, 0.0, floor)).amax() < 1e-12);
        assert!(repair(&(-Matrix3::<f64>::identity())).is_none());
        assert!(repair(&Matrix3::<f64>::zeros()).is_none());
    }
}
