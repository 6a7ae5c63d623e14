//! SO(2), the rotations of the plane, stored as an angle.

use std::f64::consts::PI;

/// Wraps an angle into (-π, π].
#[inline]
pub fn wrap(theta: f64) -> f64 {
    let mut t = theta.rem_euclid(2.0 * PI);
    if t > PI {
        t -= 2.0 * PI;
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    proptest! {
        #[test]
        fn wrap_is_in_range_and_preserves_the_rotation(t in -100.0f64..100.0) {
            let w = wrap(t);
            prop_assert!(w > -PI - 1e-12 && w <= PI + 1e-12);
            prop_assert!((w.sin() - t.sin()).abs() < 1e-9 && (w.cos() - t.cos()).abs() < 1e-9);
        }
    }
}
