//! Fuzz target: see `exercise::config`.
#![no_main]
#[path = "../exercise/config.rs"]
mod exercise;

libfuzzer_sys::fuzz_target!(|data: &[u8]| exercise::config(data));
