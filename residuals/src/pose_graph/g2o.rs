//! The g2o text format for pose graphs: `VERTEX_SE2`, `EDGE_SE2`, `VERTEX_SE3:QUAT`,
//! `EDGE_SE3:QUAT` and `FIX` (Kümmerle et al., *g2o: A General Framework for Graph Optimization*,
//! ICRA 2011). The planar lines of TORO's `.graph` files (Grisetti et al., RSS 2007), in which
//! published graphs such as Olson's Manhattan and the Intel lab are also distributed, are read
//! too: `VERTEX2` as `VERTEX_SE2`, and `EDGE2` with TORO's order of the information entries,
//! `I11 I12 I22 I33 I13 I23`. Graphs are always written with g2o's tags.
//!
//! Information matrices are stored as their upper triangle, row by row. For SE(3), g2o orders the
//! coordinates `[x, y, z, qx, qy, qz]`; they are permuted to the solver's `[ω; v]` on reading and back
//! on writing, as GTSAM's `readG2o` does.

use super::graph::{Dimension, Edge, Measurement, Pose, PoseGraph};
use super::information::{self, InformationRepair};
use crate::text::without_bom;
use nalgebra::{Isometry2, Isometry3, Matrix6, Quaternion, Translation3, UnitQuaternion, Vector2};
use std::collections::btree_map::Entry;
use std::collections::BTreeMap;
use std::io::BufRead as _;
use std::path::Path;
use thiserror::Error;

/// A g2o file that could not be read or written, with the place of the fault.
#[derive(Debug, Error, Clone, PartialEq)]
#[error("{path}{}: {message}", place(*.line))]
pub struct G2oError {
    /// The file.
    pub path: String,
    /// 1-based line number (0 for the file as a whole).
    pub line: usize,
    /// What is wrong, naming the field where there is one.
    pub message: String,
}

/// `:line`, or nothing for a fault of the whole file (line 0).
fn place(line: usize) -> String {
    if line == 0 {
        String::new()
    } else {
        format!(":{line}")
    }
}

const SE2_VERTEX: &[&str] = &["id", "x", "y", "theta"];
const SE2_EDGE: &[&str] = &[
    "from", "to", "dx", "dy", "dtheta", "I11", "I12", "I13", "I22", "I23", "I33",
];
/// TORO's planar edge: g2o's fields with the information entries in another order.
const TORO_EDGE: &[&str] = &[
    "from", "to", "dx", "dy", "dtheta", "I11", "I12", "I22", "I33", "I13", "I23",
];
const SE3_VERTEX: &[&str] = &["id", "x", "y", "z", "qx", "qy", "qz", "qw"];

fn se3_edge_fields() -> Vec<String> {
    let mut f: Vec<String> = ["from", "to", "x", "y", "z", "qx", "qy", "qz", "qw"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    for i in 1..=6 {
        for j in i..=6 {
            f.push(format!("I{i}{j}"));
        }
    }
    f
}

struct LineParser<'a> {
    path: &'a str,
    line: usize,
}

