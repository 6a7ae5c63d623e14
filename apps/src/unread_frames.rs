//! Warnings for the frames a sequence's lists name that a run will not read, and for the lines of
//! `associations.txt` that pair frames otherwise than they say ([`LeftOut`]).

use dynamap_slam::io::sequence::Sequence;
use dynamap_slam::io::tum::{LeftOut, STAMP_AGREEMENT};
use std::path::Path;

/// Warns of the frames the lists name that will not be read, and why (the lines of
/// `associations.txt` left out; depth frames without a colour frame; frames at the stamp of an
/// earlier one), and of the lines of `associations.txt` that pair a frame another line pairs
/// nearer in time or give other stamps than the lists. `max_difference` is the stamp pairing's
/// limit, for the message where the stamps paired the frames.
pub fn warn(dir: &Path, seq: &Sequence, max_difference: f64) {
    let listed = seq.listed_pairing();
    if let Some(left) = &listed {
        warn_of_listed(dir, left);
    }
    let repeated = seq.repeated_stamps();
    if repeated > 0 {
        tracing::warn!(
            "{}: {repeated} paired frames have the depth stamp of an earlier frame (a trajectory \
             has one pose per stamp); only the first at each stamp is read",
            dir.display(),
        );
    }
    let unpaired = seq.unpaired_depth();
    if unpaired > 0 {
        let why = if listed.is_some() {
            "no colour frame in associations.txt".to_string()
        } else {
            format!("no colour frame within {max_difference} s (--max-difference sets the limit)")
        };
        tracing::warn!(
            "{}: {unpaired} of {} depth frames have {why} and are not read",
            dir.display(),
            unpaired + seq.len(),
        );
    }
}

/// The warnings for `associations.txt`'s lines, by cause.
fn warn_of_listed(dir: &Path, left: &LeftOut) {
    let dir = dir.display();
    if left.unlisted > 0 {
        tracing::warn!(
            "{dir}: associations.txt lines that name frames rgb.txt or depth.txt do not list: {}; \
             they are left out",
            left.unlisted,
        );
    }
    if left.far_apart > 0 {
        tracing::warn!(
            "{dir}: associations.txt lines that pair frames more than {:.3} s apart (one frame \
             interval): {}; their colour would not show their depth's scene, so they are left out",
            left.limit,
            left.far_apart,
        );
    }
    if left.contested > 0 {
        tracing::warn!(
            "{dir}: associations.txt lines that pair a frame another line pairs nearer in time: \
             {}; each frame keeps its nearest partner and these lines are left out",
            left.contested,
        );
    }
    if left.restamped.count > 0 {
        tracing::warn!(
            "{dir}: associations.txt lines whose stamps differ from rgb.txt's or depth.txt's by \
             more than {STAMP_AGREEMENT} s: {} (up to {:.3} s); the lists' stamps are used",
            left.restamped.count,
            left.restamped.largest,
        );
    }
}
