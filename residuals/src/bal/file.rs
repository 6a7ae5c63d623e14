//! The BAL text format: a header `cameras points observations`, one line `camera point u v` per
//! observation, then the 9 parameters of every camera and the 3 coordinates of every point,
//! whitespace-separated (one per line in the published files, but any layout is read).

use super::{BalProblem, Observation};
use std::path::Path;
use thiserror::Error;

/// A BAL file that could not be read, with the place of the fault.
#[derive(Debug, Error, Clone, PartialEq)]
#[error("{path}:{line}: {message}")]
pub struct BalError {
    /// The file.
    pub path: String,
    /// 1-based line number (0 for the file as a whole).
    pub line: usize,
    /// What is wrong, naming the field.
    pub message: String,
}

/// The problem in BAL's text form: the header, one observation a line, then the cameras'
/// parameters and the points' coordinates one number a line, as the published files are laid
/// out. Numbers are written to round-trip exactly (`{:?}`), so a problem read back is the same.
pub fn format(problem: &BalProblem) -> String {
    use std::fmt::Write as _;
    let mut s =
        String::with_capacity(48 * problem.observations.len() + 26 * 9 * problem.cameras.len());
    let _ = writeln!(
        s,
        "{} {} {}",
        problem.cameras.len(),
        problem.points.len(),
        problem.observations.len()
    );
    for o in &problem.observations {
        let _ = writeln!(s, "{} {} {:?} {:?}", o.camera, o.point, o.uv[0], o.uv[1]);
    }
    for v in problem
        .cameras
        .iter()
        .flatten()
        .chain(problem.points.iter().flatten())
    {
        let _ = writeln!(s, "{v:?}");
    }
    s
}

/// Writes a BAL problem to `path` (through a temporary file renamed into place).
pub fn write(path: impl AsRef<Path>, problem: &BalProblem) -> Result<(), BalError> {
    let path = path.as_ref();
    crate::atomic::write(path, format(problem).as_bytes()).map_err(|e| BalError {
        path: path.display().to_string(),
        line: 0,
        message: format!("cannot write: {e}"),
    })
}

/// Reads a BAL problem from a file.
pub fn read(path: impl AsRef<Path>) -> Result<BalProblem, BalError> {
    let path = path.as_ref();
    let name = path.display().to_string();
    let text = crate::text::read_to_string(path).map_err(|e| BalError {
        path: name.clone(),
        line: 0,
        message: format!("cannot read: {e}"),
    })?;
    parse(&text, &name)
}

/// Whitespace-separated tokens with their line numbers.
struct Tokens<'a> {
    path: &'a str,
    lines: std::iter::Enumerate<std::str::Lines<'a>>,
    current: std::str::SplitWhitespace<'a>,
    line: usize,
}

impl<'a> Tokens<'a> {
    fn new(text: &'a str, path: &'a str) -> Self {
        Self {
            path,
            lines: text.lines().enumerate(),
            current: "".split_whitespace(),
            line: 0,
        }
    }

    fn err(&self, line: usize, message: impl Into<String>) -> BalError {
        BalError {
            path: self.path.to_string(),
            line,
            message: message.into(),
        }
    }

    /// The next token and its line, or an error naming what was expected.
    fn next(&mut self, what: &dyn Fn() -> String) -> Result<(&'a str, usize), BalError> {
        loop {
            if let Some(t) = self.current.next() {
                return Ok((t, self.line));
            }
            match self.lines.next() {
                Some((i, l)) => {
                    self.line = i + 1;
                    self.current = l.split_whitespace();
                }
                None => {
                    return Err(self.err(
                        self.line,
                        format!("the file ends where {} was expected", what()),
                    ))
                }
            }
        }
    }

    fn count(&mut self, what: &str) -> Result<usize, BalError> {
        let (t, line) = self.next(&|| format!("the header's {what}"))?;
        t.parse::<usize>().map_err(|_| {
            self.err(
                line,
                format!("header field {what}: '{t}' is not a non-negative integer"),
            )
        })
    }

