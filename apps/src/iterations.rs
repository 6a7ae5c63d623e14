//! The iteration table of the solver binaries: printed as the solver runs (above the progress
//! bar), and the cost per iteration kept for `--preview`.

use crate::cli::Session;
use dynamap_solver::IterationSummary;
use indicatif::ProgressBar;
use std::ops::ControlFlow;
use std::sync::{Arc, Mutex};

/// What a solve printed and the costs it went through.
pub struct IterationLog {
    bar: ProgressBar,
    table: bool,
    costs: Arc<Mutex<Vec<(usize, f64)>>>,
}

impl IterationLog {
    /// A log over at most `max_iterations`; the table is printed unless `-q`.
    pub fn new(session: &Session, max_iterations: usize) -> Self {
        Self {
            bar: session.progress(max_iterations as u64, "iterations"),
            table: !session.quiet,
            costs: Arc::default(),
        }
    }

    /// The solver's observer: prints the header first, then a row per iteration, and records the
    /// cost.
    pub fn observer(&self) -> impl FnMut(&IterationSummary) -> ControlFlow<()> + Send + 'static {
        let (bar, table, costs) = (self.bar.clone(), self.table, self.costs.clone());
        // a solve that resumes an earlier one numbers its iterations on from that one's last, and
        // its start point (the earlier end, changed by the caller) is not a row of its own
        let mut base = 0;
        move |it: &IterationSummary| {
            let mut costs = costs.lock().unwrap_or_else(|e| e.into_inner());
            if it.iteration == 0 {
                if let Some(&(last, _)) = costs.last() {
                    base = last;
                    return ControlFlow::Continue(());
                }
            }
            let mut row = it.clone();
            row.iteration += base;
            if table {
                bar.suspend(|| {
                    if row.iteration == 0 {
                        println!("{}", IterationSummary::HEADER);
                    }
                    println!("{row}");
                });
            }
            if it.iteration > 0 {
                bar.inc(1);
            }
            costs.push((row.iteration, row.cost));
            ControlFlow::Continue(())
        }
    }

    /// (iteration, cost) of every iteration so far, the start point first.
    pub fn costs(&self) -> Vec<(usize, f64)> {
        self.costs.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// Removes the bar (before the run's closing lines).
    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

/// Where the solve's time went ([`dynamap_solver::Timing`]), for the JSON line.
pub fn timing_json(t: &dynamap_solver::Timing) -> serde_json::Value {
    serde_json::json!({
        "setup": t.setup,
        "evaluate": t.evaluate,
        "assemble": t.assemble,
        "factorise": t.factorise,
        "step": t.step,
    })
}
