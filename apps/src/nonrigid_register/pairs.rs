//! `nonrigid_register pairs`: generated frame pairs ([`FramePairCase::set`]) registered frame to
//! frame, one row each (EPE 3D of the surface's pixels against the true scene flow), and the
//! mean: the held-out check of the frame registration's settings, which were chosen on
//! DeepDeform's shirt.

use super::frame_flags::FrameFlags;
use crate::cli::{self, Session};
use anyhow::Result;
use dynamap_slam::nonrigid::{register_frames, FrameVerdict, FrameView};
use dynamap_slam::synthetic::frame_pair::FramePairCase;

/// `pairs`: which seeds, a wall or not, and the two settings to compare.
#[derive(clap::Args, Debug)]
pub(super) struct PairArgs {
    /// The first texture seed.
    #[arg(long, default_value_t = 1)]
    first_seed: u64,
    /// Seeds per surface and field (9 pairs each).
    #[arg(long, default_value_t = 2)]
    seeds: u64,
    /// A textured wall 0.8 m behind the surface.
    #[arg(long)]
    wall: bool,
    /// NOTES 147's pairs moved far instead (12–33 cm): set 0, which the outline search was
    /// shaped on, or 1, held out (the seeds are the set's own)
    #[arg(long, value_name = "SET", value_parser = clap::value_parser!(u8).range(0..=1))]
    far: Option<u8>,
    /// How the frames are registered, as `frames`.
    #[command(flatten)]
    registration: FrameFlags,
}

/// The most seeds a set may have: ten thousand, hours of pairs; 10⁹ were killed for memory at
/// 24 GB while the set was being drawn.
const MAX_SEEDS: u64 = 10_000;

/// Registers every pair of the set and prints its row, then the mean EPE.
pub(super) fn pair_experiment(args: &PairArgs, session: &Session) -> Result<()> {
    let settings = args.registration.settings()?;
    if !(1..=MAX_SEEDS).contains(&args.seeds) {
        return Err(cli::bad_input(format!(
            "--seeds must lie between 1 and {MAX_SEEDS}, not {}",
            args.seeds
        )));
    }
    let cases = match args.far {
        Some(set) => FramePairCase::far_set(set, args.wall),
        None => FramePairCase::set(args.first_seed, args.seeds, args.wall),
    };
    let bar = session.progress(cases.len() as u64, "pairs");
    let row = |line: String| bar.suspend(|| println!("{line}"));
    row(format!(
        "{:<22} {:>5} | {:>9} {:>9} {:>8} | {:>9} {:>8} {:>7} {:>11} {:>18} {:>13}",
        "pair",
        "frame",
        "zero cm",
        "EPE cm",
        "< 5 cm",
        "matches",
        "start",
        "seconds",
        "verdict",
        "colour off   corr",
        "outline flush"
    ));
    let (mut sum, mut not_registered) = (0.0, 0);
    for case in &cases {
        let pair = case.render();
        let source = FrameView::new(
            &pair.camera,
            &pair.source.0,
            Some(&pair.source.1),
            Some(&pair.mask),
        );
        let target = FrameView::new(&pair.camera, &pair.target.0, Some(&pair.target.1), None);
        let reg = register_frames(&source, &target, &settings)?;
        let (epe, zero) = pair.score(&reg.points, &reg.warped);
        let verdict = reg.verdict();
        let registered = verdict == FrameVerdict::Registered;
        sum += epe.stats.mean;
        not_registered += usize::from(!registered);
        bar.inc(1);
        row(format!(
            "{:<22} {:>5} | {:>9.3} {:>9.3} {:>8.3} | {:>9} {:>8} {:>7.2} {:>11} {:>18} {:>13}",
            case.name(),
            case.frame,
            100.0 * zero.stats.mean,
            100.0 * epe.stats.mean,
            epe.within_5cm,
            reg.matches.as_ref().map_or("none".to_string(), |m| format!(
                "{}/{}",
                m.source.len(),
                m.matches
            )),
            reg.start.name(),
            reg.summary.seconds,
            verdict.name(),
            reg.colour.as_ref().map_or("-".to_string(), |c| format!(
                "{:.2} of {} {:>5.2}",
                c.fraction_off(),
                c.off + c.aligned,
                c.correlation
            )),
            reg.outline.as_ref().map_or("-".to_string(), |o| format!(
                "{:.2} of {}",
                o.fraction_flush(),
                o.seen
            ))
        ));
    }
    bar.finish_and_clear();
    println!(
        "mean EPE {:.3} cm over {} pairs; {} not registered",
        100.0 * sum / cases.len().max(1) as f64,
        cases.len(),
        not_registered
    );
    Ok(())
}
