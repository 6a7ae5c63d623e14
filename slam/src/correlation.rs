//! Pearson's correlation coefficient from running sums, for checks that accumulate them in one
//! pass (the rigid tracker's texture test, the non-rigid colour check).
//!
//! ```text
//! ρ = Σ(l − l̄)(m − m̄) / √(Σ(l − l̄)² Σ(m − m̄)²)
//! ```

/// ρ from the sums `[n, Σl, Σm, Σl², Σm², Σlm]`, clamped to [−1, 1]; 0 with fewer than two
/// samples or when either side is constant (no contrast to correlate).
pub fn pearson([n, sl, sm, sll, smm, slm]: [f64; 6]) -> f64 {
    if n < 2.0 {
        return 0.0;
    }
    let cov = slm - sl * sm / n;
    let (vl, vm) = (sll - sl * sl / n, smm - sm * sm / n);
    if vl <= 0.0 || vm <= 0.0 {
        return 0.0;
    }
    (cov / (vl * vm).sqrt()).clamp(-1.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sums(pairs: &[(f64, f64)]) -> [f64; 6] {
        pairs.iter().fold([0.0; 6], |s, &(l, m)| {
            [
                s[0] + 1.0,
                s[1] + l,
                s[2] + m,
                s[3] + l * l,
                s[4] + m * m,
                s[5] + l * m,
            ]
        })
    }

    #[test]
    fn an_affine_copy_correlates_fully_and_a_constant_not_at_all() {
        let l: Vec<f64> = (0..50).map(|i| ((i * 37) % 11) as f64).collect();
        let copy: Vec<(f64, f64)> = l.iter().map(|&x| (x, 3.0 - 2.0 * x)).collect();
        assert!((pearson(sums(&copy)) + 1.0).abs() < 1e-12);
        let shifted: Vec<(f64, f64)> = l.iter().map(|&x| (x, 0.5 * x + 7.0)).collect();
        assert!((pearson(sums(&shifted)) - 1.0).abs() < 1e-12);
        let flat: Vec<(f64, f64)> = l.iter().map(|&x| (x, 4.0)).collect();
        assert_eq!(pearson(sums(&flat)), 0.0);
        assert_eq!(pearson(sums(&[(1.0, 2.0)])), 0.0);
    }

    #[test]
    fn the_sums_give_the_two_pass_coefficient() {
        let pairs: Vec<(f64, f64)> = (0..40)
            .map(|i| {
                let x = i as f64;
                (x.sin(), (1.3 * x).sin() + 0.5 * x.sin())
            })
            .collect();
        let n = pairs.len() as f64;
        let (ml, mm) = (
            pairs.iter().map(|p| p.0).sum::<f64>() / n,
            pairs.iter().map(|p| p.1).sum::<f64>() / n,
        );
        let cov: f64 = pairs.iter().map(|p| (p.0 - ml) * (p.1 - mm)).sum();
        let vl: f64 = pairs.iter().map(|p| (p.0 - ml).powi(2)).sum();
        let vm: f64 = pairs.iter().map(|p| (p.1 - mm).powi(2)).sum();
        assert!((pearson(sums(&pairs)) - cov / (vl * vm).sqrt()).abs() < 1e-12);
    }
}
