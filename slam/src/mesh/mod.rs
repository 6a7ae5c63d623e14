//! Triangle meshes: what marching cubes emits, what the generator renders and what the mesh metrics
//! compare.

use nalgebra::{Point3, Vector3};

mod winding;
pub use winding::Winding;

/// An indexed triangle mesh with optional per-vertex normals and colours.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions.
    pub vertices: Vec<Point3<f32>>,
    /// Per-vertex normals (empty or one per vertex).
    pub normals: Vec<Vector3<f32>>,
    /// Per-vertex colours (empty or one per vertex).
    pub colors: Vec<[u8; 3]>,
    /// Triangles as vertex indices, counter-clockwise seen from the outside.
    pub faces: Vec<[u32; 3]>,
}

impl Mesh {
    /// Area-weighted vertex normals from the faces.
    pub fn compute_normals(&mut self) {
        let mut n = vec![Vector3::zeros(); self.vertices.len()];
        for f in &self.faces {
            let [a, b, c] = f.map(|i| self.vertices[i as usize]);
            let fn_ = (b - a).cross(&(c - a));
            for &i in f {
                n[i as usize] += fn_;
            }
        }
        self.normals = n
            .into_iter()
            .map(|v| v.try_normalize(1e-20).unwrap_or_else(Vector3::z))
            .collect();
    }

    /// Checks indices and array lengths; a message names the first fault.
    pub fn validate(&self) -> Result<(), String> {
        let nv = self.vertices.len();
        if !self.normals.is_empty() && self.normals.len() != nv {
            return Err(format!("{} normals for {nv} vertices", self.normals.len()));
        }
        if !self.colors.is_empty() && self.colors.len() != nv {
            return Err(format!("{} colours for {nv} vertices", self.colors.len()));
        }
        if let Some((k, f)) = self
            .faces
            .iter()
            .enumerate()
            .find(|(_, f)| f.iter().any(|&i| i as usize >= nv))
        {
            return Err(format!("face {k} {f:?} refers past the {nv} vertices"));
        }
        Ok(())
    }

    /// Total surface area.
    pub fn area(&self) -> f64 {
        self.faces
            .iter()
            .map(|f| {
                let [a, b, c] = f.map(|i| self.vertices[i as usize].cast::<f64>());
                0.5 * (b - a).cross(&(c - a)).norm()
            })
            .sum()
    }
}
