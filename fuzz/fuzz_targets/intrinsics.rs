//! Fuzz target: see `exercise::intrinsics`.
#![no_main]
#[path = "../exercise/mod.rs"]
#[allow(dead_code)]
mod exercise;

libfuzzer_sys::fuzz_target!(|data: &[u8]| exercise::intrinsics(data));
