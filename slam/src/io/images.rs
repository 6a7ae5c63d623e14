//! PNG and JPEG images: 16-bit depth and 8-bit colour, through the `image` crate.

use super::{write_atomic, IoError};
use crate::image::{ColorImage, Image};
use image::{ImageBuffer, ImageFormat, Luma, Rgb};
use std::path::Path;

/// Reads a 16-bit single-channel depth PNG (raw sensor units).
pub fn read_depth(path: impl AsRef<Path>) -> Result<Image<u16>, IoError> {
    let path = path.as_ref();
    let img = image::open(path)
        .map_err(|e| IoError::file(path, format!("cannot read depth image: {e}")))?;
    match img {
        image::DynamicImage::ImageLuma16(b) => {
            let (w, h) = b.dimensions();
            Ok(Image::from_vec(w as usize, h as usize, b.into_raw()).expect("size matches"))
        }
        other => Err(IoError::file(
            path,
            format!(
                "depth must be a 16-bit single-channel PNG, found {:?}",
                other.color()
            ),
        )),
    }
}

/// Reads a colour image (PNG or JPEG; grey images are expanded to RGB).
pub fn read_color(path: impl AsRef<Path>) -> Result<ColorImage, IoError> {
    let path = path.as_ref();
    let img = image::open(path)
        .map_err(|e| IoError::file(path, format!("cannot read colour image: {e}")))?
        .into_rgb8();
    let (w, h) = img.dimensions();
    // the decoder's buffer reused as pixels where it holds a whole number of them (its own
    // allocations do), copied otherwise
    let data = bytemuck::allocation::try_cast_vec(img.into_raw())
        .unwrap_or_else(|(_, raw)| raw.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect());
    Ok(Image::from_vec(w as usize, h as usize, data).expect("size matches"))
}

/// Reads an object mask (any PNG or JPEG; a pixel belongs to the object where its first channel is
/// not zero).
pub fn read_mask(path: impl AsRef<Path>) -> Result<Image<bool>, IoError> {
    let path = path.as_ref();
    let img = image::open(path)
        .map_err(|e| IoError::file(path, format!("cannot read mask image: {e}")))?
        .into_luma16();
    let (w, h) = img.dimensions();
    let data = img.pixels().map(|p| p.0[0] != 0).collect();
    Ok(Image::from_vec(w as usize, h as usize, data).expect("size matches"))
}

fn encode<P: image::Pixel<Subpixel = S> + image::PixelWithColorType, S: image::Primitive>(
    buffer: ImageBuffer<P, Vec<S>>,
    path: &Path,
) -> Result<(), IoError>
where
    [S]: image::EncodableLayout,
{
    let mut bytes = std::io::Cursor::new(Vec::new());
    buffer
        .write_to(&mut bytes, ImageFormat::Png)
        .map_err(|e| IoError::file(path, format!("cannot encode PNG: {e}")))?;
    write_atomic(path, bytes.get_ref())
}

/// Writes a 16-bit depth PNG.
pub fn write_depth(path: impl AsRef<Path>, depth: &Image<u16>) -> Result<(), IoError> {
    let path = path.as_ref();
    let b: ImageBuffer<Luma<u16>, Vec<u16>> =
        ImageBuffer::from_raw(depth.width as u32, depth.height as u32, depth.data.clone())
            .ok_or_else(|| IoError::file(path, "image size and data disagree"))?;
    encode(b, path)
}

/// Writes an 8-bit RGB PNG.
pub fn write_color(path: impl AsRef<Path>, color: &ColorImage) -> Result<(), IoError> {
    let path = path.as_ref();
    let raw: Vec<u8> = color.data.iter().flatten().copied().collect();
    let b: ImageBuffer<Rgb<u8>, Vec<u8>> =
        ImageBuffer::from_raw(color.width as u32, color.height as u32, raw)
            .ok_or_else(|| IoError::file(path, "image size and data disagree"))?;
    encode(b, path)
}
