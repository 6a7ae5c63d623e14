//! Helpers shared by the integration tests.

#![allow(dead_code)] // each test uses a different part

pub mod examples;
