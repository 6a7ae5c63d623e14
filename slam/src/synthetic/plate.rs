//! The thesis' registration experiment (sec. 4.5, Table 4.1): a flat grid of 21 × 13 vertices
//! (273 vertices, 480 triangles), 5 cm apart, and five known deformations of it. Registering the
//! flat grid onto each deformed copy and comparing every vertex with its deformed position scores a
//! non-rigid registration.

use super::deform::grid;
use crate::mesh::Mesh;
use crate::nonrigid::{clean_surface_settings, GraphParams, RegisterParams};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

/// Vertices along x.
pub const COLUMNS: usize = 21;
/// Vertices along y.
pub const ROWS: usize = 13;
/// Distance between neighbouring vertices, metres.
pub const SPACING: f64 = 0.05;

/// The flat source grid, centred on the origin in the plane z = 0, normals +z.
pub fn flat_grid() -> Mesh {
    let mut m = Mesh::default();
    for j in 0..ROWS {
        for i in 0..COLUMNS {
            m.vertices.push(Point3::new(
                ((i as f64 - (COLUMNS - 1) as f64 / 2.0) * SPACING) as f32,
                ((j as f64 - (ROWS - 1) as f64 / 2.0) * SPACING) as f32,
                0.0,
            ));
        }
    }
    grid(&mut m, COLUMNS - 1, ROWS - 1);
    m.compute_normals();
    m
}

/// The five target deformations.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlateDeformation {
    /// Rolled about an axis parallel to y with curvature 1.5 /m (no stretch).
    Bend,
    /// Turned about x by 0.8 rad per metre of x.
    Twist,
    /// A sinusoid along x: amplitude 5 cm, wavelength 0.5 m.
    Wave,
    /// A Gaussian bump of 10 cm height, σ = 10 cm, off centre.
    Bump,
    /// The bend followed by a rigid motion: 20° about (1, 2, 3), then (10, −5, 15) cm.
    BendAndRigid,
}

impl PlateDeformation {
    /// All five, in the thesis' order.
    pub const ALL: [PlateDeformation; 5] = [
        Self::Bend,
        Self::Twist,
        Self::Wave,
        Self::Bump,
        Self::BendAndRigid,
    ];

    /// Short name.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Bend => "bend",
            Self::Twist => "twist",
            Self::Wave => "wave",
            Self::Bump => "bump",
            Self::BendAndRigid => "bend+rigid",
        }
    }

    /// Where a point of the flat grid goes.
    pub fn apply(&self, p: &Point3<f64>) -> Point3<f64> {
        let (x, y) = (p.x, p.y);
        match self {
            Self::Bend => {
                let k = 1.5;
                Point3::new((k * x).sin() / k, y, (1.0 - (k * x).cos()) / k)
            }
            Self::Twist => {
                let a = 0.8 * x;
                Point3::new(x, y * a.cos(), y * a.sin())
            }
            Self::Wave => Point3::new(x, y, 0.05 * (std::f64::consts::TAU * x / 0.5).sin()),
            Self::Bump => {
                let d2 = (x - 0.2).powi(2) + (y - 0.1).powi(2);
                Point3::new(x, y, 0.1 * (-d2 / (2.0 * 0.1 * 0.1)).exp())
            }
            Self::BendAndRigid => {
                let t = Isometry3::from_parts(
                    Translation3::new(0.10, -0.05, 0.15),
                    UnitQuaternion::from_axis_angle(
                        &nalgebra::Unit::new_normalize(Vector3::new(1.0, 2.0, 3.0)),
                        20f64.to_radians(),
                    ),
                );
                t * Self::Bend.apply(p)
            }
        }
    }

    /// The deformed copy of `mesh` (same vertex order and faces, normals recomputed).
    pub fn deformed(&self, mesh: &Mesh) -> Mesh {
        let mut m = mesh.clone();
        for v in &mut m.vertices {
            *v = self.apply(&v.cast::<f64>()).cast::<f32>();
        }
        m.compute_normals();
        m
    }
}

/// The registration settings of the experiment: [`clean_surface_settings`] in metres (gate 10 cm,
/// Tukey's c 5 cm) with a node about every vertex spacing, and run to convergence as the thesis
/// did: eight stages (λ down to 1e-5) of six matchings with six steps each. The defaults' six
/// stages of eight single steps leave the wave at 1.6e-3 m instead of 2.2e-4.
pub fn registration_settings() -> (GraphParams, RegisterParams) {
    let (mut graph, mut params) = clean_surface_settings(1.0);
    graph.spacing = SPACING;
    params.max_distance = 0.1;
    params.tukey = 0.05;
    params.schedule = vec![100.0, 10.0, 1.0, 0.1, 1e-2, 1e-3, 1e-4, 1e-5];
    params.rounds = 6;
    params.iterations = 6;
    (graph, params)
}
