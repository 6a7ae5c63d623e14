//! The small dense kernels of the Schur complement: H_ee⁻¹ H_jᵀ, S_ij −= H_i u, and the inverse
//! of a small symmetric positive definite block.

/// Largest d_e × d_c product of an eliminated and a kept block's sizes (the scratch of one
/// H_ee⁻¹ H_ecᵀ block lives on the stack).
pub(super) const MAX_PRODUCT: usize = 256;
/// Largest size of an eliminated block (its scratch vectors live on the stack).
pub(super) const MAX_ELIMINATED: usize = 16;

/// u = H_ee⁻¹ H_jᵀ (d_e × d_j) from the symmetric inverse (d_e × d_e) and H_j (d_j × d_e), both
/// column-major; `hj(k)` is column k of H_j (d_j values).
#[inline(always)]
pub(super) fn inverse_times_transpose<'a>(
    inv: &[f64],
    hj: impl Fn(usize) -> &'a [f64],
    u: &mut [f64],
    de: usize,
    dj: usize,
) {
    match (de, dj) {
        (3, 9) => inverse_times_transpose_fixed::<3, 9>(inv, hj, u),
        (3, 6) => inverse_times_transpose_fixed::<3, 6>(inv, hj, u),
        _ => inverse_times_transpose_any(inv, hj, u, de, dj),
    }
}

#[inline(always)]
fn inverse_times_transpose_fixed<'a, const DE: usize, const DJ: usize>(
    inv: &[f64],
    hj: impl Fn(usize) -> &'a [f64],
    u: &mut [f64],
) {
    let columns: [&[f64; DJ]; DE] =
        std::array::from_fn(|k| hj(k)[..DJ].try_into().expect("DJ rows"));
    let (inv, u) = (&inv[..DE * DE], &mut u[..DE * DJ]);
    for c in 0..DJ {
        let mut acc = [0.0f64; DE];
        for k in 0..DE {
            let h = columns[k][c];
            for (a, iv) in acc.iter_mut().zip(&inv[k * DE..(k + 1) * DE]) {
                *a += iv * h;
            }
        }
        u[c * DE..(c + 1) * DE].copy_from_slice(&acc);
    }
}

fn inverse_times_transpose_any<'a>(
    inv: &[f64],
    hj: impl Fn(usize) -> &'a [f64],
    u: &mut [f64],
    de: usize,
    dj: usize,
) {
    u[..de * dj].fill(0.0);
    for k in 0..de {
        let column = &hj(k)[..dj];
        for (c, &h) in column.iter().enumerate() {
            for r in 0..de {
                u[r + c * de] += inv[r + k * de] * h;
            }
        }
    }
}

/// S_ij −= H_i u for one block, with H_i d_i × d_e (`hi(k)` its column k) and u = H_ee⁻¹ H_jᵀ
/// d_e × d_j (column-major); column c of the block starts at `out[starts(c)]` (only rows ≤ c on
/// the diagonal). The common sizes run through a fixed-size kernel.
#[inline(always)]
pub(super) fn subtract_block<'a>(
    out: &mut [f64],
    starts: impl Fn(usize) -> usize,
    hi: impl Fn(usize) -> &'a [f64],
    u: &[f64],
    (di, dj, de): (usize, usize, usize),
    diagonal: bool,
) {
    match (di, dj, de) {
        (9, 9, 3) => subtract_fixed::<9, 9, 3>(out, starts, hi, u, diagonal),
        (6, 6, 3) => subtract_fixed::<6, 6, 3>(out, starts, hi, u, diagonal),
        _ => {
            for c in 0..dj {
                let start = starts(c);
                let rows = if diagonal { c + 1 } else { di };
                let o = &mut out[start..start + rows];
                for k in 0..de {
                    let uv = u[k + c * de];
                    for (ov, hv) in o.iter_mut().zip(&hi(k)[..rows]) {
                        *ov -= hv * uv;
                    }
                }
            }
        }
    }
}

/// [`subtract_block`] for fixed sizes, each column formed in registers first.
#[inline(always)]
fn subtract_fixed<'a, const DI: usize, const DJ: usize, const DE: usize>(
    out: &mut [f64],
    starts: impl Fn(usize) -> usize,
    hi: impl Fn(usize) -> &'a [f64],
    u: &[f64],
    diagonal: bool,
) {
    let columns: [&[f64; DI]; DE] =
        std::array::from_fn(|k| hi(k)[..DI].try_into().expect("DI rows"));
    let u = &u[..DE * DJ];
    for c in 0..DJ {
        let mut acc = [0.0f64; DI];
        for k in 0..DE {
            let uv = u[k + c * DE];
            for (a, hv) in acc.iter_mut().zip(columns[k]) {
                *a += hv * uv;
            }
        }
        let start = starts(c);
        if diagonal {
            for (o, a) in out[start..start + c + 1].iter_mut().zip(&acc) {
                *o -= a;
            }
        } else {
            let o: &mut [f64; DI] = (&mut out[start..start + DI]).try_into().expect("DI rows");
            for (o, a) in o.iter_mut().zip(&acc) {
                *o -= a;
            }
        }
    }
}

