//! What the benchmark binaries share: their setup and their statistic.

use anyhow::Result;

/// How much to time, on how many threads.
#[derive(clap::Args, Debug)]
pub struct Timing {
    /// Timed frames per stage.
    #[arg(long, default_value_t = 300)]
    pub frames: usize,
    /// Worker threads (0: all cores).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
}

impl Timing {
    /// Checks that at least one frame is timed and sizes rayon's pool.
    pub fn setup(&self) -> Result<()> {
        if self.frames == 0 {
            return Err(crate::cli::bad_input("--frames must be at least 1"));
        }
        if self.threads > 0 {
            rayon::ThreadPoolBuilder::new()
                .num_threads(self.threads)
                .build_global()?;
        }
        Ok(())
    }
}

/// The median of `v` (the upper one of an even count), sorting it.
pub fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}
