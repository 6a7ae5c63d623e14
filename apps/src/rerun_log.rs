//! `--rerun FILE.rrd` / `--rerun-connect [URL]`: a run logged for the Rerun viewer
//! (<https://rerun.io>), when built with `--features rerun`. Without the feature the flags exist
//! but asking for a recording fails with a message saying how to build it.
//!
//! Entities (the world frame is the sequence's; cameras are camera-to-world poses):
//! `world/camera` (pose and pinhole), `world/camera/rgb`, `world/camera/depth`, `model_view`
//! (the model raycast from the tracked pose), `world/trajectory/{estimate,ground_truth}`,
//! `world/mesh`, `world/graph/{nodes,edges}`, `world/live_mesh`, `tracking/*` and `solver/*`
//! scalars. Time lines: `frame` and `iteration`.

use anyhow::Result;
use dynamap_slam::camera::Camera;
use dynamap_slam::image::{ColorImage, Image};
use dynamap_slam::mesh::Mesh;
use nalgebra::{Isometry3, Point3};
use std::path::PathBuf;

/// The flags that ask for a recording.
#[derive(clap::Args, Debug, Clone)]
pub struct RerunFlags {
    /// Log the run to this Rerun recording (.rrd; needs a build with --features rerun).
    #[arg(long, value_name = "FILE.rrd")]
    pub rerun: Option<PathBuf>,
    /// Stream the run to a Rerun viewer (default rerun+http://127.0.0.1:9876/proxy; needs a build
    /// with --features rerun).
    #[arg(long, value_name = "URL", num_args = 0..=1,
          default_missing_value = "rerun+http://127.0.0.1:9876/proxy")]
    pub rerun_connect: Option<String>,
}

/// A recording, or nothing when none was asked for (every call then does nothing).
pub struct Recorder {
    #[cfg(feature = "rerun")]
    stream: Option<rerun::RecordingStream>,
}

impl Recorder {
    /// Opens the recording the flags ask for; fails (bad input) when one is asked for in a build
    /// without the `rerun` feature.
    pub fn open(flags: &RerunFlags, application: &'static str) -> Result<Self> {
        let wanted = flags.rerun.is_some() || flags.rerun_connect.is_some();
        #[cfg(feature = "rerun")]
        {
            let builder = || rerun::RecordingStreamBuilder::new(application);
            let stream = match (&flags.rerun, &flags.rerun_connect) {
                (Some(path), _) => Some(builder().save(path).map_err(|e| {
                    anyhow::anyhow!("cannot open the recording {}: {e}", path.display())
                })?),
                (None, Some(url)) => Some(
                    builder()
                        .connect_grpc_opts(url.clone())
                        .map_err(|e| anyhow::anyhow!("cannot connect to {url}: {e}"))?,
                ),
                (None, None) => None,
            };
            let _ = wanted;
            Ok(Self { stream })
        }
        #[cfg(not(feature = "rerun"))]
        {
            let _ = application;
            if wanted {
                return Err(crate::cli::bad_input(
                    "--rerun needs a build with the rerun feature: cargo run --release --features rerun --example ...",
                ));
            }
            Ok(Self {})
        }
    }

    /// Whether anything is recorded.
    pub fn enabled(&self) -> bool {
        #[cfg(feature = "rerun")]
        return self.stream.is_some();
        #[cfg(not(feature = "rerun"))]
        false
    }
}

#[cfg(feature = "rerun")]
mod enabled {
    use super::*;
    use anyhow::Context;

    fn position(p: &Isometry3<f64>) -> [f32; 3] {
        let t = p.translation.vector;
        [t.x as f32, t.y as f32, t.z as f32]
    }

    fn transform(p: &Isometry3<f64>) -> rerun::Transform3D {
        let q = p.rotation.coords.cast::<f32>(); // (i, j, k, w)
        rerun::Transform3D::from_translation_rotation(
            position(p),
            rerun::Quaternion::from_xyzw([q[0], q[1], q[2], q[3]]),
        )
    }

    impl Recorder {
        fn with(
            &self,
            f: impl FnOnce(&rerun::RecordingStream) -> rerun::RecordingStreamResult<()>,
        ) -> Result<()> {
            match &self.stream {
                Some(s) => f(s).context("writing the Rerun recording"),
                None => Ok(()),
            }
        }

        /// Sets the time of what follows on `timeline` (frame or iteration number).
        pub fn at(&self, timeline: &'static str, step: usize) {
            if let Some(s) = &self.stream {
                s.set_time_sequence(timeline, step as i64);
            }
        }

        /// The camera at `entity`: its camera-to-world pose and its pinhole model.
        pub fn camera(&self, entity: &str, camera: &Camera, pose: &Isometry3<f64>) -> Result<()> {
            self.with(|s| {
                s.log(entity, &transform(pose))?;
                let (fx, fy) = (camera.fx as f32, camera.fy as f32);
                let (cx, cy) = (camera.cx as f32, camera.cy as f32);
                // K by columns
                let k = [[fx, 0.0, 0.0], [0.0, fy, 0.0], [cx, cy, 1.0]];
                s.log(
                    entity,
                    &rerun::Pinhole::new(k)
                        .with_resolution([camera.width as f32, camera.height as f32]),
                )
            })
        }

