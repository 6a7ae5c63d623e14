//! Checks of the numbers a flag may take. Each failure is bad input (exit code 2) that names the
//! flag, what it must be and the value given (`--max-distance must be a positive number, not
//! -0.1`), so that a value the pipeline would misread (a negative gate squared into a positive
//! one, a NaN weight, a voxel so small that one frame's ray march takes hours) never starts a
//! run.

use crate::cli::bad_input;
use anyhow::Result;
use std::fmt::Display;

use dynamap_slam::camera::usable_focal_length;
pub use dynamap_slam::synthetic::{MAX_FRAMES, MAX_PIXELS};
use dynamap_slam::tsdf::{usable_voxel_size, MAX_VOXEL_SIZE, MIN_VOXEL_SIZE};

/// The most iterations a flag may ask of one solve: far beyond what any converging solve takes,
/// and a bound on a run whose solves never converge.
pub const MAX_ITERATIONS: usize = 1000;

/// `--width` × `--height` of a frame to render is at most [`MAX_PIXELS`].
pub fn frame_size(width: usize, height: usize) -> Result<()> {
    if width.saturating_mul(height) <= MAX_PIXELS {
        Ok(())
    } else {
        Err(bad_input(format!(
            "--width × --height must be at most {MAX_PIXELS} pixels (4096 × 4096), not \
             {width} × {height}"
        )))
    }
}

/// The frames of a sequence to render (`flag`) are between 1 and [`MAX_FRAMES`].
pub fn frame_count(flag: &str, frames: usize) -> Result<()> {
    if (1..=MAX_FRAMES).contains(&frames) {
        Ok(())
    } else {
        Err(bad_input(format!(
            "{flag} must lie between 1 and {MAX_FRAMES}, not {frames}"
        )))
    }
}

/// `value` is a finite number above zero.
pub fn positive<T: Into<f64> + Copy + Display>(flag: &str, value: T) -> Result<()> {
    let v: f64 = value.into();
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(bad_input(format!(
            "{flag} must be a positive number, not {value}"
        )))
    }
}

/// `value` is a finite number of zero or more.
pub fn non_negative<T: Into<f64> + Copy + Display>(flag: &str, value: T) -> Result<()> {
    let v: f64 = value.into();
    if v.is_finite() && v >= 0.0 {
        Ok(())
    } else {
        Err(bad_input(format!(
            "{flag} must be a number of 0 or more, not {value}"
        )))
    }
}

/// `value` is a focal length, pixels ([`usable_focal_length`]: finite and not zero). A negative
/// one is a mirrored image axis (ICL-NUIM's fy = −480), which [`dynamap_slam::camera`] carries
/// through every formula.
pub fn focal_length(flag: &str, value: f64) -> Result<()> {
    if usable_focal_length(value) {
        Ok(())
    } else {
        Err(bad_input(format!(
            "{flag} must be a finite non-zero focal length (negative for a mirrored axis), not \
             {value}"
        )))
    }
}

/// Pinhole intrinsics given as flags, each `(flag, value)` and `None` where not given: fx and fy
/// focal lengths ([`focal_length`]), cx and cy finite.
pub fn intrinsics(given: [(&str, Option<f64>); 4]) -> Result<()> {
    for (k, (flag, value)) in given.into_iter().enumerate() {
        match value {
            Some(v) if k < 2 => focal_length(flag, v)?,
            Some(v) => finite(flag, v)?,
            None => {}
        }
    }
    Ok(())
}

/// `value` is a finite number.
pub fn finite(flag: &str, value: f64) -> Result<()> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(bad_input(format!(
            "{flag} must be a finite number, not {value}"
        )))
    }
}

/// `value` lies in `lo..=hi` (`unit` follows the bounds in the message: " degrees", " metres").
pub fn within<T: Into<f64> + Copy + Display>(
    flag: &str,
    value: T,
    (lo, hi): (f64, f64),
    unit: &str,
) -> Result<()> {
    if (lo..=hi).contains(&value.into()) {
        Ok(())
    } else {
        Err(bad_input(format!(
            "{flag} must lie between {lo} and {hi}{unit}, not {value}"
        )))
    }
}