impl LineParser<'_> {
    fn err(&self, message: impl Into<String>) -> G2oError {
        G2oError {
            path: self.path.to_string(),
            line: self.line,
            message: message.into(),
        }
    }
    fn count<S: AsRef<str>>(
        &self,
        tag: &str,
        tokens: &[&str],
        names: &[S],
    ) -> Result<(), G2oError> {
        if tokens.len() != names.len() {
            let what = if tokens.len() < names.len() {
                format!("missing field {}", names[tokens.len()].as_ref())
            } else {
                format!("{} unexpected extra fields", tokens.len() - names.len())
            };
            return Err(self.err(format!(
                "{tag} needs {} fields ({}), found {}: {what}",
                names.len(),
                names
                    .iter()
                    .map(|s| s.as_ref())
                    .collect::<Vec<_>>()
                    .join(" "),
                tokens.len()
            )));
        }
        Ok(())
    }
    fn id(&self, tok: &str, name: &str) -> Result<usize, G2oError> {
        tok.parse::<usize>().map_err(|_| {
            self.err(format!(
                "field {name}: '{tok}' is not a non-negative integer id"
            ))
        })
    }
    fn num(&self, tok: &str, name: &str) -> Result<f64, G2oError> {
        let v: f64 = tok
            .parse()
            .map_err(|_| self.err(format!("field {name}: '{tok}' is not a number")))?;
        if !v.is_finite() {
            return Err(self.err(format!("field {name}: '{tok}' is not finite")));
        }
        Ok(v)
    }
    fn nums<S: AsRef<str>>(&self, tokens: &[&str], names: &[S]) -> Result<Vec<f64>, G2oError> {
        tokens
            .iter()
            .zip(names)
            .map(|(t, n)| self.num(t, n.as_ref()))
            .collect()
    }
    fn quaternion(&self, q: &[f64]) -> Result<UnitQuaternion<f64>, G2oError> {
        let quat = Quaternion::new(q[3], q[0], q[1], q[2]);
        let n = quat.norm();
        if n.is_nan() || n <= 1e-9 {
            return Err(self.err("fields qx qy qz qw: the quaternion is zero, not a rotation"));
        }
        Ok(UnitQuaternion::from_quaternion(quat))
    }
}

/// What reading does with an edge whose information matrix is not positive definite.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum InformationPolicy {
    /// Refuse the file, naming the line.
    #[default]
    Refuse,
    /// Replace the matrix by the nearest positive-definite one ([`information::repair`]) and
    /// report the edge; a matrix with no positive eigenvalue is still refused.
    Repair,
}

/// Reads a g2o pose graph from a file, refusing information matrices that are not positive
/// definite.
pub fn read(path: impl AsRef<Path>) -> Result<PoseGraph, G2oError> {
    read_with(path, InformationPolicy::Refuse).map(|(g, _)| g)
}

/// Reads a g2o pose graph from a file under `policy`, with the edges whose information matrix
/// was repaired.
pub fn read_with(
    path: impl AsRef<Path>,
    policy: InformationPolicy,
) -> Result<(PoseGraph, Vec<InformationRepair>), G2oError> {
    let path = path.as_ref();
    let name = path.display().to_string();
    let file = crate::text::open(path).map_err(|e| G2oError {
        path: name.clone(),
        line: 0,
        message: format!("cannot read: {e}"),
    })?;
    // line by line: a million-pose graph's text is never held whole
    parse_lines(file.lines(), &name, policy)
}

fn upper<const N: usize>(values: &[f64]) -> nalgebra::SMatrix<f64, N, N> {
    let mut m = nalgebra::SMatrix::<f64, N, N>::zeros();
    let mut k = 0;
    for i in 0..N {
        for j in i..N {
            m[(i, j)] = values[k];
            m[(j, i)] = values[k];
            k += 1;
        }
    }
    m
}

/// g2o's SE(3) order `[t; r]` to the solver's `[ω; v]` (and back: the permutation is its own inverse).
fn swap_halves(m: &Matrix6<f64>) -> Matrix6<f64> {
    Matrix6::from_fn(|i, j| m[((i + 3) % 6, (j + 3) % 6)])
}

/// Parses g2o text; `path` names the source in errors. Information matrices that are not
/// positive definite are refused.
pub fn parse(text: &str, path: &str) -> Result<PoseGraph, G2oError> {
    parse_with(text, path, InformationPolicy::Refuse).map(|(g, _)| g)
}

/// [`parse`] under `policy`, with the edges whose information matrix was repaired.
pub fn parse_with(
    text: &str,
    path: &str,
    policy: InformationPolicy,
) -> Result<(PoseGraph, Vec<InformationRepair>), G2oError> {
    parse_lines(text.lines().map(Ok), path, policy)
}

