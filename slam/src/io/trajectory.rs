//! Trajectories in the TUM format: one pose per line, `timestamp tx ty tz qx qy qz qw`,
//! camera-to-world (Sturm et al., IROS 2012).

use super::{data_lines, number, read_text, write_atomic, IoError};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use std::fmt::Write as _;
use std::path::Path;

/// Timestamped camera-to-world poses.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Trajectory {
    /// Seconds.
    pub stamps: Vec<f64>,
    /// `T_world_camera` per stamp.
    pub poses: Vec<Isometry3<f64>>,
}

const FIELDS: [&str; 8] = ["timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw"];

impl Trajectory {
    /// Number of poses.
    pub fn len(&self) -> usize {
        self.stamps.len()
    }
    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.stamps.is_empty()
    }
    /// Appends a pose.
    pub fn push(&mut self, stamp: f64, pose: Isometry3<f64>) {
        self.stamps.push(stamp);
        self.poses.push(pose);
    }

    /// Reads a TUM trajectory file.
    pub fn read_tum(path: impl AsRef<Path>) -> Result<Self, IoError> {
        let path = path.as_ref();
        Self::parse_tum(&read_text(path)?, path)
    }

    /// Parses TUM text; `path` names it in errors. A stamp given twice with two poses is refused,
    /// naming both lines (which of them holds is not for an evaluation to guess); a line
    /// repeated with the same pose is kept as it is.
    pub fn parse_tum(text: &str, path: &Path) -> Result<Self, IoError> {
        let mut t = Trajectory::default();
        let mut lines = Vec::new();
        for (line, f) in data_lines(text) {
            lines.push(line);
            if f.len() != 8 {
                return Err(IoError::line(
                    path,
                    line,
                    format!(
                        "expected 8 fields ({}), found {}",
                        FIELDS.join(" "),
                        f.len()
                    ),
                ));
            }
            let v: Vec<f64> = (0..8)
                .map(|k| number(path, line, &f, k, FIELDS[k]))
                .collect::<Result<_, _>>()?;
            let q = Quaternion::new(v[7], v[4], v[5], v[6]);
            if q.norm() < 1e-9 {
                return Err(IoError::line(
                    path,
                    line,
                    "fields qx qy qz qw: the quaternion is zero",
                ));
            }
            t.push(
                v[0],
                Isometry3::from_parts(
                    Translation3::new(v[1], v[2], v[3]),
                    UnitQuaternion::from_quaternion(q),
                ),
            );
        }
        t.check_repeated_stamps(&lines, path)?;
        Ok(t)
    }

    /// The error for the first stamp that two poses share, `lines` being each pose's line.
    fn check_repeated_stamps(&self, lines: &[usize], path: &Path) -> Result<(), IoError> {
        let mut order: Vec<usize> = (0..self.len()).collect();
        order.sort_by(|&a, &b| self.stamps[a].total_cmp(&self.stamps[b]).then(a.cmp(&b)));
        let clash = order.windows(2).find(|w| {
            let (a, b) = (w[0], w[1]);
            self.stamps[a] == self.stamps[b] && self.poses[a] != self.poses[b]
        });
        match clash {
            Some(w) => Err(IoError::line(
                path,
                lines[w[1]],
                format!(
                    "timestamp {} is also on line {} with another pose",
                    self.stamps[w[1]], lines[w[0]]
                ),
            )),
            None => Ok(()),
        }
    }

    /// The TUM text of this trajectory (every number at full precision).
    pub fn format_tum(&self) -> String {
        let mut s = String::from("# timestamp tx ty tz qx qy qz qw\n");
        for (stamp, p) in self.stamps.iter().zip(&self.poses) {
            let (t, q) = (p.translation.vector, p.rotation.quaternion());
            let _ = writeln!(
                s,
                "{stamp:.6} {:?} {:?} {:?} {:?} {:?} {:?} {:?}",
                t.x, t.y, t.z, q.i, q.j, q.k, q.w
            );
        }
        s
    }

    /// Writes the trajectory through a temporary file.
    pub fn write_tum(&self, path: impl AsRef<Path>) -> Result<(), IoError> {
        write_atomic(path, self.format_tum().as_bytes())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_errors() {
        let text = "# comment\n1.0 1 2 3 0 0 0 1\n2.5 -1 0.5 2 0.1 0.2 0.3 0.927\n";
        let t = Trajectory::parse_tum(text, Path::new("t.txt")).unwrap();
        assert_eq!(t.len(), 2);
        let back = Trajectory::parse_tum(&t.format_tum(), Path::new("u.txt")).unwrap();
        assert_eq!(back.stamps, t.stamps);
        for (a, b) in back.poses.iter().zip(&t.poses) {
            assert!((a.to_homogeneous() - b.to_homogeneous()).abs().max() < 1e-15);
        }
        let e = Trajectory::parse_tum("1 2 3\n", Path::new("t.txt")).unwrap_err();
        assert_eq!(
            e.to_string(),
            "t.txt:1: expected 8 fields (timestamp tx ty tz qx qy qz qw), found 3"
        );
        let e = Trajectory::parse_tum("1 2 3 4 0 0 x 1\n", Path::new("t.txt")).unwrap_err();
        assert_eq!(e.to_string(), "t.txt:1: field qz: 'x' is not a number");
        let e = Trajectory::parse_tum("\n1 2 3 4 0 0 0 0\n", Path::new("t.txt")).unwrap_err();
        assert_eq!(
            e.to_string(),
            "t.txt:2: fields qx qy qz qw: the quaternion is zero"
        );
        // a stamp repeated with another pose is refused by both lines; a line repeated is kept
        let twice = "1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 1\n# again\n1 0 0 0 0 0 0 1\n";
        assert_eq!(
            Trajectory::parse_tum(twice, Path::new("t.txt"))
                .unwrap()
                .len(),
            3
        );
        let clash = "1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 1\n1 9 9 9 0 0 0 1\n";
        let e = Trajectory::parse_tum(clash, Path::new("t.txt")).unwrap_err();
        assert_eq!(
            e.to_string(),
            "t.txt:3: timestamp 1 is also on line 1 with another pose"
        );
    }

    proptest::proptest! {
        #[test]
        fn any_trajectory_round_trips_through_tum_text(
            poses in proptest::collection::vec(
                (-1e3f64..1e3, -1e3f64..1e3, -1e3f64..1e3, -4.0f64..4.0, -4.0f64..4.0, -4.0f64..4.0),
                1..20,
            ),
            start in 0u32..2_000_000,
        ) {
            let mut t = Trajectory::default();
            for (k, &(x, y, z, a, b, c)) in poses.iter().enumerate() {
                let pose = Isometry3::new(nalgebra::Vector3::new(x, y, z), nalgebra::Vector3::new(a, b, c));
                // stamps in whole microseconds, which six decimals carry exactly
                t.push((start as f64 + 33_333.0 * k as f64) * 1e-6, pose);
            }
            let back = Trajectory::parse_tum(&t.format_tum(), Path::new("t.txt")).unwrap();
            proptest::prop_assert_eq!(back.len(), t.len());
            for (s, u) in back.stamps.iter().zip(&t.stamps) {
                proptest::prop_assert!((s - u).abs() < 1e-9);
            }
            for (p, q) in back.poses.iter().zip(&t.poses) {
                proptest::prop_assert!((p.to_homogeneous() - q.to_homogeneous()).abs().max() < 1e-12);
            }
        }
    }
}
