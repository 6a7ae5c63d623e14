//! Plain rectangular sheets and the deformations of issue 26: isometric bends (an S, a roll, a
//! fold), a twist and a saddle, each alone or followed by a rigid motion, at any size. A sheet
//! has no texture and no given correspondences, so registering the flat sheet onto a deformed
//! copy tests what a method finds by itself; the copy keeps the vertex order, so every vertex can
//! be scored against where it went.

use super::deform::grid;
use crate::mesh::Mesh;
use nalgebra::{Isometry3, Point3, Translation3, Unit, UnitQuaternion, Vector3};
use std::f64::consts::PI;

/// A flat sheet: `columns × rows` vertices, `width` long along x, 0.6 × `width` along y (the
/// thesis' plate's 20 : 12), centred on the origin in the plane z = 0, normals +z.
pub fn flat_sheet(columns: usize, rows: usize, width: f64) -> Mesh {
    let (columns, rows) = (columns.max(2), rows.max(2));
    let height = 0.6 * width;
    let mut m = Mesh::default();
    for j in 0..rows {
        for i in 0..columns {
            let x = (i as f64 / (columns - 1) as f64 - 0.5) * width;
            let y = (j as f64 / (rows - 1) as f64 - 0.5) * height;
            m.vertices.push(Point3::new(x as f32, y as f32, 0.0));
        }
    }
    grid(&mut m, columns - 1, rows - 1);
    m.compute_normals();
    m
}

/// `sheet` (a [`flat_sheet`] of `columns × rows`) with each inner vertex moved in the plane by up
/// to `share` of the grid's spacing, each way, at random (seeded): a mesh of the same sheet with
/// no vertex where another mesh of it has one. The rim stays straight.
pub fn jittered(mut sheet: Mesh, columns: usize, rows: usize, share: f64, seed: u64) -> Mesh {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let (columns, rows) = (columns.max(2), rows.max(2));
    let (dx, dy) = (
        (sheet.vertices[1].x - sheet.vertices[0].x) as f64,
        (sheet.vertices[columns].y - sheet.vertices[0].y) as f64,
    );
    for j in 1..rows - 1 {
        for i in 1..columns - 1 {
            let v = &mut sheet.vertices[j * columns + i];
            v.x += (rng.random_range(-share..share) * dx) as f32;
            v.y += (rng.random_range(-share..share) * dy) as f32;
        }
    }
    sheet.compute_normals();
    sheet
}

/// How the sheet is deformed; lengths are fractions of the sheet's width W (its extent along x),
/// so one deformation looks the same at every size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SheetShape {
    /// An S along x (isometric): the tangent's angle from the x axis is `tilt · cos(π u / W)` at
    /// arc length u from the middle, so the sheet rises steeply in the middle and lies flat at
    /// both ends.
    SBend {
        /// The tangent's largest angle, radians.
        tilt: f64,
    },
    /// Rolled about an axis parallel to y with constant curvature (isometric), through `angle`
    /// radians end to end.
    Roll {
        /// The total angle of the roll, radians.
        angle: f64,
    },
    /// Folded (isometric) along a crease through (0.15 W, 0) turned 30° from the y axis, over a
    /// rounded crease of radius 0.03 W: the side beyond it is turned by `angle`.
    Fold {
        /// The fold's angle, radians.
        angle: f64,
    },
    /// Turned about the x axis by `angle · x / W` (end to end `angle`); stretches slightly.
    Twist {
        /// The twist between the two ends, radians.
        angle: f64,
    },
    /// z = `height` · W · ((2x / W)² − (2y / 0.6 W)²) / 2: a saddle; stretches.
    Saddle {
        /// The height of the saddle's rims as a fraction of W.
        height: f64,
    },
}

/// A deformation of a sheet of width `width`, then an optional rigid motion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SheetDeformation {
    /// The bend, twist or saddle.
    pub shape: SheetShape,
    /// The rigid motion applied afterwards (about the origin), if any.
    pub rigid: Option<Isometry3<f64>>,
}

/// A registration's errors against a [`SheetDeformation`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SheetScore {
    /// The largest distance a vertex was moved, metres.
    pub displacement: f64,
    /// The largest vertex error, as a share of `displacement`.
    pub max: f64,
    /// The mean vertex error, as a share of `displacement`.
    pub mean: f64,
}

/// The rigid motion of the cases: `degrees` about the axis (1, 2, 3), then `shift` metres along
/// (2, −1, 2)/3.
pub fn case_motion(degrees: f64, shift: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::from(Vector3::new(2.0, -1.0, 2.0) * (shift / 3.0)),
        UnitQuaternion::from_axis_angle(
            &Unit::new_normalize(Vector3::new(1.0, 2.0, 3.0)),
            degrees.to_radians(),
        ),
    )
}