/// Parses lines of g2o text (an unreadable line is an error naming it).
fn parse_lines<S: AsRef<str>>(
    lines: impl Iterator<Item = std::io::Result<S>>,
    path: &str,
    policy: InformationPolicy,
) -> Result<(PoseGraph, Vec<InformationRepair>), G2oError> {
    let mut repairs = Vec::new();
    let mut graph = PoseGraph::new(Dimension::Two);
    graph.source = path.to_string();
    let mut dimension: Option<(Dimension, usize)> = None;
    let edge3 = se3_edge_fields();
    // each vertex's line, for the message on a duplicate; dropped once the file is read
    let mut vertex_lines = BTreeMap::new();
    for (i, raw) in lines.enumerate() {
        let p = LineParser { path, line: i + 1 };
        let raw = raw.map_err(|e| p.err(format!("cannot read: {e}")))?;
        let raw = raw.as_ref();
        let raw = if i == 0 { without_bom(raw) } else { raw };
        let content = raw.split('#').next().unwrap_or("").trim();
        if content.is_empty() {
            continue;
        }
        let mut tokens = content.split_whitespace();
        let tag = tokens.next().unwrap_or("");
        let rest: Vec<&str> = tokens.collect();
        check_dimension(&p, tag, &mut dimension)?;
        match tag {
            "VERTEX_SE2" | "VERTEX2" | "VERTEX_SE3:QUAT" => {
                let (id, pose) = parse_vertex(&p, tag, &rest)?;
                add_vertex(&mut graph, &mut vertex_lines, &p, id, pose)?;
            }
            "EDGE_SE2" | "EDGE2" | "EDGE_SE3:QUAT" => {
                let (edge, repair) = parse_edge(&p, tag, &rest, &edge3, policy)?;
                graph.edges.push(edge);
                repairs.extend(repair);
            }
            "FIX" => {
                if rest.is_empty() {
                    return Err(p.err("FIX needs at least one vertex id"));
                }
                for t in &rest {
                    graph.fixed.insert(p.id(t, "id")?);
                }
            }
            other => {
                return Err(p.err(format!(
                    "unknown tag '{other}' (expected VERTEX_SE2, EDGE_SE2, VERTEX_SE3:QUAT, EDGE_SE3:QUAT, FIX, or TORO's VERTEX2 and EDGE2)"
                )));
            }
        }
    }
    match dimension {
        Some((d, _)) => graph.dimension = d,
        None => {
            return Err(G2oError {
                path: path.to_string(),
                line: 0,
                message: "no vertices or edges".into(),
            })
        }
    }
    if let Some(&f) = graph.fixed.iter().find(|f| !graph.vertices.contains_key(f)) {
        return Err(G2oError {
            path: path.to_string(),
            line: 0,
            message: format!("FIX names vertex {f}, which has no VERTEX line"),
        });
    }
    // the edges are kept through the solve: not at up to twice their size
    graph.edges.shrink_to_fit();
    Ok((graph, repairs))
}

/// Notes the graph's dimension from the first tag that has one; an error when `tag` is of the
/// other dimension.
fn check_dimension(
    p: &LineParser<'_>,
    tag: &str,
    dimension: &mut Option<(Dimension, usize)>,
) -> Result<(), G2oError> {
    let this_dim = match tag {
        "VERTEX_SE2" | "EDGE_SE2" | "VERTEX2" | "EDGE2" => Dimension::Two,
        "VERTEX_SE3:QUAT" | "EDGE_SE3:QUAT" => Dimension::Three,
        _ => return Ok(()),
    };
    match *dimension {
        None => *dimension = Some((this_dim, p.line)),
        Some((prev, at)) if prev != this_dim => {
            return Err(p.err(format!(
                "{tag} mixes dimensions: line {at} started a {} graph",
                if prev == Dimension::Two { "2D" } else { "3D" }
            )));
        }
        _ => {}
    }
    Ok(())
}

