//! The generated deforming scene's flags, shared by `generate deforming` and `nonrigid_slam`:
//! the field that moves the surface and the surface itself
//! ([`dynamap_slam::synthetic::deform`]).

use clap::ValueEnum;
use dynamap_slam::synthetic::deform::{Field, SurfaceKind};

/// The deformation field.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum DeformMotion {
    /// Curl about an axis parallel to x.
    Bend,
    /// Rotation about y, growing along y.
    Twist,
    /// A travelling ripple.
    Wave,
}

impl From<DeformMotion> for Field {
    fn from(m: DeformMotion) -> Self {
        match m {
            DeformMotion::Bend => Field::Bend,
            DeformMotion::Twist => Field::Twist,
            DeformMotion::Wave => Field::Wave,
        }
    }
}

/// The generated surface.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum SurfaceArg {
    /// A 1 m × 1 m plate.
    Plane,
    /// An open cylinder (a tube), radius 0.25 m, height 0.8 m.
    Cylinder,
    /// A sphere of radius 0.3 m.
    Sphere,
}

impl From<SurfaceArg> for SurfaceKind {
    fn from(s: SurfaceArg) -> Self {
        match s {
            SurfaceArg::Plane => SurfaceKind::Plane,
            SurfaceArg::Cylinder => SurfaceKind::Cylinder,
            SurfaceArg::Sphere => SurfaceKind::Sphere,
        }
    }
}
