//! Text as editors write it: a file may begin with the UTF-8 byte-order mark (U+FEFF, bytes
//! `EF BB BF`), which Windows tools add and which is legal UTF-8. It is not part of the first line's
//! content, so every reader drops it before parsing.

/// The byte-order mark.
const BOM: char = '\u{feff}';

/// `text` without a leading byte-order mark.
pub fn without_bom(text: &str) -> &str {
    text.strip_prefix(BOM).unwrap_or(text)
}

#[cfg(test)]
mod tests {
    use super::*;

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