/// A pivot at most this fraction of its column's diagonal marks the matrix as numerically
/// singular.
const PIVOT_FLOOR: f64 = 1e-13;

/// Blocks up to this size keep their diagonal on the stack during [`invert_spd`].
const STACK_DIAGONAL: usize = 16;

/// Inverts a symmetric positive definite `d × d` matrix in place by Gauss-Jordan elimination
/// (no pivoting is needed for such matrices: every pivot is a Schur complement's diagonal).
/// On a pivot that is not clearly positive returns its index.
///
/// Pivot k is tested against a_kk, its own diagonal, not against the largest: the test is then
/// the same for D A D with any positive diagonal D (Jacobi scaling), so an unknown whose
/// entries are small beside the others' (a camera's focal length, 0.1 against 10¹² for its
/// rotation) is not taken for a singular one (NOTES 74).
pub(crate) fn invert_spd(a: &mut [f64], d: usize) -> Result<(), usize> {
    // the original diagonal, on the stack for the common sizes (cameras, points, poses)
    let mut stack = [0.0f64; STACK_DIAGONAL];
    let mut heap = Vec::new();
    let diagonal = if d <= STACK_DIAGONAL {
        &mut stack[..d]
    } else {
        heap.resize(d, 0.0);
        &mut heap[..]
    };
    for (i, v) in diagonal.iter_mut().enumerate() {
        *v = a[i + i * d];
    }
    for k in 0..d {
        let pivot = a[k + k * d];
        if pivot.is_nan() || pivot <= PIVOT_FLOOR * diagonal[k] || !pivot.is_finite() {
            return Err(k);
        }
        let inv = 1.0 / pivot;
        a[k + k * d] = 1.0;
        for j in 0..d {
            a[k + j * d] *= inv;
        }
        for i in 0..d {
            if i == k {
                continue;
            }
            let f = a[i + k * d];
            if f == 0.0 {
                continue;
            }
            a[i + k * d] = 0.0;
            for j in 0..d {
                a[i + j * d] -= f * a[k + j * d];
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gauss_jordan_inverts_a_positive_definite_matrix() {
        let m = [4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 2.0];
        let mut inv = m;
        invert_spd(&mut inv, 3).unwrap();
        for r in 0..3 {
            for c in 0..3 {
                let v: f64 = (0..3).map(|k| m[r + k * 3] * inv[k + c * 3]).sum();
                assert!((v - if r == c { 1.0 } else { 0.0 }).abs() < 1e-14);
            }
        }
        let mut singular = [1.0, 1.0, 1.0, 1.0];
        assert_eq!(invert_spd(&mut singular, 2), Err(1));
        let mut negative = [1.0, 0.0, 0.0, -1e-20];
        assert_eq!(invert_spd(&mut negative, 2), Err(1));
    }

    /// The inverse of D M D is D⁻¹ M⁻¹ D⁻¹ for scales 10⁻⁶…10⁶ (a camera's focal length beside
    /// its rotation), and a matrix singular up to rounding stays refused at any scale.
    #[test]
    fn gauss_jordan_treats_scaled_unknowns_alike() {
        let m = [4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 2.0];
        let mut m_inv = m;
        invert_spd(&mut m_inv, 3).unwrap();
        let d = [1e6, 1e-6, 3.0];
        let mut scaled: Vec<f64> = (0..9).map(|i| d[i % 3] * m[i] * d[i / 3]).collect();
        invert_spd(&mut scaled, 3).unwrap();
        for i in 0..9 {
            let expected = m_inv[i] / (d[i % 3] * d[i / 3]);
            assert!(
                (scaled[i] - expected).abs() <= 1e-12 * expected.abs(),
                "{i}"
            );
        }
        // rank 1: [1, 2]ᵀ[1, 2] scaled by diag(1e6, 1e-6)
        let v = [1e6, 2e-6];
        let mut singular = [v[0] * v[0], v[1] * v[0], v[0] * v[1], v[1] * v[1]];
        assert_eq!(invert_spd(&mut singular, 2), Err(1));
    }
}
