//! Fuzz target: see `exercise::config`.
#![no_main]
#[path = "../../examples/common/cli.rs"]
#[allow(unused)]
mod cli;
#[path = "../exercise/config.rs"]
mod exercise;

libfuzzer_sys::fuzz_target!(|data: &[u8]| exercise::config(data));
