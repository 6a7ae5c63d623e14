//! Fuzz target: see `exercise::tum`.
#![no_main]
#[path = "../exercise/mod.rs"]
#[allow(dead_code)]
mod exercise;

libfuzzer_sys::fuzz_target!(|data: &[u8]| exercise::tum(data));
