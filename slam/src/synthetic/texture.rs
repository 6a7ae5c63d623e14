//! Procedural solid textures: colour as a smooth random function of the 3D point on the surface
//! (a sum of plane waves squashed by tanh), so every surface has intensity gradients at several
//! scales and the colour of a material point is the same from every view.

use nalgebra::{Point3, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A solid texture: per channel, `0.5 + 0.5 tanh(½ Σ_k sin(w_k · p + φ_k))`, mixed with a base colour.
#[derive(Clone, Debug)]
pub struct Texture {
    waves: Vec<(Vector3<f64>, f64, usize)>,
    base: [f64; 3],
    contrast: f64,
}

impl Texture {
    /// A random texture from `seed`, with wave numbers between `min_k` and `max_k` (radians per metre).
    pub fn random(seed: u64, min_k: f64, max_k: f64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let waves = (0..12)
            .map(|i| {
                let dir = Vector3::new(
                    rng.random::<f64>() - 0.5,
                    rng.random::<f64>() - 0.5,
                    rng.random::<f64>() - 0.5,
                )
                .try_normalize(1e-9)
                .unwrap_or_else(Vector3::x);
                let k = min_k + (max_k - min_k) * rng.random::<f64>();
                (dir * k, rng.random::<f64>() * std::f64::consts::TAU, i % 3)
            })
            .collect();
        let base = [
            0.2 + 0.6 * rng.random::<f64>(),
            0.2 + 0.6 * rng.random::<f64>(),
            0.2 + 0.6 * rng.random::<f64>(),
        ];
        Self {
            waves,
            base,
            contrast: 0.6,
        }
    }

    /// One flat colour everywhere: a surface without texture, where the photometric term sees no
    /// gradient.
    pub fn plain(color: [f64; 3]) -> Self {
        Self {
            waves: Vec::new(),
            base: color,
            contrast: 0.0,
        }
    }

    /// Colour in [0, 1]³ at a point of the surface (in the object's own frame).
    pub fn color(&self, p: &Point3<f64>) -> [f64; 3] {
        let mut f = [0.0; 3];
        for (w, phase, c) in &self.waves {
            let s = (w.dot(&p.coords) + phase).sin();
            f[*c] += s;
            // every wave touches every channel a little, for grey-level contrast
            for (k, v) in f.iter_mut().enumerate() {
                if k != *c {
                    *v += 0.3 * s;
                }
            }
        }
        let mut out = [0.0; 3];
        for k in 0..3 {
            let t = 0.5 + 0.5 * (0.5 * f[k]).tanh();
            out[k] = (self.base[k] * (1.0 - self.contrast) + t * self.contrast).clamp(0.0, 1.0);
        }
        out
    }
}