    fn index(&mut self, what: &dyn Fn() -> String, limit: usize) -> Result<usize, BalError> {
        let (t, line) = self.next(what)?;
        let i = t.parse::<usize>().map_err(|_| {
            self.err(
                line,
                format!("{}: '{t}' is not a non-negative integer", what()),
            )
        })?;
        if i >= limit {
            return Err(self.err(
                line,
                format!(
                    "{}: {i} is out of range (the header declares {limit})",
                    what()
                ),
            ));
        }
        Ok(i)
    }

    fn number(&mut self, what: &dyn Fn() -> String) -> Result<f64, BalError> {
        let (t, line) = self.next(what)?;
        let v: f64 = t
            .parse()
            .map_err(|_| self.err(line, format!("{}: '{t}' is not a number", what())))?;
        if !v.is_finite() {
            return Err(self.err(line, format!("{}: '{t}' is not finite", what())));
        }
        Ok(v)
    }
}

/// Parses a BAL problem from text; `path` names it in errors.
pub fn parse(text: &str, path: &str) -> Result<BalProblem, BalError> {
    let text = crate::text::without_bom(text);
    let mut tokens = Tokens::new(text, path);
    let num_cameras = tokens.count("number of cameras")?;
    let num_points = tokens.count("number of points")?;
    let num_observations = tokens.count("number of observations")?;
    // A file cannot hold more observations than it has bytes; refuse absurd headers before
    // allocating for them.
    if num_observations > text.len() || num_cameras > text.len() || num_points > text.len() {
        return Err(tokens.err(1, "the header declares more entries than the file can hold"));
    }
    let mut observations = Vec::with_capacity(num_observations);
    for k in 0..num_observations {
        let camera = tokens.index(&|| format!("observation {k}: camera index"), num_cameras)?;
        let point = tokens.index(&|| format!("observation {k}: point index"), num_points)?;
        let u = tokens.number(&|| format!("observation {k}: u"))?;
        let v = tokens.number(&|| format!("observation {k}: v"))?;
        observations.push(Observation {
            camera,
            point,
            uv: [u, v],
        });
    }
    const CAMERA: [&str; 9] = ["rx", "ry", "rz", "tx", "ty", "tz", "f", "k1", "k2"];
    let mut cameras = Vec::with_capacity(num_cameras);
    for c in 0..num_cameras {
        let mut cam = [0.0; 9];
        for (i, x) in cam.iter_mut().enumerate() {
            *x = tokens.number(&|| format!("camera {c}: {}", CAMERA[i]))?;
        }
        cameras.push(cam);
    }
    let mut points = Vec::with_capacity(num_points);
    for p in 0..num_points {
        let mut pt = [0.0; 3];
        for (i, x) in pt.iter_mut().enumerate() {
            *x = tokens.number(&|| format!("point {p}: {}", ["x", "y", "z"][i]))?;
        }
        points.push(pt);
    }
    if let Ok((t, line)) = tokens.next(&String::new) {
        return Err(tokens.err(
            line,
            format!("unexpected extra data '{t}' after the last point"),
        ));
    }
    Ok(BalProblem {
        cameras,
        points,
        observations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const SMALL: &str = "2 1 2\n0 0 1.5 -2.0\n1 0 3.0 4.0\n\
        0.1\n0.2\n0.3\n1\n2\n3\n500\n0\n0\n\
        0\n0\n0\n0\n0\n0\n400\n0.01\n0\n\
        1 2 -10\n";

    #[test]
    fn a_gzipped_problem_reads_as_its_text() {
        use std::io::Write;
        let path = std::env::temp_dir().join(format!("dynamap-bal-{}.txt.gz", std::process::id()));
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        gz.write_all(SMALL.as_bytes()).unwrap();
        std::fs::write(&path, gz.finish().unwrap()).unwrap();
        let read = read(&path).unwrap();
        let _ = std::fs::remove_file(&path);
        assert_eq!(format(&read), format(&parse(SMALL, "small").unwrap()));
    }

    #[test]
    fn a_written_problem_reads_back_the_same() {
        use crate::bal::synthetic::{generate, SyntheticOptions};
        let s = generate(&SyntheticOptions {
            cameras: 30,
            points: 200,
            pixel_noise: 0.7,
            outlier_fraction: 0.05,
            views: Some((2, 6)),
            ..SyntheticOptions::default()
        });
        let back = parse(&format(&s.start), "written.txt").unwrap();
        assert_eq!(back, s.start);
        let dir = std::env::temp_dir().join(format!("dynamap-bal-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("p.txt");
        write(&path, &s.start).unwrap();
        assert_eq!(read(&path).unwrap(), s.start);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_byte_order_mark_and_crlf_lines_read_as_the_same_problem() {
        let plain = parse(SMALL, "small.txt").unwrap();
        let marked = format!("\u{feff}{}", SMALL.replace('\n', "\r\n"));
        assert_eq!(parse(&marked, "small.txt").unwrap(), plain);
    }

    #[test]
    fn local_visibility_gives_each_point_a_run_of_neighbouring_cameras() {
        use crate::bal::synthetic::{generate, SyntheticOptions};
        let n = 40;
        let s = generate(&SyntheticOptions {
            cameras: n,
            points: 300,
            views: Some((3, 5)),
            ..SyntheticOptions::default()
        });
        let mut seen = vec![Vec::new(); 300];
        for o in &s.start.observations {
            seen[o.point].push(o.camera);
        }
        for cams in &seen {
            assert!((3..=5).contains(&cams.len()), "{cams:?}");
            // a run of consecutive cameras on the ring: every gap but one (the wrap) is 1
            let gaps = cams.windows(2).filter(|w| w[1] - w[0] != 1).count();
            assert!(gaps <= 1, "{cams:?}");
        }
    }

    #[test]
    fn reads_header_observations_cameras_and_points() {
        let p = parse(SMALL, "small.txt").unwrap();
        assert_eq!(p.cameras.len(), 2);
        assert_eq!(p.points, vec![[1.0, 2.0, -10.0]]);
        assert_eq!(p.observations[1].camera, 1);
        assert_eq!(p.observations[1].uv, [3.0, 4.0]);
        assert_eq!(p.cameras[1][6], 400.0);
    }

    #[test]
    fn errors_name_the_line_and_field() {
        let bad_index = SMALL.replace("1 0 3.0 4.0", "2 0 3.0 4.0");
        let e = parse(&bad_index, "f.txt").unwrap_err();
        assert_eq!(e.line, 3);
        assert!(e.message.contains("observation 1: camera index"), "{e}");
        assert!(e.to_string().starts_with("f.txt:3:"));

        let bad_number = SMALL.replace("\n500\n", "\nfive\n");
        let e = parse(&bad_number, "f.txt").unwrap_err();
        assert_eq!(e.line, 10);
        assert!(e.message.contains("camera 0: f"), "{e}");

        let truncated = &SMALL[..SMALL.len() - 4];
        let e = parse(truncated, "f.txt").unwrap_err();
        assert!(e.message.contains("point 0: z"), "{e}");

        let extra = format!("{SMALL}7\n");
        let e = parse(&extra, "f.txt").unwrap_err();
        assert_eq!(e.line, 23);

        let e = parse("3 x 1\n", "f.txt").unwrap_err();
        assert!(e.message.contains("number of points"), "{e}");
        let e = parse("1 1 99999999999\n", "f.txt").unwrap_err();
        assert!(e.message.contains("more entries"), "{e}");
        let e = parse("", "f.txt").unwrap_err();
        assert!(e.message.contains("number of cameras"), "{e}");
    }
}
