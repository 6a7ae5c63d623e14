//! A walk through a grid of streets (after Olson's Manhattan and city10k, 2006): one pose per
//! intersection passed, odometry between consecutive poses, and a loop closure when the walk comes
//! back to an intersection it left at least [`CityOptions::min_loop_gap`] poses before. In 3-D the
//! city has a few floors joined by stairs at every intersection.

use super::{check, walk, Noise, SyntheticError, SyntheticGraph};
use crate::pose_graph::graph::{Dimension, Pose};
use nalgebra::{Isometry2, Isometry3, Translation3, UnitQuaternion, Vector2};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::FRAC_PI_2;

/// Settings of [`city`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CityOptions {
    /// Number of poses.
    pub poses: usize,
    /// SE(2) or SE(3).
    pub dimension: Dimension,
    /// Mean number of visits per intersection: the city has `poses / visits` intersections, so it
    /// grows with the walk.
    pub visits: f64,
    /// Probability of turning left or right at an intersection.
    pub turn: f64,
    /// Floors of the 3-D city (a city grows wider, not taller).
    pub floors: usize,
    /// Probability of taking the stairs at an intersection (3-D only).
    pub stairs: f64,
    /// Probability that a return to an intersection is measured as a loop closure.
    pub loop_probability: f64,
    /// Least number of poses between the two ends of a loop closure.
    pub min_loop_gap: usize,
    /// Measurements and start.
    pub noise: Noise,
}

impl Default for CityOptions {
    fn default() -> Self {
        Self {
            poses: 10_000,
            dimension: Dimension::Two,
            visits: 4.0,
            turn: 0.3,
            floors: 3,
            stairs: 0.1,
            loop_probability: 0.5,
            min_loop_gap: 10,
            noise: Noise::default(),
        }
    }
}

/// Streets 1 m apart, floors 1 m apart; `side × side` intersections on `floors` floors.
#[derive(Clone, Copy, Debug)]
struct Grid {
    side: i64,
    floors: i64,
}

impl Grid {
    /// The smallest square grid with at least `cells` intersections over its floors (one in
    /// 2-D).
    fn for_cells(cells: f64, floors: usize) -> Self {
        let floors = floors.max(1);
        Self {
            side: ((cells / floors as f64).sqrt().ceil() as i64).max(3),
            floors: floors as i64,
        }
    }
    fn index(&self, p: [i64; 3]) -> usize {
        ((p[2] * self.side + p[1]) * self.side + p[0]) as usize
    }
    fn inside(&self, p: [i64; 3]) -> bool {
        (0..self.side).contains(&p[0])
            && (0..self.side).contains(&p[1])
            && (0..self.floors).contains(&p[2])
    }
}

/// The four headings: +x, +y, −x, −y.
const HEADINGS: [[i64; 2]; 4] = [[1, 0], [0, 1], [-1, 0], [0, -1]];

/// A city walk of `o.poses` poses.
pub fn city(o: &CityOptions) -> Result<SyntheticGraph, SyntheticError> {
    check(o.poses, 2, &o.noise)?;
    let probability = |p: f64| (0.0..=1.0).contains(&p);
    let settings_ok = probability(o.turn)
        && probability(o.stairs)
        && probability(o.loop_probability)
        && o.visits >= 1.0
        && o.visits.is_finite();
    if !settings_ok {
        return Err(SyntheticError::Setting(
            "turn, stairs and loop_probability must lie in [0, 1] and visits be at least 1",
        ));
    }
    let floors = match o.dimension {
        Dimension::Two => 1,
        Dimension::Three => o.floors,
    };
    let grid = Grid::for_cells(o.poses as f64 / o.visits, floors);
    let mut rng = ChaCha8Rng::seed_from_u64(o.noise.seed.wrapping_add(0x5717));
    let mut last_visit = vec![u32::MAX; (grid.side * grid.side * grid.floors) as usize];
    let mut at = [grid.side / 2, grid.side / 2, 0];
    let mut heading = 0usize;
    let mut truth = Vec::with_capacity(o.poses);
    let mut loops = Vec::new();
    for i in 0..o.poses {
        if i > 0 {
            (at, heading) = step(&grid, at, heading, o, &mut rng);
        }
        truth.push(pose(at, heading, o.dimension));
        let cell = grid.index(at);
        let before = last_visit[cell];
        if before != u32::MAX
            && i - before as usize >= o.min_loop_gap
            && rng.random_bool(o.loop_probability)
        {
            loops.push((before as usize, i));
        }
        last_visit[cell] = i as u32;
    }
    Ok(walk(o.dimension, "city", truth, &loops, &o.noise))
}

/// The next intersection and heading: the stairs (3-D, when a floor is there), else a turn or
/// straight on, never off the grid and back only at a dead end.
fn step(
    grid: &Grid,
    at: [i64; 3],
    heading: usize,
    o: &CityOptions,
    rng: &mut ChaCha8Rng,
) -> ([i64; 3], usize) {
    if grid.floors > 1 && rng.random_bool(o.stairs) {
        let dz = if rng.random_bool(0.5) { 1 } else { -1 };
        for dz in [dz, -dz] {
            let next = [at[0], at[1], at[2] + dz];
            if grid.inside(next) {
                return (next, heading);
            }
        }
    }
    let first = if rng.random_bool(o.turn) {
        heading + if rng.random_bool(0.5) { 1 } else { 3 }
    } else {
        heading
    };
    // the chosen way, then straight on, the two turns, and back last
    for h in [first, heading, heading + 1, heading + 3, heading + 2] {
        let h = h % 4;
        let d = HEADINGS[h];
        let next = [at[0] + d[0], at[1] + d[1], at[2]];
        if grid.inside(next) {
            return (next, h);
        }
    }
    unreachable!("a grid of side ≥ 3 has a neighbour in some direction")
}

