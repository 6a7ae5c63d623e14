//! The integration tests as one test binary, one module per former test file. Each test binary
//! is linked with the release profile's thin LTO over every dependency, about 30 s of CPU
//! apiece on this machine, so one binary instead of twelve saves CI several minutes (NOTES 51).
//! `cargo test --release --test integration rigid::` runs one module's tests.
//!
//! Kept apart: `fuzz_corpus` (it includes the fuzz targets' modules, which name `crate::cli`),
//! and the feature-gated `real_data` and `rerun_recording`.

#[path = "../common/mod.rs"]
mod common;

mod bounds_covariance;
mod bundle_adjustment;
mod chi2_agreement;
mod cli;
mod exposure;
mod faults;
mod g2o_files;
mod kinect;
mod loops;
mod nonrigid;
mod relocalise;
mod rigid;
mod robust;
mod sensor;
mod solver;
mod submaps;
mod tsdf;
