//! Text as editors write and datasets publish it.
//!
//! - A file may begin with the UTF-8 byte-order mark (U+FEFF, bytes `EF BB BF`), which Windows
//!   tools add and which is legal UTF-8. It is not part of the first line's content, so every
//!   reader drops it before parsing ([`without_bom`]).
//! - A file may be compressed as published: the BAL problems are `.txt.bz2`, and logs are often
//!   gzipped. [`open`] tells gzip (RFC 1952, bytes `1F 8B`) and bzip2 (`BZh` and a block size
//!   digit) from plain text by their first bytes, whatever the file's name, and decompresses as
//!   it reads. Archives and other compressors (zip, xz, zstd, 7z) are refused by name.

use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;

/// The byte-order mark.
const BOM: char = '\u{feff}';

/// Formats recognised by their first bytes that [`open`] refuses, with what to do instead.
const REFUSED: &[(&[u8], &str)] = &[
    (
        b"PK\x03\x04",
        "a zip archive: extract the file from it first",
    ),
    (b"\xFD7zXZ\x00", "xz-compressed: decompress it first (unxz)"),
    (
        b"\x28\xB5\x2F\xFD",
        "zstd-compressed: decompress it first (unzstd)",
    ),
    (
        b"7z\xBC\xAF\x27\x1C",
        "a 7-Zip archive: extract the file from it first",
    ),
];

/// Opens `path` for reading as text, decompressing gzip and bzip2 (told by the first bytes).
/// A file in another compressed or archive format is an [`std::io::ErrorKind::InvalidData`]
/// error that names the format; decompression errors surface from the reader's reads.
pub fn open(path: impl AsRef<Path>) -> std::io::Result<Box<dyn BufRead>> {
    let mut file = BufReader::new(File::open(path)?);
    let head = file.fill_buf()?;
    if head.starts_with(&[0x1F, 0x8B]) {
        return Ok(Box::new(BufReader::new(
            flate2::bufread::MultiGzDecoder::new(file),
        )));
    }
    if head.len() >= 4 && head.starts_with(b"BZh") && (b'1'..=b'9').contains(&head[3]) {
        return Ok(Box::new(BufReader::new(
            bzip2::bufread::MultiBzDecoder::new(file),
        )));
    }
    if let Some((_, what)) = REFUSED.iter().find(|(magic, _)| head.starts_with(magic)) {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("the file is {what}"),
        ));
    }
    Ok(Box::new(file))
}

/// The whole text of `path`, decompressed as [`open`] does.
pub fn read_to_string(path: impl AsRef<Path>) -> std::io::Result<String> {
    let mut text = String::new();
    open(path)?.read_to_string(&mut text)?;
    Ok(text)
}

/// `text` without a leading byte-order mark.
pub fn without_bom(text: &str) -> &str {
    text.strip_prefix(BOM).unwrap_or(text)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    /// A scratch file holding `bytes`.
    fn file(name: &str, bytes: &[u8]) -> std::path::PathBuf {
        let path = std::env::temp_dir().join(format!("dynamap-text-{}-{name}", std::process::id()));
        std::fs::write(&path, bytes).unwrap();
        path
    }

    #[test]
    fn gzip_and_bzip2_read_as_their_text_whatever_the_name() {
        let text = "# a graph\nVERTEX_SE2 0 0 0 0\n".repeat(500);
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        gz.write_all(text.as_bytes()).unwrap();
        let gz = gz.finish().unwrap();
        let mut bz = bzip2::write::BzEncoder::new(Vec::new(), bzip2::Compression::fast());
        bz.write_all(text.as_bytes()).unwrap();
        let bz = bz.finish().unwrap();
        // two gzip members one after the other are one stream (as `cat a.gz b.gz` makes)
        let twice = [gz.clone(), gz.clone()].concat();
        for (name, bytes, want) in [
            ("plain.txt", text.as_bytes().to_vec(), text.clone()),
            ("g.txt", gz.clone(), text.clone()),
            ("b.g2o", bz.clone(), text.clone()),
            ("twice.gz", twice, text.repeat(2)),
        ] {
            let path = file(name, &bytes);
            assert_eq!(read_to_string(&path).unwrap(), want, "{name}");
            let lines = open(&path).unwrap().lines().count();
            assert_eq!(lines, want.lines().count(), "{name}");
            std::fs::remove_file(path).unwrap();
        }
        // a cut stream is an error, not a shorter text, in either format
        for (name, whole) in [("cut.bz2", &bz), ("cut.gz", &gz)] {
            let path = file(name, &whole[..whole.len() / 2]);
            assert!(read_to_string(&path).is_err(), "{name}");
            std::fs::remove_file(path).unwrap();
        }
    }

    #[test]
    fn archives_and_other_compressors_are_refused_by_name_and_short_files_read() {
        for (name, bytes, says) in [
            ("a.zip", &b"PK\x03\x04rest"[..], "zip archive"),
            ("a.xz", &b"\xFD7zXZ\x00rest"[..], "xz"),
            ("a.zst", &b"\x28\xB5\x2F\xFDrest"[..], "zstd"),
        ] {
            let path = file(name, bytes);
            let e = read_to_string(&path).unwrap_err();
            assert_eq!(e.kind(), std::io::ErrorKind::InvalidData, "{name}");
            assert!(e.to_string().contains(says), "{name}: {e}");
            std::fs::remove_file(path).unwrap();
        }
        // text that merely starts like a magic number, and empty and one-byte files, are text
        for (name, bytes) in [
            ("bz.txt", &b"BZh is not a digit"[..]),
            ("e", b""),
            ("one", b"B"),
        ] {
            let path = file(name, bytes);
            assert_eq!(read_to_string(&path).unwrap().as_bytes(), bytes, "{name}");
            std::fs::remove_file(path).unwrap();
        }
    }

    #[test]
    fn only_a_leading_mark_is_dropped() {
        assert_eq!(without_bom("\u{feff}# list\n1 a.png"), "# list\n1 a.png");
        assert_eq!(without_bom("# list"), "# list");
        assert_eq!(without_bom(""), "");
        // one mark is dropped; a second (or one inside the text) is content
        assert_eq!(without_bom("\u{feff}\u{feff}x"), "\u{feff}x");
        assert_eq!(without_bom("a\u{feff}b"), "a\u{feff}b");
    }
}