impl SheetShape {
    /// Short name with the amount.
    pub fn name(&self) -> String {
        match self {
            Self::SBend { tilt } => format!("s-bend {:.0}°", tilt.to_degrees()),
            Self::Roll { angle } => format!("roll {:.0}°", angle.to_degrees()),
            Self::Fold { angle } => format!("fold {:.0}°", angle.to_degrees()),
            Self::Twist { angle } => format!("twist {angle:.1}"),
            Self::Saddle { height } => format!("saddle {height:.2}"),
        }
    }

    /// Where the point (x, y, 0) of a sheet of width `w` goes.
    pub fn apply(&self, p: &Point3<f64>, w: f64) -> Point3<f64> {
        let (x, y) = (p.x, p.y);
        match *self {
            Self::SBend { tilt } => {
                let (px, pz) = s_curve(x, tilt, w);
                Point3::new(px, y, pz)
            }
            Self::Roll { angle } => {
                if angle.abs() < 1e-12 {
                    return Point3::new(x, y, 0.0);
                }
                let k = angle / w;
                Point3::new((k * x).sin() / k, y, (1.0 - (k * x).cos()) / k)
            }
            Self::Fold { angle } => fold(x, y, angle, w),
            Self::Twist { angle } => {
                let a = angle * x / w;
                Point3::new(x, y * a.cos(), y * a.sin())
            }
            Self::Saddle { height } => {
                let (u, v) = (2.0 * x / w, 2.0 * y / (0.6 * w));
                Point3::new(x, y, 0.5 * height * w * (u * u - v * v))
            }
        }
    }
}

/// The S curve at arc length `u`: ∫₀ᵘ (cos θ, sin θ) with θ(s) = tilt · cos(π s / w), by
/// Simpson's rule on steps of at most w / 2000.
fn s_curve(u: f64, tilt: f64, w: f64) -> (f64, f64) {
    let steps = 2 * ((u.abs() / w * 1000.0).ceil() as usize).max(1);
    let h = u / steps as f64;
    let (mut x, mut z) = (0.0, 0.0);
    for k in 0..=steps {
        let weight = if k == 0 || k == steps {
            1.0
        } else if k % 2 == 1 {
            4.0
        } else {
            2.0
        };
        let theta = tilt * (PI * k as f64 * h / w).cos();
        x += weight * theta.cos();
        z += weight * theta.sin();
    }
    (x * h / 3.0, z * h / 3.0)
}

/// The fold of [`SheetShape::Fold`]: points beyond the crease line are carried over a cylinder
/// of radius 0.03 w and on, turned by `angle`.
fn fold(x: f64, y: f64, angle: f64, w: f64) -> Point3<f64> {
    let r = 0.03 * w;
    let turn = 30f64.to_radians();
    // across the crease, in the sheet's plane
    let n = Vector3::new(turn.cos(), -turn.sin(), 0.0);
    let p = Vector3::new(x, y, 0.0);
    let t = (p - Vector3::new(0.15 * w, 0.0, 0.0)).dot(&n);
    if t <= 0.0 {
        return Point3::from(p);
    }
    let on_line = p - n * t;
    let z = Vector3::z();
    let arc = angle.abs() * r;
    let s = angle.signum();
    let offset = if t < arc {
        let a = t / r;
        n * (r * a.sin()) + z * (s * r * (1.0 - a.cos()))
    } else {
        let a = angle.abs();
        n * (r * a.sin() + (t - arc) * a.cos())
            + z * (s * (r * (1.0 - a.cos()) + (t - arc) * a.sin()))
    };
    Point3::from(on_line + offset)
}

impl SheetDeformation {
    /// Where the point `p` of a flat sheet of width `w` goes.
    pub fn apply(&self, p: &Point3<f64>, w: f64) -> Point3<f64> {
        let q = self.shape.apply(p, w);
        self.rigid.map_or(q, |m| m * q)
    }

    /// The deformed copy of the flat `sheet` of width `w` (same vertex order and faces, normals
    /// recomputed).
    pub fn deformed(&self, sheet: &Mesh, w: f64) -> Mesh {
        let mut m = sheet.clone();
        for v in &mut m.vertices {
            *v = self.apply(&v.cast::<f64>(), w).cast::<f32>();
        }
        m.compute_normals();
        m
    }

