//! The integration tests as one test binary, one module per former test file: each test binary
//! is linked on its own, so one binary instead of twelve saves CI minutes (NOTES 51, 61).
//! `cargo test --release --test integration rigid::` runs one module's tests.
//!
//! Kept apart: `fuzz_corpus` (it includes the fuzz targets' modules) and the feature-gated
//! `real_data`. The tests that run the applications' binaries are dynamap-apps' (`apps/tests/`).

mod bounds_covariance;
mod bundle_adjustment;
mod chi2_agreement;
mod colour_timing;
mod exposure;
mod fragments;
mod g2o_files;
mod kinect;
mod large_pose_graphs;
mod loops;
mod nonrigid;
mod recorded;
mod relocalise;
mod rigid;
mod robust;
mod sensor;
mod sensor_frame;
mod solver;
mod structure;
mod submaps;
mod tsdf;