/// The pose at an intersection facing along a heading.
fn pose(at: [i64; 3], heading: usize, dimension: Dimension) -> Pose {
    let yaw = heading as f64 * FRAC_PI_2;
    match dimension {
        Dimension::Two => Pose::Se2(Isometry2::new(
            Vector2::new(at[0] as f64, at[1] as f64),
            yaw,
        )),
        Dimension::Three => Pose::Se3(Isometry3::from_parts(
            Translation3::new(at[0] as f64, at[1] as f64, at[2] as f64),
            UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pose_graph::synthetic::Start;

    fn position(p: &Pose) -> [f64; 3] {
        match p {
            Pose::Se2(x) => [x.translation.x, x.translation.y, 0.0],
            Pose::Se3(x) => [x.translation.x, x.translation.y, x.translation.z],
        }
    }

    fn distance(a: &Pose, b: &Pose) -> f64 {
        let (a, b) = (position(a), position(b));
        (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt()
    }

    fn extent(truth: &std::collections::BTreeMap<usize, Pose>) -> f64 {
        let xs: Vec<f64> = truth.values().map(|p| position(p)[0]).collect();
        xs.iter().cloned().fold(f64::MIN, f64::max) - xs.iter().cloned().fold(f64::MAX, f64::min)
    }

    #[test]
    fn the_walk_steps_one_block_at_a_time_and_closes_loops_where_it_returns() {
        for dimension in [Dimension::Two, Dimension::Three] {
            let o = CityOptions {
                poses: 3000,
                dimension,
                ..Default::default()
            };
            let s = city(&o).unwrap();
            let n = o.poses;
            assert_eq!(s.graph.vertices.len(), n);
            for i in 1..n {
                assert!((distance(&s.truth[&(i - 1)], &s.truth[&i]) - 1.0).abs() < 1e-12);
            }
            let loops = &s.graph.edges[n - 1..];
            assert!(
                (n / 10..n / 2).contains(&loops.len()),
                "{dimension:?}: {} loops over {n} poses",
                loops.len()
            );
            for e in loops {
                assert!(e.to - e.from >= o.min_loop_gap);
                assert!(distance(&s.truth[&e.from], &s.truth[&e.to]) < 1e-12);
            }
            if dimension == Dimension::Three {
                let floors: std::collections::BTreeSet<i64> =
                    s.truth.values().map(|p| position(p)[2] as i64).collect();
                assert_eq!(floors.len(), o.floors, "every floor is walked");
            }
        }
    }

    #[test]
    fn the_city_grows_with_the_walk() {
        let size = |poses| {
            extent(
                &city(&CityOptions {
                    poses,
                    ..Default::default()
                })
                .unwrap()
                .truth,
            )
        };
        let (small, large) = (size(2_000), size(32_000));
        assert!(
            large > 2.5 * small && large < 6.0 * small,
            "16× the poses: extent {small} → {large} m"
        );
    }

    #[test]
    fn noisy_measurements_fit_the_truth_as_their_gaussian_says_and_odometry_starts_on_the_chain() {
        let o = CityOptions {
            poses: 4000,
            dimension: Dimension::Three,
            noise: Noise {
                start: Start::Odometry,
                ..Default::default()
            },
            ..Default::default()
        };
        let s = city(&o).unwrap();
        // at the truth each edge's chi2 is χ² with 6 degrees of freedom
        let dof = 6.0 * s.graph.edges.len() as f64;
        let chi2 = s.graph.chi2(&s.truth);
        assert!(
            (chi2 - dof).abs() < 5.0 * (2.0 * dof).sqrt(),
            "chi2 at the truth {chi2}, expected {dof}"
        );
        let mut chain = s.graph.clone();
        chain.edges.truncate(o.poses - 1);
        assert!(
            chain.chi2(&s.graph.vertices) < 1e-12,
            "odometry fits itself"
        );
        let exact = city(&CityOptions {
            noise: Noise {
                noisy: false,
                ..o.noise
            },
            ..o
        })
        .unwrap();
        assert!(exact.graph.chi2(&exact.truth) < 1e-18);
    }

    #[test]
    fn bad_settings_are_refused() {
        let bad = |o: CityOptions| city(&o).err();
        assert_eq!(
            bad(CityOptions {
                poses: 1,
                ..Default::default()
            }),
            Some(SyntheticError::TooSmall { poses: 1, least: 2 })
        );
        for sigma in [0.0, -1.0, f64::NAN] {
            let mut o = CityOptions::default();
            o.noise.rotation_sigma = sigma;
            assert_eq!(bad(o), Some(SyntheticError::Noise));
        }
        for turn in [-0.1, 1.5, f64::NAN] {
            let o = CityOptions {
                turn,
                ..Default::default()
            };
            assert!(matches!(bad(o), Some(SyntheticError::Setting(_))));
        }
    }
}
