//! Messages beside a progress bar.

use indicatif::ProgressBar;

/// A message above the progress bar, or on stderr when the bar is hidden (`--quiet`), so that
/// skipped and failed frames are always reported.
pub fn report_line(bar: &ProgressBar, message: String) {
    if bar.is_hidden() {
        eprintln!("{message}");
    } else {
        bar.println(message);
    }
}