/// A voxel edge, metres, that the volumes take ([`usable_voxel_size`]).
pub fn voxel(flag: &str, value: f32) -> Result<()> {
    if usable_voxel_size(value) {
        Ok(())
    } else {
        Err(bad_input(format!(
            "{flag} must lie between {MIN_VOXEL_SIZE} and {MAX_VOXEL_SIZE} metres, not {value}"
        )))
    }
}

/// An angle gate, degrees: above 0 and at most 180.
pub fn angle(flag: &str, value: f64) -> Result<()> {
    positive(flag, value)?;
    within(flag, value, (0.0, 180.0), " degrees")
}

/// Iteration counts, one per level or stage: none above [`MAX_ITERATIONS`], and (when
/// `some_needed`) at least one above zero.
pub fn iterations(flag: &str, counts: &[usize], some_needed: bool) -> Result<()> {
    if let Some(n) = counts.iter().find(|&&n| n > MAX_ITERATIONS) {
        return Err(bad_input(format!(
            "{flag} must be at most {MAX_ITERATIONS}, not {n}"
        )));
    }
    if some_needed && counts.iter().all(|&n| n == 0) {
        let somewhere = if counts.len() > 1 {
            " on some level"
        } else {
            ""
        };
        return Err(bad_input(format!(
            "{flag} must be at least 1{somewhere}: with none, nothing is solved"
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_check_names_the_flag_and_the_value_and_passes_the_range() {
        let message = |r: Result<()>| r.unwrap_err().to_string();
        assert!(positive("--a", 0.5).is_ok());
        for v in [0.0, -0.1, f64::NAN, f64::INFINITY] {
            let m = message(positive("--a", v));
            assert!(m.contains("--a") && m.contains(&v.to_string()), "{m}");
        }
        assert!(non_negative("--b", 0.0).is_ok());
        assert!(non_negative("--b", -1e-9).is_err());
        assert!(non_negative("--b", f64::NAN).is_err());
        assert!(within("--c", 180.0, (0.0, 180.0), " degrees").is_ok());
        let m = message(within("--c", 180.5, (0.0, 180.0), " degrees"));
        assert!(m.contains("0 and 180 degrees, not 180.5"), "{m}");
        assert!(within("--c", f64::NAN, (0.0, 180.0), " degrees").is_err());
        assert!(finite("--d", -3.0).is_ok());
        assert!(finite("--d", f64::NEG_INFINITY).is_err());
        // single precision values are named as given, not widened
        assert!(message(positive("--e", -0.1f32)).contains("not -0.1"));
        assert!(voxel("--v", 0.0001).is_ok() && voxel("--v", 1.0).is_ok());
        assert!(voxel("--v", f32::NAN).is_err() && voxel("--v", 1.5).is_err());
        assert!(message(voxel("--v", 1e-5)).contains("0.0001"));
        let k = |fy: f64, cy: f64| {
            intrinsics([
                ("--fx", None),
                ("--fy", Some(fy)),
                ("--cx", None),
                ("--cy", Some(cy)),
            ])
        };
        assert!(k(-480.0, -10.0).is_ok());
        assert!(
            message(k(0.0, 1.0)).contains("--fy") && message(k(1.0, f64::NAN)).contains("--cy")
        );
        assert!(angle("--g", 180.0).is_ok());
        assert!(angle("--g", 0.0).is_err() && angle("--g", 180.5).is_err());
        assert!(iterations("--i", &[0, 0, 3], true).is_ok());
        assert!(iterations("--i", &[0, 0], false).is_ok());
        assert!(message(iterations("--i", &[0, 0], true)).contains("at least 1"));
        assert!(message(iterations("--i", &[2, 1001], true)).contains("1001"));
        assert!(frame_size(4096, 4096).is_ok());
        assert!(frame_count("--f", 0).is_err() && frame_count("--f", MAX_FRAMES + 1).is_err());
        assert!(frame_count("--f", MAX_FRAMES).is_ok());
        assert!(message(frame_size(usize::MAX, 2)).contains("--width"));
    }
}
