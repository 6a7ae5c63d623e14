//! Dense flow files in DeepDeform's binary layout (NeuralTracking's `load_flow_binary`): three
//! little-endian `u32` (width, height, channels), then `f32` values channel by channel, each a
//! row-major `height × width` plane. Scene flow (`.sflow`) has 3 channels in metres, optical flow
//! (`.oflow`) 2 in pixels; a non-finite value marks a pixel without flow.

use super::{write_atomic, IoError};
use crate::image::Image;
use std::path::Path;

/// Reads a flow file of `C` channels.
pub fn read_flow<const C: usize>(path: impl AsRef<Path>) -> Result<Image<[f32; C]>, IoError> {
    let path = path.as_ref();
    let bytes =
        std::fs::read(path).map_err(|e| IoError::file(path, format!("cannot read: {e}")))?;
    decode_flow(&bytes, path)
}

/// Decodes the bytes of a flow file of `C` channels (see [`read_flow`]); `path` names them in
/// errors.
pub fn decode_flow<const C: usize>(bytes: &[u8], path: &Path) -> Result<Image<[f32; C]>, IoError> {
    let word = |k: usize| -> Option<u32> {
        bytes
            .get(4 * k..4 * k + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    let (Some(w), Some(h), Some(c)) = (word(0), word(1), word(2)) else {
        return Err(IoError::file(path, "shorter than the 12-byte flow header"));
    };
    if c as usize != C {
        return Err(IoError::file(
            path,
            format!("{c} flow channels, expected {C}"),
        ));
    }
    let (w, h) = (w as usize, h as usize);
    if w == 0 || h == 0 {
        return Err(IoError::file(path, format!("an empty {w}×{h} flow")));
    }
    let plane = w
        .checked_mul(h)
        .filter(|n| n.checked_mul(4 * C).is_some_and(|b| b + 12 == bytes.len()))
        .ok_or_else(|| {
            IoError::file(
                path,
                format!(
                    "{} bytes do not hold a {w}×{h}×{C} float flow after the header",
                    bytes.len()
                ),
            )
        })?;
    let mut data = vec![[0.0f32; C]; plane];
    for (ch, chunk) in bytes[12..].chunks_exact(4 * plane).enumerate() {
        for (o, b) in data.iter_mut().zip(chunk.chunks_exact(4)) {
            o[ch] = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        }
    }
    Ok(Image::from_vec(w, h, data).expect("size checked"))
}

/// Writes a flow file (through a temporary file renamed into place).
pub fn write_flow<const C: usize>(
    path: impl AsRef<Path>,
    flow: &Image<[f32; C]>,
) -> Result<(), IoError> {
    write_atomic(path, &encode_flow(flow))
}

/// The bytes of a flow file: width, height and channel count (u32), then each channel's plane
/// of little-endian f32, row by row (what [`decode_flow`] reads).
pub fn encode_flow<const C: usize>(flow: &Image<[f32; C]>) -> Vec<u8> {
    let mut bytes = Vec::with_capacity(12 + 4 * C * flow.data.len());
    for v in [flow.width as u32, flow.height as u32, C as u32] {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    for ch in 0..C {
        for p in &flow.data {
            bytes.extend_from_slice(&p[ch].to_le_bytes());
        }
    }
    bytes
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flow_files_round_trip_and_bad_ones_are_named() {
        let dir = std::env::temp_dir().join(format!("dynamap-flow-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.sflow");
        let mut flow = Image::filled(3, 2, [0.0f32; 3]);
        for (k, p) in flow.data.iter_mut().enumerate() {
            *p = [k as f32, -(k as f32), 0.5];
        }
        flow.data[4] = [f32::NAN; 3];
        write_flow(&path, &flow).unwrap();
        let back: Image<[f32; 3]> = read_flow(&path).unwrap();
        assert_eq!((back.width, back.height), (3, 2));
        assert_eq!(back.data[1], [1.0, -1.0, 0.5]);
        assert!(back.data[4][0].is_nan());
        // wrong channel count, truncated body
        let e = read_flow::<2>(&path).unwrap_err();
        assert!(e.message.contains("3 flow channels"), "{e}");
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() - 4]).unwrap();
        let e = read_flow::<3>(&path).unwrap_err();
        assert!(
            e.to_string().contains("a.sflow") && e.message.contains("bytes"),
            "{e}"
        );
        std::fs::write(&path, [1u8, 2]).unwrap();
        assert!(read_flow::<3>(&path)
            .unwrap_err()
            .message
            .contains("header"));
        std::fs::remove_dir_all(&dir).ok();
    }

    proptest::proptest! {
        #[test]
        fn any_flow_round_trips_bit_for_bit(
            w in 1usize..9, h in 1usize..7,
            values in proptest::collection::vec(proptest::num::f32::ANY, 3 * 8 * 6),
        ) {
            let mut flow = Image::filled(w, h, [0.0f32; 3]);
            for (k, p) in flow.data.iter_mut().enumerate() {
                *p = [values[3 * k], values[3 * k + 1], values[3 * k + 2]];
            }
            let back: Image<[f32; 3]> = decode_flow(&encode_flow(&flow), Path::new("f")).unwrap();
            proptest::prop_assert_eq!((back.width, back.height), (w, h));
            for (a, b) in back.data.iter().zip(&flow.data) {
                proptest::prop_assert_eq!(a.map(f32::to_bits), b.map(f32::to_bits));
            }
        }
    }
}