/// A VERTEX_SE2 (or VERTEX2) or VERTEX_SE3:QUAT line's id and pose.
fn parse_vertex(p: &LineParser<'_>, tag: &str, rest: &[&str]) -> Result<(usize, Pose), G2oError> {
    let (names, pose) = if tag != "VERTEX_SE3:QUAT" {
        p.count(tag, rest, SE2_VERTEX)?;
        let v = p.nums(&rest[1..], &SE2_VERTEX[1..])?;
        (
            SE2_VERTEX,
            Pose::Se2(Isometry2::new(Vector2::new(v[0], v[1]), v[2])),
        )
    } else {
        p.count(tag, rest, SE3_VERTEX)?;
        let v = p.nums(&rest[1..], &SE3_VERTEX[1..])?;
        let q = p.quaternion(&v[3..7])?;
        (
            SE3_VERTEX,
            Pose::Se3(Isometry3::from_parts(
                Translation3::new(v[0], v[1], v[2]),
                q,
            )),
        )
    };
    Ok((p.id(rest[0], names[0])?, pose))
}

/// Adds a vertex; an error naming the first definition when the id is taken.
fn add_vertex(
    graph: &mut PoseGraph,
    vertex_lines: &mut BTreeMap<usize, usize>,
    p: &LineParser<'_>,
    id: usize,
    pose: Pose,
) -> Result<(), G2oError> {
    match graph.vertices.entry(id) {
        Entry::Occupied(_) => Err(p.err(format!(
            "duplicate vertex id {id} (first defined on line {})",
            vertex_lines[&id]
        ))),
        Entry::Vacant(slot) => {
            slot.insert(pose);
            vertex_lines.insert(id, p.line);
            Ok(())
        }
    }
}

/// An EDGE_SE2, EDGE2 or EDGE_SE3:QUAT line, which must join two vertices; an information matrix
/// that is not positive definite is refused or repaired as `policy` says.
fn parse_edge(
    p: &LineParser<'_>,
    tag: &str,
    rest: &[&str],
    edge3: &[String],
    policy: InformationPolicy,
) -> Result<(Edge, Option<InformationRepair>), G2oError> {
    let mut measurement = if tag == "EDGE_SE2" {
        p.count(tag, rest, SE2_EDGE)?;
        let v = p.nums(&rest[2..], &SE2_EDGE[2..])?;
        Measurement::Se2 {
            z: Isometry2::new(Vector2::new(v[0], v[1]), v[2]),
            information: upper::<3>(&v[3..9]),
        }
    } else if tag == "EDGE2" {
        p.count(tag, rest, TORO_EDGE)?;
        let v = p.nums(&rest[2..], &TORO_EDGE[2..])?;
        // I11 I12 I22 I33 I13 I23 into g2o's I11 I12 I13 I22 I23 I33
        let g2o_order = [v[3], v[4], v[7], v[5], v[8], v[6]];
        Measurement::Se2 {
            z: Isometry2::new(Vector2::new(v[0], v[1]), v[2]),
            information: upper::<3>(&g2o_order),
        }
    } else {
        p.count(tag, rest, edge3)?;
        let v = p.nums(&rest[2..], &edge3[2..])?;
        let q = p.quaternion(&v[3..7])?;
        Measurement::Se3 {
            z: Isometry3::from_parts(Translation3::new(v[0], v[1], v[2]), q),
            information: swap_halves(&upper::<6>(&v[7..28])),
        }
    };
    let from = p.id(rest[0], "from")?;
    let to = p.id(rest[1], "to")?;
    if from == to {
        return Err(p.err(format!("edge from vertex {from} to itself")));
    }
    let repaired = match &mut measurement {
        Measurement::Se2 { information, .. } => definite(information, policy),
        Measurement::Se3 { information, .. } => definite(information, policy),
    };
    let repair = match repaired {
        Ok(None) => None,
        Ok(Some((smallest_eigenvalue, raised, floor))) => Some(InformationRepair {
            line: p.line,
            from,
            to,
            smallest_eigenvalue,
            raised,
            floor,
        }),
        Err(why) => return Err(p.err(format!("fields I11..: {why}"))),
    };
    let edge = Edge {
        from,
        to,
        measurement,
        line: p.line,
    };
    Ok((edge, repair))
}

