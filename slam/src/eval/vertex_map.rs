//! A registration scored against a ground-truth vertex map: line k of the map names the target
//! vertex that source vertex k corresponds to (the camel gallop's `maps/i_to_j`, Sumner & Popović,
//! *Deformation transfer for triangle meshes*, SIGGRAPH 2004). The error is the distance from each
//! moved source vertex to its partner, over a scale (the target's bounding-box diagonal).

use crate::io::{read_text, IoError};
use nalgebra::Vector3;
use std::path::Path;

/// A vertex map and the entries it is scored on.
#[derive(Clone, Debug, PartialEq)]
pub struct VertexMap {
    /// The partner (target vertex) of each source vertex.
    pub partner: Vec<usize>,
    /// Whether each entry is scored: all but those pointing at a target vertex that more than
    /// 1 % of the source's vertices point at (the camel maps send their unmatched vertices,
    /// about 7 %, to one vertex).
    pub scored: Vec<bool>,
}

/// Mean and 95th percentile of the scored entries' distances, over the scale.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MapError {
    /// Mean relative distance.
    pub mean: f64,
    /// 95th percentile (the entry at 0.95 n of the sorted distances).
    pub p95: f64,
}

impl VertexMap {
    /// Reads a map for `sources` source vertices, each line an index below `targets` (blank
    /// lines skipped); an error names the file and line. A map with no entry to score is refused.
    pub fn read(path: impl AsRef<Path>, sources: usize, targets: usize) -> Result<Self, IoError> {
        let path = path.as_ref();
        Self::parse(&read_text(path)?, path, sources, targets)
    }

    /// [`Self::read`] from the file's text; `path` names it in errors.
    pub fn parse(text: &str, path: &Path, sources: usize, targets: usize) -> Result<Self, IoError> {
        let partner = text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty())
            .map(|(i, l)| match l.trim().parse::<usize>() {
                Ok(k) if k < targets => Ok(k),
                _ => Err(IoError::line(
                    path,
                    i + 1,
                    format!("'{}' is not a vertex index below {targets}", l.trim()),
                )),
            })
            .collect::<Result<Vec<_>, _>>()?;
        if partner.len() != sources {
            return Err(IoError::file(
                path,
                format!("{} lines for {sources} source vertices", partner.len()),
            ));
        }
        let mut count = vec![0usize; targets];
        for &k in &partner {
            count[k] += 1;
        }
        let scored: Vec<bool> = partner
            .iter()
            .map(|&k| count[k] * 100 <= partner.len())
            .collect();
        if !scored.contains(&true) {
            // an error of 0 over no entries would read as a perfect registration
            return Err(IoError::file(
                path,
                "no entry to score: every vertex maps to a target shared by more than 1 % of them",
            ));
        }
        Ok(Self { partner, scored })
    }

    /// The number of scored entries.
    pub fn scored_count(&self) -> usize {
        self.scored.iter().filter(|&&s| s).count()
    }

    /// The distances from `points` (the source's vertices, moved or not) to their partners in
    /// `targets`, over `scale`.
    pub fn error(&self, points: &[Vector3<f64>], targets: &[Vector3<f64>], scale: f64) -> MapError {
        let mut d: Vec<f64> = points
            .iter()
            .zip(&self.partner)
            .zip(&self.scored)
            .filter(|(_, &s)| s)
            .map(|((p, &k), _)| (p - targets[k]).norm() / scale)
            .collect();
        d.sort_by(f64::total_cmp);
        let mean = d.iter().sum::<f64>() / d.len().max(1) as f64;
        let p95 = d
            .get((0.95 * d.len() as f64) as usize)
            .copied()
            .unwrap_or(0.0);
        MapError { mean, p95 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_map_is_read_scored_and_measured_and_bad_lines_are_named() {
        let path = Path::new("map");
        // 200 sources: 197 map to themselves, 3 to the catch-all vertex 199 (1.5 % > 1 %)
        let text: String = (0..200)
            .map(|i| format!("{}\n", if i < 197 { i } else { 199 }))
            .collect();
        let map = VertexMap::parse(&text, path, 200, 200).unwrap();
        assert_eq!(map.scored_count(), 197);
        let targets: Vec<Vector3<f64>> =
            (0..200).map(|i| Vector3::new(i as f64, 0.0, 0.0)).collect();
        let moved: Vec<Vector3<f64>> = targets
            .iter()
            .map(|t| t + Vector3::new(0.0, 2.0, 0.0))
            .collect();
        let e = map.error(&moved, &targets, 4.0);
        assert!((e.mean - 0.5).abs() < 1e-12 && (e.p95 - 0.5).abs() < 1e-12);
        assert_eq!(map.error(&targets, &targets, 1.0).mean, 0.0);
        let err = VertexMap::parse("0\n7\n", path, 2, 5).unwrap_err();
        assert_eq!(err.line, 2);
        assert!(
            err.to_string()
                .contains("'7' is not a vertex index below 5"),
            "{err}"
        );
        let err = VertexMap::parse("0\n1\n", path, 3, 5).unwrap_err();
        assert!(
            err.to_string().contains("2 lines for 3 source vertices"),
            "{err}"
        );
        let err = VertexMap::parse("4\n4\n4\n", path, 3, 5).unwrap_err();
        assert!(err.to_string().contains("no entry to score"), "{err}");
    }
}
