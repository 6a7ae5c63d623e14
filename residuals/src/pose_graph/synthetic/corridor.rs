//! Passes up and down a long corridor: one pose per metre, a turn on the spot at each end, and
//! loop closures only at doors every
//! [`CorridorOptions::door_spacing`] metres, each tied to the previous pass's pose at that door. Long
//! chains held by few closures: the ill-conditioned case of a pose graph. In 3-D the corridor is a
//! ramp rising 2 %.

use super::{check, walk, Noise, SyntheticError, SyntheticGraph};
use crate::pose_graph::graph::{Dimension, Pose};
use nalgebra::{Isometry2, Isometry3, Translation3, UnitQuaternion, Vector2};
use std::f64::consts::PI;

/// Settings of [`corridor`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CorridorOptions {
    /// Number of poses.
    pub poses: usize,
    /// SE(2) or SE(3).
    pub dimension: Dimension,
    /// Length of the corridor (metres, one pose per metre): a building's, whatever the length of
    /// the walk; a longer walk makes more passes.
    pub length: usize,
    /// Metres between doors; each pass after the first closes a loop at every door to the pass
    /// before.
    pub door_spacing: usize,
    /// Measurements and start.
    pub noise: Noise,
}

impl Default for CorridorOptions {
    fn default() -> Self {
        Self {
            poses: 10_000,
            dimension: Dimension::Two,
            length: 1000,
            door_spacing: 100,
            noise: Noise::default(),
        }
    }
}

/// Rise of the 3-D ramp per metre.
const SLOPE: f64 = 0.02;

/// A corridor walk of `o.poses` poses.
pub fn corridor(o: &CorridorOptions) -> Result<SyntheticGraph, SyntheticError> {
    let spacing = o.door_spacing.max(2);
    let length = o.length.max(spacing + 1);
    // two passes at least, so that there is a loop
    check(o.poses, 2 * length, &o.noise)?;
    let passes = o.poses / length;
    let doors = length / spacing;
    let door_at: Vec<usize> = (0..doors)
        .map(|d| ((2 * d + 1) * length) / (2 * doors))
        .collect();
    let mut last_at_door = vec![usize::MAX; doors];
    let mut truth = Vec::with_capacity(o.poses);
    let mut loops = Vec::new();
    for i in 0..o.poses {
        let pass = (i / length).min(passes - 1);
        let k = (i - pass * length) as f64;
        // out on even passes, back on odd ones; a pass's first pose turns on the spot where the
        // last one ended (the last pass takes the remainder and runs on past the end)
        let back = pass % 2 == 1;
        let x = if back { (length - 1) as f64 - k } else { k };
        truth.push(pose(x, back, o.dimension));
        if let Some(d) = door_at.iter().position(|&a| a as f64 == x) {
            if last_at_door[d] != usize::MAX && i > last_at_door[d] + 1 {
                loops.push((last_at_door[d], i));
            }
            last_at_door[d] = i;
        }
    }
    Ok(walk(o.dimension, "corridor", truth, &loops, &o.noise))
}

/// The pose `x` metres along the corridor, facing out (+x) or back.
fn pose(x: f64, back: bool, dimension: Dimension) -> Pose {
    let yaw = if back { PI } else { 0.0 };
    match dimension {
        Dimension::Two => Pose::Se2(Isometry2::new(Vector2::new(x, 0.0), yaw)),
        Dimension::Three => Pose::Se3(Isometry3::from_parts(
            Translation3::new(x, 0.0, SLOPE * x),
            UnitQuaternion::from_euler_angles(0.0, -SLOPE.atan(), yaw),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn x_of(p: &Pose) -> f64 {
        match p {
            Pose::Se2(x) => x.translation.x,
            Pose::Se3(x) => x.translation.x,
        }
    }

    #[test]
    fn passes_turn_at_the_ends_and_close_loops_only_at_the_doors() {
        for dimension in [Dimension::Two, Dimension::Three] {
            let o = CorridorOptions {
                poses: 5000,
                dimension,
                length: 500,
                door_spacing: 50,
                ..Default::default()
            };
            let s = corridor(&o).unwrap();
            let passes = o.poses / o.length;
            let doors = o.length / o.door_spacing;
            let loops = &s.graph.edges[o.poses - 1..];
            assert_eq!(loops.len(), (passes - 1) * doors, "{dimension:?}");
            for e in loops {
                let (a, b) = (x_of(&s.truth[&e.from]), x_of(&s.truth[&e.to]));
                assert_eq!(a, b, "a loop joins two visits of one door");
                assert_eq!(e.to / o.length, e.from / o.length + 1, "to the pass before");
            }
            let xs: Vec<f64> = s.truth.values().map(x_of).collect();
            assert!(xs.iter().all(|&x| (0.0..o.length as f64).contains(&x)));
            // each pass covers the corridor, one metre per pose or a turn on the spot
            for w in xs.windows(2) {
                assert!((w[1] - w[0]).abs() <= 1.0);
            }
            assert_eq!(xs.iter().filter(|&&x| x == 0.0).count(), passes);
        }
    }

    #[test]
    fn a_walk_too_short_for_two_passes_is_refused() {
        let o = CorridorOptions {
            poses: 1500,
            ..Default::default()
        };
        assert_eq!(
            corridor(&o).err(),
            Some(SyntheticError::TooSmall {
                poses: 1500,
                least: 2000
            })
        );
    }
}