    /// How far `warped` (the flat `sheet`'s vertices of a sheet of width `w`, registered onto
    /// this deformation of it) lies from where the deformation sends each vertex.
    pub fn score(&self, sheet: &Mesh, warped: &[Vector3<f64>], w: f64) -> SheetScore {
        let mut score = SheetScore::default();
        let mut sum = 0.0;
        let errors: Vec<f64> = sheet
            .vertices
            .iter()
            .zip(warped)
            .map(|(p, q)| {
                let p = p.cast::<f64>();
                let truth = self.apply(&p, w);
                score.displacement = score.displacement.max((truth - p).norm());
                (q - truth.coords).norm()
            })
            .collect();
        for e in &errors {
            score.max = score.max.max(*e / score.displacement);
            sum += e / score.displacement;
        }
        score.mean = sum / errors.len().max(1) as f64;
        score
    }

    /// The cases of `nonrigid_register sheets`: each shape at `amount` × its issue's largest
    /// amount (1: an S of 69°, a roll of 180°, a fold of 90°, a twist of 0.8 rad, a saddle 0.15
    /// W high), alone and followed by a rigid motion of `degrees` and `shift` metres.
    pub fn cases(amount: f64, degrees: f64, shift: f64) -> Vec<SheetDeformation> {
        let shapes = [
            SheetShape::SBend { tilt: 1.2 * amount },
            SheetShape::Roll { angle: PI * amount },
            SheetShape::Fold {
                angle: PI / 2.0 * amount,
            },
            SheetShape::Twist {
                angle: 0.8 * amount,
            },
            SheetShape::Saddle {
                height: 0.15 * amount,
            },
        ];
        let mut out = Vec::new();
        for shape in shapes {
            out.push(SheetDeformation { shape, rigid: None });
            out.push(SheetDeformation {
                shape,
                rigid: Some(case_motion(degrees, shift)),
            });
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Largest relative change of an edge's length between the flat sheet and `def` of it.
    fn stretch(def: SheetShape, w: f64) -> f64 {
        let sheet = flat_sheet(41, 25, w);
        let moved = SheetDeformation {
            shape: def,
            rigid: None,
        }
        .deformed(&sheet, w);
        let mut worst: f64 = 0.0;
        for f in &sheet.faces {
            for (a, b) in [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])] {
                let (a, b) = (a as usize, b as usize);
                let before = (sheet.vertices[a] - sheet.vertices[b]).norm() as f64;
                let after = (moved.vertices[a] - moved.vertices[b]).norm() as f64;
                worst = worst.max((after / before - 1.0).abs());
            }
        }
        worst
    }

    #[test]
    fn the_bends_keep_lengths_and_the_saddle_does_not() {
        for w in [0.1, 2.0] {
            for shape in [
                SheetShape::SBend { tilt: 1.2 },
                SheetShape::Roll { angle: PI },
                SheetShape::Fold { angle: PI / 2.0 },
            ] {
                // chords of an edge across the fold's crease (radius 0.03 w) are a little
                // shorter than the edge
                let s = stretch(shape, w);
                assert!(s < 0.02, "{} at {w} m stretches edges by {s}", shape.name());
            }
            assert!(stretch(SheetShape::Saddle { height: 0.15 }, w) > 0.02);
        }
    }

    #[test]
    fn the_s_bend_rises_in_the_middle_and_ends_level() {
        let (w, tilt) = (1.0, 1.2);
        let shape = SheetShape::SBend { tilt };
        let end = shape.apply(&Point3::new(0.5, 0.0, 0.0), w);
        let start = shape.apply(&Point3::new(-0.5, 0.0, 0.0), w);
        assert!((end.coords + start.coords).norm() < 1e-9, "point symmetric");
        assert!(end.z > 0.1 && end.x < 0.5);
        // the slope at the middle is tan(tilt)
        let h = 1e-4;
        let a = shape.apply(&Point3::new(h, 0.0, 0.0), w);
        let b = shape.apply(&Point3::new(-h, 0.0, 0.0), w);
        assert!(((a.z - b.z) / (a.x - b.x) - tilt.tan()).abs() < 1e-3);
    }

    #[test]
    fn the_fold_turns_the_far_side_by_its_angle() {
        let w = 1.0;
        let shape = SheetShape::Fold { angle: PI / 2.0 };
        // two points on the far flat part, along the crease's normal
        let turn = 30f64.to_radians();
        let n = Vector3::new(turn.cos(), -turn.sin(), 0.0);
        let p = Point3::new(0.15, 0.0, 0.0) + n * 0.2;
        let q = Point3::new(0.15, 0.0, 0.0) + n * 0.3;
        let d = shape.apply(&q, w) - shape.apply(&p, w);
        assert!((d.norm() - 0.1).abs() < 1e-9);
        assert!((d.normalize().z - 1.0).abs() < 1e-9, "{d:?}");
        // the near side stays
        let near = Point3::new(-0.3, 0.1, 0.0);
        assert_eq!(shape.apply(&near, w), near);
    }
}