/// Leaves a positive-definite `information` as it is; otherwise refuses it or, under
/// [`InformationPolicy::Repair`], replaces it and gives (smallest eigenvalue, raised, floor).
fn definite<const N: usize>(
    information: &mut nalgebra::SMatrix<f64, N, N>,
    policy: InformationPolicy,
) -> Result<Option<(f64, usize, f64)>, &'static str> {
    if nalgebra::Cholesky::new(*information).is_some() {
        return Ok(None);
    }
    if policy == InformationPolicy::Refuse {
        return Err(
            "the information matrix is not positive definite (read with repair to take \
                    the nearest positive-definite one)",
        );
    }
    let (m, smallest, raised, floor) = information::repair(information)
        .ok_or("the information matrix has no positive eigenvalue; nothing to repair")?;
    *information = m;
    Ok(Some((smallest, raised, floor)))
}

/// Formats a pose graph as g2o text with the vertices in `poses` (all digits needed to read each
/// number back exactly: Rust's shortest round-trip form, as precise as `%.17g`).
pub fn format(graph: &PoseGraph, poses: &std::collections::BTreeMap<usize, Pose>) -> String {
    let mut bytes = Vec::with_capacity(64 * (poses.len() + graph.edges.len()));
    // writing to memory cannot fail, and every number and tag is ASCII
    let _ = format_into(&mut bytes, graph, poses);
    String::from_utf8_lossy(&bytes).into_owned()
}

/// [`format`] written to `s` line by line.
fn format_into(
    s: &mut dyn std::io::Write,
    graph: &PoseGraph,
    poses: &std::collections::BTreeMap<usize, Pose>,
) -> std::io::Result<()> {
    for (id, pose) in poses {
        let c = pose.coordinates();
        let tag = match pose {
            Pose::Se2(_) => "VERTEX_SE2",
            Pose::Se3(_) => "VERTEX_SE3:QUAT",
        };
        write!(s, "{tag} {id}")?;
        for v in c {
            write!(s, " {v:?}")?;
        }
        writeln!(s)?;
    }
    for f in &graph.fixed {
        writeln!(s, "FIX {f}")?;
    }
    for e in &graph.edges {
        let (tag, z, info): (_, Vec<f64>, Vec<f64>) = match &e.measurement {
            Measurement::Se2 { z, information } => (
                "EDGE_SE2",
                Pose::Se2(*z).coordinates(),
                (0..3)
                    .flat_map(|i| (i..3).map(move |j| (i, j)))
                    .map(|(i, j)| information[(i, j)])
                    .collect(),
            ),
            Measurement::Se3 { z, information } => {
                let g = swap_halves(information);
                (
                    "EDGE_SE3:QUAT",
                    Pose::Se3(*z).coordinates(),
                    (0..6)
                        .flat_map(|i| (i..6).map(move |j| (i, j)))
                        .map(|(i, j)| g[(i, j)])
                        .collect(),
                )
            }
        };
        write!(s, "{tag} {} {}", e.from, e.to)?;
        for v in z.iter().chain(&info) {
            write!(s, " {v:?}")?;
        }
        writeln!(s)?;
    }
    Ok(())
}

