//! DeepDeform's deformation-graph files (Bozic et al., "DeepDeform", CVPR 2020; the
//! `graph_nodes/*.bin` of its NeuralTracking example data): a little-endian `i32` node count n,
//! then n × 3 `f32` node positions in the source frame's camera coordinates, metres.

use super::IoError;
use nalgebra::Vector3;
use std::path::Path;

/// Reads a DeepDeform `graph_nodes` file: the node positions, metres, in the source camera's frame.
pub fn read_graph_nodes(path: impl AsRef<Path>) -> Result<Vec<Vector3<f64>>, IoError> {
    let path = path.as_ref();
    let bytes =
        std::fs::read(path).map_err(|e| IoError::file(path, format!("cannot read: {e}")))?;
    decode_graph_nodes(&bytes, path)
}

/// Decodes the bytes of a `graph_nodes` file (see [`read_graph_nodes`]); `path` names them in
/// errors. The file must hold exactly its count of nodes, each finite, and at least one.
pub fn decode_graph_nodes(bytes: &[u8], path: &Path) -> Result<Vec<Vector3<f64>>, IoError> {
    let Some(head) = bytes.get(..4) else {
        return Err(IoError::file(path, "shorter than the 4-byte node count"));
    };
    let n = i32::from_le_bytes([head[0], head[1], head[2], head[3]]);
    let body = &bytes[4..];
    if n <= 0 || body.len() != 12 * n as usize {
        return Err(IoError::file(
            path,
            format!(
                "a count of {n} nodes, and {} bytes after it (12 per node)",
                body.len()
            ),
        ));
    }
    let float = |k: usize| f32::from_le_bytes([body[k], body[k + 1], body[k + 2], body[k + 3]]);
    (0..n as usize)
        .map(|i| {
            let p = Vector3::new(float(12 * i), float(12 * i + 4), float(12 * i + 8));
            if p.iter().all(|v| v.is_finite()) {
                Ok(p.cast())
            } else {
                Err(IoError::file(
                    path,
                    format!("node {i} is not finite: {p:?}"),
                ))
            }
        })
        .collect()
}

/// The bytes of a `graph_nodes` file holding `nodes` (the inverse of [`decode_graph_nodes`]).
pub fn encode_graph_nodes(nodes: &[Vector3<f64>]) -> Vec<u8> {
    let mut out = (nodes.len() as i32).to_le_bytes().to_vec();
    for p in nodes {
        for v in p.iter() {
            out.extend_from_slice(&(*v as f32).to_le_bytes());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nodes_round_trip_and_bad_files_name_their_fault() {
        let nodes = vec![
            Vector3::new(-0.13, 0.5, 1.76),
            Vector3::new(0.25, -0.1, 1.9),
        ];
        let path = Path::new("nodes.bin");
        let bytes = encode_graph_nodes(&nodes);
        assert_eq!(bytes.len(), 4 + 24);
        let back = decode_graph_nodes(&bytes, path).unwrap();
        for (a, b) in back.iter().zip(&nodes) {
            assert!((a - b).norm() < 1e-6);
        }
        let cut = decode_graph_nodes(&bytes[..bytes.len() - 1], path).unwrap_err();
        assert!(cut
            .to_string()
            .starts_with("nodes.bin: a count of 2 nodes, and 23 bytes"));
        assert!(decode_graph_nodes(&bytes[..3], path).is_err());
        assert!(decode_graph_nodes(&encode_graph_nodes(&[]), path).is_err());
        let mut negative = bytes.clone();
        negative[..4].copy_from_slice(&(-2i32).to_le_bytes());
        assert!(decode_graph_nodes(&negative, path).is_err());
        let nan = encode_graph_nodes(&[Vector3::new(0.0, f64::NAN, 1.0)]);
        let e = decode_graph_nodes(&nan, path).unwrap_err();
        assert!(e.to_string().contains("node 0 is not finite"), "{e}");
        assert!(read_graph_nodes("/no/such/nodes.bin").is_err());
    }
}