        /// An RGB image.
        pub fn color(&self, entity: &str, img: &ColorImage) -> Result<()> {
            self.with(|s| {
                let bytes: Vec<u8> = img.data.iter().flatten().copied().collect();
                s.log(
                    entity,
                    &rerun::Image::from_rgb24(bytes, [img.width as u32, img.height as u32]),
                )
            })
        }

        /// A raw 16-bit depth image with `units_per_metre`.
        pub fn depth(&self, entity: &str, img: &Image<u16>, units_per_metre: f64) -> Result<()> {
            self.with(|s| {
                let bytes: Vec<u8> = img.data.iter().flat_map(|d| d.to_le_bytes()).collect();
                s.log(
                    entity,
                    &rerun::DepthImage::from_gray16(bytes, [img.width as u32, img.height as u32])
                        .with_meter(units_per_metre as f32),
                )
            })
        }

        /// A path through the positions of `poses`.
        pub fn path(&self, entity: &str, poses: &[Isometry3<f64>], rgb: [u8; 3]) -> Result<()> {
            self.with(|s| {
                let strip: Vec<[f32; 3]> = poses.iter().map(position).collect();
                s.log(
                    entity,
                    &rerun::LineStrips3D::new([strip])
                        .with_colors([rerun::Color::from_rgb(rgb[0], rgb[1], rgb[2])]),
                )
            })
        }

        /// One value of a plotted series.
        pub fn scalar(&self, entity: &str, value: f64) -> Result<()> {
            self.with(|s| s.log(entity, &rerun::Scalars::single(value)))
        }

        /// A triangle mesh with its normals and colours.
        pub fn mesh(&self, entity: &str, mesh: &Mesh) -> Result<()> {
            self.with(|s| {
                let positions: Vec<[f32; 3]> =
                    mesh.vertices.iter().map(|v| [v.x, v.y, v.z]).collect();
                let mut m = rerun::Mesh3D::new(positions)
                    .with_triangle_indices(mesh.faces.iter().map(|f| [f[0], f[1], f[2]]));
                if mesh.normals.len() == mesh.vertices.len() {
                    m = m.with_vertex_normals(mesh.normals.iter().map(|n| [n.x, n.y, n.z]));
                }
                if mesh.colors.len() == mesh.vertices.len() {
                    m = m.with_vertex_colors(
                        mesh.colors
                            .iter()
                            .map(|c| rerun::Color::from_rgb(c[0], c[1], c[2])),
                    );
                }
                s.log(entity, &m)
            })
        }

        /// Points and the segments between pairs of them (a graph).
        pub fn graph(
            &self,
            entity: &str,
            nodes: &[Point3<f64>],
            edges: &[(usize, usize)],
        ) -> Result<()> {
            self.with(|s| {
                let p = |v: &Point3<f64>| [v.x as f32, v.y as f32, v.z as f32];
                s.log(
                    format!("{entity}/nodes"),
                    &rerun::Points3D::new(nodes.iter().map(p)),
                )?;
                let segments = edges.iter().map(|&(a, b)| [p(&nodes[a]), p(&nodes[b])]);
                s.log(
                    format!("{entity}/edges"),
                    &rerun::LineStrips3D::new(segments),
                )
            })
        }

        /// Writes out what is buffered.
        pub fn flush(&self) -> Result<()> {
            match &self.stream {
                Some(s) => s.flush_blocking().context("flushing the Rerun recording"),
                None => Ok(()),
            }
        }
    }
}

#[cfg(not(feature = "rerun"))]
mod disabled {
    use super::*;

    impl Recorder {
        /// Sets the time of what follows (no recording in this build).
        pub fn at(&self, _: &'static str, _: usize) {}
        /// Logs a camera (no recording in this build).
        pub fn camera(&self, _: &str, _: &Camera, _: &Isometry3<f64>) -> Result<()> {
            Ok(())
        }
        /// Logs an RGB image (no recording in this build).
        pub fn color(&self, _: &str, _: &ColorImage) -> Result<()> {
            Ok(())
        }
        /// Logs a depth image (no recording in this build).
        pub fn depth(&self, _: &str, _: &Image<u16>, _: f64) -> Result<()> {
            Ok(())
        }
        /// Logs a path (no recording in this build).
        pub fn path(&self, _: &str, _: &[Isometry3<f64>], _: [u8; 3]) -> Result<()> {
            Ok(())
        }
        /// Logs a scalar (no recording in this build).
        pub fn scalar(&self, _: &str, _: f64) -> Result<()> {
            Ok(())
        }
        /// Logs a mesh (no recording in this build).
        pub fn mesh(&self, _: &str, _: &Mesh) -> Result<()> {
            Ok(())
        }
        /// Logs a graph (no recording in this build).
        pub fn graph(&self, _: &str, _: &[Point3<f64>], _: &[(usize, usize)]) -> Result<()> {
            Ok(())
        }
        /// Flushes (no recording in this build).
        pub fn flush(&self) -> Result<()> {
            Ok(())
        }
    }
}