/// Writes the graph with vertices `poses` to `path` through a temporary file renamed into place, so
/// a failed write never leaves a truncated file.
pub fn write(
    path: impl AsRef<Path>,
    graph: &PoseGraph,
    poses: &std::collections::BTreeMap<usize, Pose>,
) -> Result<(), G2oError> {
    let path = path.as_ref();
    let err = |e: std::io::Error| G2oError {
        path: path.display().to_string(),
        line: 0,
        message: format!("cannot write: {e}"),
    };
    crate::atomic::write_with(path, |w| format_into(w, graph, poses)).map_err(err)
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD2: &str =
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0.1\nEDGE_SE2 0 1 1 0 0.1 10 0 0 10 0 20\n";
    const GOOD3: &str =
        "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 0.0998 0.995\n\
        EDGE_SE3:QUAT 0 1 1 0 0 0 0 0.0998 0.995 1 0 0 0 0 0 2 0 0 0 0 3 0 0 0 4 0 0 5 0 6\n";

    fn message(text: &str) -> String {
        parse(text, "g.g2o").unwrap_err().to_string()
    }

    #[test]
    fn reads_both_dimensions() {
        let g = parse(GOOD2, "a").unwrap();
        assert_eq!(
            (g.dimension, g.vertices.len(), g.edges.len()),
            (Dimension::Two, 2, 1)
        );
        let g = parse(GOOD3, "b").unwrap();
        assert_eq!(g.dimension, Dimension::Three);
        // g2o's translation information (1, 4, 6 on the diagonal) moves to the lower half.
        match &g.edges[0].measurement {
            Measurement::Se3 { information, .. } => {
                let d: Vec<f64> = (0..6).map(|i| information[(i, i)]).collect();
                assert_eq!(d, vec![4.0, 5.0, 6.0, 1.0, 2.0, 3.0]);
            }
            _ => unreachable!(),
        }
    }

    #[test]
    fn toros_planar_lines_are_the_same_graph_with_its_information_order() {
        // the information [[10, 1, 2], [1, 20, 3], [2, 3, 30]]: g2o writes I11 I12 I13 I22 I23
        // I33, TORO I11 I12 I22 I33 I13 I23
        let g2o = parse(
            "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0.1\nEDGE_SE2 0 1 1 0 0.1 10 1 2 20 3 30\n",
            "a.g2o",
        )
        .unwrap();
        let toro = parse(
            "VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0.1\nEDGE2 0 1 1 0 0.1 10 1 20 30 2 3\n",
            "a.graph",
        )
        .unwrap();
        assert_eq!(toro.dimension, Dimension::Two);
        assert_eq!(toro.vertices, g2o.vertices);
        match (&toro.edges[0].measurement, &g2o.edges[0].measurement) {
            (
                Measurement::Se2 {
                    z: a,
                    information: i,
                },
                Measurement::Se2 {
                    z: b,
                    information: j,
                },
            ) => {
                assert_eq!((a, i), (b, j));
                assert_eq!(i[(0, 2)], 2.0);
                assert_eq!(i[(2, 1)], 3.0);
            }
            _ => unreachable!(),
        }
        // TORO's lines are planar: with a 3-D line they mix dimensions
        let mixed = message("VERTEX2 0 0 0 0\nVERTEX_SE3:QUAT 1 0 0 0 0 0 0 1\n");
        assert!(mixed.contains("mixes dimensions"), "{mixed}");
        let short = message("VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 0 1 1 0 0 10 0 10 10 0\n");
        assert!(short.contains("missing field I23"), "{short}");
    }

    #[test]
    fn a_compressed_file_reads_as_its_text() {
        use std::io::Write;
        let dir = std::env::temp_dir().join(format!("dynamap-g2o-z-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut bz = bzip2::write::BzEncoder::new(Vec::new(), bzip2::Compression::fast());
        bz.write_all(GOOD3.as_bytes()).unwrap();
        let path = dir.join("graph.g2o.bz2");
        std::fs::write(&path, bz.finish().unwrap()).unwrap();
        let read = read(&path).unwrap();
        let plain = parse(GOOD3, &path.display().to_string()).unwrap();
        assert_eq!(
            format(&read, &read.vertices),
            format(&plain, &plain.vertices)
        );
        assert_eq!(read.edges.len(), plain.edges.len());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn format_then_parse_round_trips() {
        for text in [GOOD2, GOOD3] {
            let g = parse(text, "a").unwrap();
            let once = format(&g, &g.vertices);
            let back = parse(&once, "b").unwrap();
            for (id, p) in &g.vertices {
                let (a, b) = (p.coordinates(), back.vertices[id].coordinates());
                assert!(
                    a.iter()
                        .zip(&b)
                        .all(|(x, y)| (x - y).abs() <= 1e-15 * x.abs().max(1.0)),
                    "{a:?} {b:?}"
                );
            }
            assert_eq!(back.edges.len(), g.edges.len());
        }
    }

    /// Under the repair policy an indefinite information matrix is replaced by a positive-definite
    /// one and reported with its line and edge; one with no positive eigenvalue is still refused;
    /// the strict reading refuses both.
    #[test]
    fn indefinite_information_is_repaired_and_reported_or_refused() {
        let text = "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 0 1\n\
                    EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 \
                    1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 -1e-7\n";
        let (g, repairs) = parse_with(text, "c.g2o", InformationPolicy::Repair).unwrap();
        assert_eq!(repairs.len(), 1);
        let r = &repairs[0];
        assert_eq!((r.line, r.from, r.to, r.raised), (3, 0, 1, 1));
        assert!((r.smallest_eigenvalue + 1e-7).abs() < 1e-15, "{r:?}");
        let Measurement::Se3 { information, .. } = &g.edges[0].measurement else {
            unreachable!()
        };
        assert!(nalgebra::Cholesky::new(*information).is_some());
        assert!(g.build_problem(&g.vertices).is_ok());
        let strict = parse(text, "c.g2o").unwrap_err().to_string();
        assert!(
            strict.starts_with(
                "c.g2o:3: fields I11..: the information matrix is not positive definite"
            ),
            "{strict}"
        );
        let hopeless = "VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 1 1 0 0 -1 0 0 -1 0 -1\n";
        let err = parse_with(hopeless, "h.g2o", InformationPolicy::Repair).unwrap_err();
        assert!(err.to_string().contains("no positive eigenvalue"), "{err}");
    }

    #[test]
    fn every_fault_names_its_line_and_field() {
        let cases: &[(&str, &str)] = &[
            ("VERTEX_SE2 0 0 0\n", "g.g2o:1: VERTEX_SE2 needs 4 fields (id x y theta), found 3: missing field theta"),
            ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 nan 0 0\n", "g.g2o:2: field x: 'nan' is not finite"),
            ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 0 1 0 0\n", "g.g2o:2: duplicate vertex id 0 (first defined on line 1)"),
            ("VERTEX_XY 0 1 2\n", "g.g2o:1: unknown tag 'VERTEX_XY'"),
            ("VERTEX_SE2 -1 0 0 0\n", "g.g2o:1: field id: '-1' is not a non-negative integer id"),
            ("VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 -1\n", "g.g2o:2: fields I11..: the information matrix is not positive definite"),
            ("VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 0 1 0 0 1 0 0 1 0 1\n", "g.g2o:2: edge from vertex 0 to itself"),
            ("VERTEX_SE2 0 0 0 0\nVERTEX_SE3:QUAT 1 0 0 0 0 0 0 1\n", "g.g2o:2: VERTEX_SE3:QUAT mixes dimensions"),
            ("VERTEX_SE3:QUAT 1 0 0 0 0 0 0 0\n", "g.g2o:1: fields qx qy qz qw: the quaternion is zero"),
            ("VERTEX_SE2 0 0 0 0 7\n", "g.g2o:1: VERTEX_SE2 needs 4 fields (id x y theta), found 5: 1 unexpected extra fields"),
            ("EDGE_SE2 0 1 1 0 0.1 10 0 0 10 0 1e999\n", "g.g2o:1: field I33: '1e999' is not finite"),
            ("# nothing\n\n", "g.g2o: no vertices or edges"),
            ("VERTEX_SE2 0 0 0 0\nFIX 3\n", "g.g2o: FIX names vertex 3, which has no VERTEX line"),
            ("VERTEX_SE2 0 0 0 0\nFIX\n", "g.g2o:2: FIX needs at least one vertex id"),
        ];
        for (text, expected) in cases {
            let m = message(text);
            assert!(
                m.starts_with(expected),
                "{text:?}\n got  {m}\n want {expected}"
            );
        }
    }
}
