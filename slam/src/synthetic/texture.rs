//! Procedural solid textures: colour as a smooth random function of the 3D point on the surface
//! (a sum of plane waves squashed by tanh), so every surface has intensity gradients at several
//! scales and the colour of a material point is the same from every view.

use nalgebra::{Point3, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use wide::f64x4;

/// Four waves of one channel as lanes: wave vectors' x, y, z and phases (a lane with a zero wave
/// and zero phase adds sin 0 = 0).
type Lanes = [f64x4; 4];

/// A plane wave: wave vector (radians per metre), phase and the channel it colours.
type Wave = (Vector3<f64>, f64, usize);

/// A solid texture: per channel c, `0.5 + 0.5 tanh(½ (S_c + 0.3 Σ_{c'≠c} S_c'))` with S_c the sum of
/// channel c's waves `sin(w_k · p + φ_k)`, mixed with a base colour.
#[derive(Clone, Debug)]
pub struct Texture {
    base: [f64; 3],
    contrast: f64,
    /// The waves of each channel, four at a time, for [`Self::color`].
    lanes: [Vec<Lanes>; 3],
}

impl Texture {
    /// A random texture from `seed`, with wave numbers between `min_k` and `max_k` (radians per metre).
    pub fn random(seed: u64, min_k: f64, max_k: f64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let waves: Vec<Wave> = (0..12)
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
        Self::new(&waves, base, 0.6)
    }

    /// One flat colour everywhere: a surface without texture, where the photometric term sees no
    /// gradient.
    pub fn plain(color: [f64; 3]) -> Self {
        Self::new(&[], color, 0.0)
    }

    /// The texture of `waves` (wave vector, phase, channel), with base colour and contrast.
    fn new(waves: &[Wave], base: [f64; 3], contrast: f64) -> Self {
        let lanes = [0, 1, 2].map(|c| {
            let of_c: Vec<&Wave> = waves.iter().filter(|w| w.2 == c).collect();
            (of_c.chunks(4))
                .map(|four| {
                    let mut lane = [[0.0; 4]; 4];
                    for (j, (w, phase, _)) in four.iter().enumerate() {
                        [lane[0][j], lane[1][j], lane[2][j], lane[3][j]] = [w.x, w.y, w.z, *phase];
                    }
                    lane.map(f64x4::from)
                })
                .collect()
        });
        Self {
            base,
            contrast,
            lanes,
        }
    }

    /// Colour in [0, 1]³ at a point of the surface (in the object's own frame). With S_c the sum of
    /// channel c's waves, channel c's sum is S_c + 0.3 (S_c' + S_c''): every wave touches every
    /// channel a little, for grey-level contrast. Four waves at a time (`wide`'s sin and tanh,
    /// within a few ulp of the standard library's).
    pub fn color(&self, p: &Point3<f64>) -> [f64; 3] {
        let (x, y, z) = (f64x4::splat(p.x), f64x4::splat(p.y), f64x4::splat(p.z));
        // a loop, not an array `map`: LLVM left `map`'s closure out of line in some builds
        let mut s = [0.0; 3];
        for (sum, lanes) in s.iter_mut().zip(&self.lanes) {
            let mut acc = f64x4::ZERO;
            for [wx, wy, wz, phase] in lanes {
                acc += (*wx * x + *wy * y + *wz * z + *phase).sin_cos().0;
            }
            *sum = acc.reduce_add();
        }
        let f = [0, 1, 2].map(|k| s[k] + 0.3 * (s[(k + 1) % 3] + s[(k + 2) % 3]));
        let t = (f64x4::from([f[0], f[1], f[2], 0.0]) * f64x4::splat(0.5))
            .tanh()
            .to_array();
        let mut out = [0.0; 3];
        for k in 0..3 {
            let t = 0.5 + 0.5 * t[k];
            out[k] = (self.base[k] * (1.0 - self.contrast) + t * self.contrast).clamp(0.0, 1.0);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The formula of [`Texture::color`] one wave at a time with the standard library's sin and
    /// tanh.
    fn scalar(waves: &[Wave], tex: &Texture, p: &Point3<f64>) -> [f64; 3] {
        let mut f = [0.0; 3];
        for (w, phase, c) in waves {
            let s = (w.dot(&p.coords) + phase).sin();
            for (k, v) in f.iter_mut().enumerate() {
                *v += if k == *c { s } else { 0.3 * s };
            }
        }
        [0, 1, 2].map(|k| {
            let t = 0.5 + 0.5 * (0.5 * f[k]).tanh();
            (tex.base[k] * (1.0 - tex.contrast) + t * tex.contrast).clamp(0.0, 1.0)
        })
    }

    #[test]
    fn the_colour_four_waves_at_a_time_is_the_scalar_formula() {
        // 14 waves: channels with 5, 5 and 4, so that one lane of four is padded
        let waves: Vec<_> = (0..14)
            .map(|i| {
                let a = i as f64;
                let dir = Vector3::new(a.sin(), (1.3 * a).cos(), 0.5).normalize();
                (dir * (2.0 + 3.0 * a), 0.7 * a, i % 3)
            })
            .collect();
        let tex = Texture::new(&waves, [0.3, 0.5, 0.7], 0.6);
        let mut worst = 0.0f64;
        for i in 0..2000 {
            let a = i as f64;
            let p = Point3::new((a * 0.37).sin() * 3.0, (a * 0.11).cos() * 2.5, a * 1e-3);
            for (x, y) in tex.color(&p).iter().zip(scalar(&waves, &tex, &p)) {
                worst = worst.max((x - y).abs());
            }
        }
        assert!(worst < 1e-13, "{worst}");
        let plain = Texture::plain([0.2, 0.4, 0.6]);
        assert_eq!(plain.color(&Point3::new(1.0, 2.0, 3.0)), [0.2, 0.4, 0.6]);
    }
}
