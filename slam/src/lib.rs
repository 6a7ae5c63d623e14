//! # dynamap-slam
//!
//! Dense RGB-D SLAM on the dynamap solver.
