//! The warp field's normal equations, assembled in the blend's eight coordinates, and the
//! Levenberg-Marquardt loop that solves them on the solver's block-sparse Cholesky
//! ([`BlockSystem`]).
//!
//! The data terms of a point bound to nodes k (thesis eq. 4.4, and the point-to-point term beside
//! it) have Jacobian blocks `J_k = s_k w_k G P_k`: G = ∂r/∂b is the residual's derivative by the
//! blended dual quaternion b (its 8 coordinates), `s_k w_k` the node's signed blend weight, and
//! `P_k = ∂(q_k ⊗ e(δ))/∂δ` (8 × 6) depends on node k alone ([`right_perturbation`]). So
//!
//! ```text
//! H_kl = Σ_points J_kᵀ J_l = P_kᵀ (Σ_points s_k w_k s_l w_l ρ' GᵀG) P_l,   g_k = P_kᵀ Σ_points s_k w_k ρ' Gᵀr
//! ```
//!
//! Each point gives one symmetric 8 × 8 matrix (36 numbers) to each of its ten node pairs, and each
//! pair is projected once per linearisation: about a quarter of the work of forming every 1 × 6
//! and 3 × 6 block and multiplying them out (what the generic [`dynamap_solver::Problem`] path does
//! with [`WarpedPointToPlane`](dynamap_residuals::deform::WarpedPointToPlane) and
//! [`WarpedPointToPoint`](dynamap_residuals::deform::WarpedPointToPoint); the tests check that
//! both give the same H and g). The photometric row of tracking (module `photometric`) enters
//! the same way, with `G = (∂I/∂p)ᵀ ∂W(v)/∂b`; a test checks its gradient against central
//! differences of the cost. DynamicFusion (Newcombe et al. 2015) assembles its GPU system
//! the same way. Robust kernels enter as iteratively reweighted least squares, weight ρ'(s), as on
//! the solver's dense path. The as-rigid-as-possible terms (eq. 4.5-4.7) and the stay prior are
//! added as 6 × 6 blocks.
//!
//! Each point's matrix and gradient are computed once, in parallel, and kept with its pairs' and
//! nodes' scales; each entry and node then sums what its points give, in the points' order
//! (module `point_terms`), so the bits do not depend on the thread count and no per-thread
//! accumulator of every entry is zeroed and added up. The block structure (node pairs that
//! share a point or an edge) is kept, with its symbolic factorisation, for as long as the points'
//! pairs fit in it; when new pairs appear it is rebuilt as the union of old and new.

use super::graph::{Binding, DeformationGraph};
use super::linear_steps::{LinearEffort, LinearSteps};
use super::photometric::PhotometricTarget;
use super::point_terms::{
    fill_terms, packed, project, PointTerms, TermIndex, NONE, PAIRS, SLOT_PAIRS,
};
use super::prior_index::PriorIndex;
use dynamap_residuals::deform::{
    as_rigid_as_possible, blend, right_perturbation, transform_point, transform_point_jacobian,
    MAX_NEIGHBOURS,
};
use dynamap_solver::lie::se3;
use dynamap_solver::robust::Tukey;
use dynamap_solver::{
    BlockSystem, CgStart, Damping, FactorPrecision, LevenbergDamping, RobustKernel, SolveError,
};
use nalgebra::{DualQuaternion, Isometry3, SMatrix, Vector3, Vector6};
use rayon::prelude::*;
use std::time::Instant;

/// Fixed number of point chunks the data cost is summed in.
const CHUNKS: usize = 4;

/// The matches and weights one round of Levenberg-Marquardt works with.
pub(crate) struct WarpTerms<'a> {
    /// Canonical points.
    pub points: &'a [Vector3<f64>],
    /// Their nodes and weights.
    pub bindings: &'a [Binding],
    /// Each point's partner (point, unit normal), if it has one.
    pub matches: &'a [Option<(Vector3<f64>, Vector3<f64>)>],
    /// Tukey's c of the point-to-plane term, metres.
    pub tukey: f64,
    /// Weight of the point-to-point term (0: none).
    pub point_weight: f64,
    /// Directed regulariser edges (i, j, g_j, λ φ_ij).
    pub edges: &'a [(u32, u32, Vector3<f64>, f64)],
    /// Stay priors: `A₀⁻¹` per node, and their weight (0: none).
    pub anchors: &'a [Isometry3<f64>],
    /// Weight of the stay priors.
    pub stay_weight: f64,
    /// The photometric term, if any.
    pub photometric: Option<Photometric<'a>>,
    /// The chromaticity term, if any (module `chroma`).
    pub chroma: Option<Photometric<'a>>,
}

/// The photometric term of a round: live intensities, reference intensities, weight λ and
/// Tukey's c (module `photometric`).
#[derive(Clone, Copy)]
pub(crate) struct Photometric<'a> {
    pub target: PhotometricTarget<'a>,
    pub weight: f64,
    pub tukey: f64,
}

impl Photometric<'_> {
    /// Point i's residual `I(π(p)) − I_ref` at its warped position p, with `∂I/∂p`, if it has a
    /// reference and projects inside the image.
    #[inline]
    fn residual(&self, i: usize, p: &Vector3<f64>) -> Option<(f64, Vector3<f64>)> {
        let reference = self.target.reference[i];
        if !reference.is_finite() {
            return None;
        }
        let (value, d) = self.target.live.sample(p)?;
        Some((value - reference as f64, d))
    }

    /// ½λρ of a residual, and its IRLS weight λρ'.
    #[inline]
    fn cost(&self, r: f64) -> (f64, f64) {
        let [rho, w, _] = Tukey(self.tukey).evaluate(r * r);
        (0.5 * self.weight * rho, self.weight * w)
    }

    /// Point i's ½λρ at its warped position p (0 without a residual).
    #[inline]
    fn cost_at(term: Option<&Self>, i: usize, p: &Vector3<f64>) -> f64 {
        term.and_then(|ph| Some(ph.cost(ph.residual(i, p)?.0).0))
            .unwrap_or(0.0)
    }

    /// Point i's row at p with `dp = ∂p/∂b`: ½λρ, residual r, IRLS weight and `G = dpᵀ ∂I/∂p`
    /// (all zero without a residual).
    #[inline]
    fn row(
        term: Option<&Self>,
        i: usize,
        p: &Vector3<f64>,
        dp: &SMatrix<f64, 3, 8>,
    ) -> (f64, f64, f64, SMatrix<f64, 8, 1>) {
        match term.and_then(|ph| Some((ph, ph.residual(i, p)?))) {
            Some((ph, (r, di))) => {
                let (c, w) = ph.cost(r);
                (c, r, w, dp.transpose() * di)
            }
            None => (0.0, 0.0, 0.0, SMatrix::<f64, 8, 1>::zeros()),
        }
    }
}

/// Relative change of the cost below which one round's minimisation has converged: a step
/// that gained less, or a rejected one whose model promised less.
const FUNCTION_TOLERANCE: f64 = 1e-10;

/// Relative residual `‖(H + μI)δ + g‖ / ‖g‖` at which conjugate gradients on an earlier
/// factorisation stop: a refined step is then taken instead of factorising anew.
const REFINE_TOLERANCE: f64 = 1e-3;

/// Relative residual at which a block-Jacobi step ends if it does not reach its iteration cap
/// first. Chosen among 10⁻³, 3·10⁻³ and 10⁻² on `nonrigid_slam`'s 2.2-cm plate and the Kinect
/// model's plate bend 3 and tube twist 3 (10⁻² left more frames unfused on the plate, 20
/// against 14); verified on six other Kinect cases and the default run, each within ±0.5 mm
/// of 10⁻³'s errors (NOTES 192). A tracker takes two such steps a frame, and the next frame
/// corrects what one leaves.
const BLOCK_JACOBI_TOLERANCE: f64 = 3e-3;

/// How [`WarpSystem::minimise`] steps.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Steps {
    /// Levenberg-Marquardt iterations at most.
    pub iterations: usize,
    /// Initial damping τ, a fraction of H's largest diagonal element.
    pub damping: f64,
    /// How each step is solved.
    pub linear: LinearSteps,
}

/// What one call of [`WarpSystem::minimise`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Minimised {
    /// Iterations taken (each one factorisation).
    pub iterations: usize,
    /// Whether any step was taken: if not, the motions are as they were.
    pub moved: bool,
    /// The block-Jacobi steps' conjugate gradients.
    pub linear: LinearEffort,
}

/// How [`WarpSystem::try_step`] costs a trial step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Costing {
    /// The cost alone: no step follows.
    CostOnly,
    /// A linearisation at the trial motions, which gives the cost too: another step may follow.
    Linearise,
}

/// What one trial step came to.
enum Trial {
    /// The cost fell to `cost` with gain ratio `gain`; `converged` when by less than the
    /// function tolerance (or the step was negligible).
    Taken {
        cost: f64,
        gain: f64,
        converged: bool,
    },
    /// The cost did not fall (or H + μI could not be factorised); `negligible` when the model
    /// promised less than the function tolerance, so that no damping would gain more.
    Rejected { negligible: bool },
}

/// The assembled system, its structure and the buffers reused across iterations and calls.
#[derive(Default)]
pub(crate) struct WarpSystem {
    system: Option<BlockSystem>,
    /// The number type of its factorisation.
    precision: FactorPrecision,
    /// Regulariser pairs the structure was built with.
    edge_pairs: Vec<(u32, u32)>,
    /// Per point: the entry of each of its binding pairs ([`SLOT_PAIRS`] order).
    slots: Vec<[u32; PAIRS]>,
    /// Each point's terms at the last linearisation, and which entries and nodes read them.
    point_terms: Vec<PointTerms>,
    term_index: TermIndex,
    /// The regularisers' entries, kept while the edges and the structure are the same.
    prior_index: PriorIndex,
    /// Counts the structures built, so that what was found for one is not read for another.
    generation: u64,
    /// `P_k` of every node at the current motions.
    perturb: Vec<SMatrix<f64, 8, 6>>,
    /// Node motions and their dual quaternions: current and trial.
    motions: Vec<Isometry3<f64>>,
    dqs: Vec<DualQuaternion<f64>>,
    trial: Vec<Isometry3<f64>>,
    trial_dqs: Vec<DualQuaternion<f64>>,
    step: Vec<f64>,
    /// The step each Levenberg-Marquardt iteration of the last minimisation solved: where the
    /// same iteration's conjugate gradients start in the next (block-Jacobi steps only).
    last_steps: Vec<Vec<f64>>,
    /// The regularisers' terms of the last linearisation.
    priors: Vec<PriorTerms>,
}

impl WarpSystem {
    /// Readies the structure for `graph` and these bindings: kept when every pair fits,
    /// otherwise rebuilt (with the old pairs kept, so that it settles over frames).
    pub fn prepare(
        &mut self,
        graph: &DeformationGraph,
        bindings: &[Binding],
        precision: FactorPrecision,
    ) -> Result<(), SolveError> {
        let nodes = graph.nodes.len();
        let edge_pairs: Vec<(u32, u32)> = graph
            .edges
            .iter()
            .enumerate()
            .flat_map(|(i, js)| {
                js.iter()
                    .map(move |&j| ((i as u32).min(j), (i as u32).max(j)))
            })
            .collect();
        let same_graph = self
            .system
            .as_ref()
            .is_some_and(|s| s.num_blocks() == nodes)
            && self.edge_pairs == edge_pairs
            && self.precision == precision;
        // a system replaced lends its buffers to the next
        let retired = if same_graph { None } else { self.system.take() };
        self.slots.resize(bindings.len(), [NONE; PAIRS]);
        let fits = self.system.as_ref().is_some_and(|s| {
            self.slots
                .par_iter_mut()
                .zip(bindings)
                .all(|(slots, b)| fill_slots(s, b, slots))
        });
        if !fits {
            let mut pairs: Vec<(usize, usize)> = edge_pairs
                .iter()
                .map(|&(i, j)| (i as usize, j as usize))
                .collect();
            if let Some(old) = &self.system {
                pairs.extend((0..old.num_entries()).map(|e| old.entry_blocks(e)));
            }
            for b in bindings {
                for &(x, y) in &SLOT_PAIRS {
                    if y < b.count && x != y {
                        pairs.push((b.nodes[x] as usize, b.nodes[y] as usize));
                    }
                }
            }
            let mut system = BlockSystem::with_precision(&vec![6; nodes], pairs, precision)?;
            if let Some(old) = self.system.take().or(retired) {
                system.reuse_buffers(old);
            }
            for (slots, b) in self.slots.iter_mut().zip(bindings) {
                let ok = fill_slots(&system, b, slots);
                debug_assert!(ok, "every binding pair was given");
            }
            self.system = Some(system);
            self.generation += 1;
            self.edge_pairs = edge_pairs;
            self.precision = precision;
        }
        let s = self.system.as_ref().expect("built above");
        let size = (s.num_entries(), s.num_blocks());
        self.term_index
            .build(&self.slots, bindings, size, self.generation);
        self.step.resize(s.dim(), 0.0);
        Ok(())
    }

    /// Sets the node motions the next round starts from.
    pub(crate) fn set_motions(&mut self, motions: impl Iterator<Item = Isometry3<f64>>) {
        self.motions.clear();
        self.motions.extend(motions);
        self.dqs.clear();
        self.dqs.extend(
            self.motions
                .iter()
                .map(dynamap_residuals::deform::dual_quaternion),
        );
    }

    /// The node motions.
    pub fn motions(&self) -> &[Isometry3<f64>] {
        &self.motions
    }

    /// Up to `steps.iterations` Levenberg-Marquardt iterations from the current motions (Madsen,
    /// Nielsen & Tingleff's damping update from μ₀ = `steps.damping` · max diag H). Returns the
    /// iterations taken and whether any step was; adds the seconds spent linearising and costing
    /// trial points to `evaluate_seconds` (the rest is factorising and solving).
    pub fn minimise(
        &mut self,
        terms: &WarpTerms<'_>,
        steps: Steps,
        evaluate_seconds: &mut f64,
    ) -> Result<Minimised, SolveError> {
        let clock = Instant::now();
        let mut cost = self.linearise(terms);
        *evaluate_seconds += clock.elapsed().as_secs_f64();
        if !cost.is_finite() {
            return Err(SolveError::NonFiniteInitialCost(0));
        }
        let mut lm = LevenbergDamping::new(
            steps.damping * self.system().max_diagonal().max(f64::MIN_POSITIVE),
            0.0,
        );
        let (mut done, mut moved, mut effort) = (0, false, LinearEffort::default());
        while done < steps.iterations {
            done += 1;
            let mut step = std::mem::take(&mut self.step);
            let start = self.start_at_last(done - 1, steps.linear, &mut step);
            let solved = self.solve_step(lm.mu(), steps.linear, &mut step, (start, &mut effort));
            if solved.is_ok() && matches!(steps.linear, LinearSteps::BlockJacobi(_)) {
                self.last_steps[done - 1].clone_from(&step);
            }
            let clock = Instant::now();
            // a step that another may follow is costed by linearising there: the cost comes
            // with H and g, which a taken step needs next
            let next = match done < steps.iterations {
                true => Costing::Linearise,
                false => Costing::CostOnly,
            };
            // a failed factorisation is a rejected step
            let trial = match solved {
                Ok(predicted) => self.try_step(terms, &step, (predicted, cost), next),
                Err(_) => Trial::Rejected { negligible: false },
            };
            self.step = step;
            match trial {
                Trial::Taken {
                    cost: new_cost,
                    gain,
                    converged,
                } => {
                    cost = new_cost;
                    lm.taken(gain);
                    moved = true;
                    *evaluate_seconds += clock.elapsed().as_secs_f64();
                    if converged {
                        break;
                    }
                }
                Trial::Rejected { negligible } => {
                    *evaluate_seconds += clock.elapsed().as_secs_f64();
                    if negligible || !lm.rejected() {
                        break;
                    }
                }
            }
        }
        Ok(Minimised {
            iterations: done,
            moved,
            linear: effort,
        })
    }

    /// Where iteration `k`'s block-Jacobi step starts ([`CgStart`]): at the step iteration `k`
    /// of the last minimisation solved, written into `step`, its nodes in the graph's order
    /// and nodes added since starting at 0 (a tracker's next frame moves much as its last did;
    /// the solver drops a guess worse than 0). Other linear steps start at 0, and so does an
    /// iteration without a last step that fits (the first frame's, or a graph grown smaller).
    fn start_at_last(&mut self, k: usize, linear: LinearSteps, step: &mut [f64]) -> CgStart {
        if !matches!(linear, LinearSteps::BlockJacobi(_)) {
            return CgStart::Zero;
        }
        if self.last_steps.len() <= k {
            self.last_steps.resize_with(k + 1, Vec::new);
        }
        let last = &self.last_steps[k];
        if last.is_empty() || last.len() > step.len() {
            // no guess: the solver would take one product to find 0 no worse
            return CgStart::Zero;
        }
        let (kept, added) = step.split_at_mut(last.len());
        kept.copy_from_slice(last);
        added.fill(0.0);
        CgStart::Guess
    }

    /// Writes the step solving `(H + μI)δ = −g` into `step` and returns the decrease the
    /// quadratic model predicts for it, as `linear` says ([`LinearSteps`]). A refined step is
    /// taken when conjugate gradients on the last factorisation reach [`REFINE_TOLERANCE`],
    /// else the system is factorised anew (an error if even then they do not); a block-Jacobi
    /// step is the last iterate, converged or not.
    fn solve_step(
        &mut self,
        mu: f64,
        linear: LinearSteps,
        step: &mut [f64],
        (start, effort): (CgStart, &mut LinearEffort),
    ) -> Result<f64, SolveError> {
        let system = self.system.as_mut().expect("prepared");
        let damping = Damping::Identity(mu);
        let iterations = match linear {
            LinearSteps::Factorise => {
                system.solve(damping, step)?;
                // for the exact solution: L(0) − L(δ) = ½ δᵀ(μδ − g)
                return Ok(damping.predicted_decrease(step, system.gradient(), std::iter::empty()));
            }
            LinearSteps::BlockJacobi(n) => {
                let solved =
                    system.solve_block_jacobi(damping, step, BLOCK_JACOBI_TOLERANCE, n, start)?;
                effort.steps += 1;
                effort.iterations += solved.iterations;
                effort.truncated += usize::from(!solved.converged);
                if !solved.converged {
                    tracing::debug!(
                        iterations = n,
                        tolerance = BLOCK_JACOBI_TOLERANCE,
                        "block-Jacobi step truncated at its cap"
                    );
                }
                return Ok(system.model_decrease(step));
            }
            LinearSteps::Refine(n) => n,
        };
        if system.has_factorisation() {
            let refined = system.solve_refined(damping, step, REFINE_TOLERANCE, iterations);
            if refined.converged {
                return Ok(system.model_decrease(step));
            }
        }
        system.factorise(damping)?;
        let refined = system.solve_refined(damping, step, REFINE_TOLERANCE, iterations);
        if refined.converged {
            return Ok(system.model_decrease(step));
        }
        Err(SolveError::LinearSolver(format!(
            "conjugate gradients did not reach {REFINE_TOLERANCE} on a new factorisation in \
             {iterations} iterations"
        )))
    }

    /// Costs the motions moved by `step` (the solution of `(H + μI)δ = −g`, whose model
    /// promised `predicted` from `cost`) and takes them when the cost falls ([`Trial`]). With
    /// [`Costing::Linearise`], H and g are left at the motions kept, taken or not.
    fn try_step(
        &mut self,
        terms: &WarpTerms<'_>,
        step: &[f64],
        (predicted, cost): (f64, f64),
        costing: Costing,
    ) -> Trial {
        self.trial.clear();
        self.trial.extend(
            self.motions
                .iter()
                .enumerate()
                .map(|(k, m)| m * se3::exp(&Vector6::from_column_slice(&step[6 * k..6 * k + 6]))),
        );
        self.trial_dqs.clear();
        self.trial_dqs.extend(
            self.trial
                .iter()
                .map(dynamap_residuals::deform::dual_quaternion),
        );
        let new_cost = match costing {
            Costing::CostOnly => cost_at(terms, &self.trial, &self.trial_dqs),
            Costing::Linearise => {
                self.swap_trial();
                self.linearise(terms)
            }
        };
        let actual = cost - new_cost;
        let gain = actual / predicted;
        let tolerance = FUNCTION_TOLERANCE * cost.max(f64::MIN_POSITIVE);
        if !(new_cost.is_finite() && predicted > 0.0 && gain > 0.0) {
            if costing == Costing::Linearise {
                // back to the motions kept, and H and g with them (the same cost, to the bit)
                self.swap_trial();
                self.linearise(terms);
            }
            return Trial::Rejected {
                negligible: predicted.is_finite() && predicted.abs() < tolerance,
            };
        }
        if costing == Costing::CostOnly {
            self.swap_trial();
        }
        let step_norm = step.iter().map(|d| d * d).sum::<f64>().sqrt();
        Trial::Taken {
            cost: new_cost,
            gain,
            converged: actual < tolerance || step_norm < 1e-10,
        }
    }

    /// Exchanges the current motions with the trial ones.
    fn swap_trial(&mut self) {
        std::mem::swap(&mut self.motions, &mut self.trial);
        std::mem::swap(&mut self.dqs, &mut self.trial_dqs);
    }

    fn system(&self) -> &BlockSystem {
        self.system.as_ref().expect("prepared")
    }

    /// Fills H and g at the current motions and returns the cost ½Σρ.
    pub(crate) fn linearise(&mut self, terms: &WarpTerms<'_>) -> f64 {
        let system = self.system.as_mut().expect("prepared");
        let n = terms.points.len();
        let dqs = &self.dqs;
        // every point's terms, in parallel; the cost summed as `cost_at` sums it
        fill_terms(&mut self.point_terms, n, |i, t| {
            t.cost = data_terms(terms, i, dqs, Some(t));
        });
        let points = &self.point_terms;
        let per = n.div_ceil(CHUNKS).max(1);
        let costs = (0..CHUNKS).map(|c| {
            let range = (c * per).min(n)..((c + 1) * per).min(n);
            points[range].iter().map(|t| t.cost).sum::<f64>()
        });
        let data: f64 = costs.sum();
        self.perturb.clear();
        self.perturb.extend(dqs.iter().map(right_perturbation));
        // the regularisers' blocks, each prior in parallel, added in their order
        let stays = match terms.stay_weight > 0.0 {
            true => terms.anchors.len(),
            false => 0,
        };
        self.prior_index
            .refresh(terms.edges, stays, system, self.generation);
        prior_terms(terms, &self.motions, stays, &mut self.priors);
        // summed as `regulariser_cost` sums them, so that the two costs agree to the bit
        let priors: f64 = self.priors.iter().fold(0.0, |c, p| c + p.cost);
        let cost = data + priors;
        // every entry: its points' sum projected, H_e = P_iᵀ A_e P_j, then the priors' blocks
        let (perturb, index) = (&self.perturb, &self.prior_index);
        let (prior, gather) = (&self.priors, &self.term_index);
        system.set_entries(|e, i, j, out| {
            project(&perturb[i], &gather.entry_sum(e, points), &perturb[j], out);
            for &x in index.blocks_of(e) {
                let b = prior[x as usize / 3].block(x as usize % 3);
                for (o, v) in out.iter_mut().zip(b.as_slice()) {
                    *o += v;
                }
            }
        });
        let gradient = system.gradient_mut();
        gradient
            .par_chunks_mut(6)
            .zip(perturb.par_iter())
            .enumerate()
            .with_min_len(64)
            .for_each(|(k, (out, p))| {
                let g8 = SMatrix::<f64, 8, 1>::from(gather.node_sum(k, points));
                out.copy_from_slice((p.transpose() * g8).as_slice());
            });
        for p in &self.priors {
            for (&k, g) in p.nodes.iter().zip(&p.grads) {
                if k != NONE {
                    for (o, v) in gradient[6 * k as usize..][..6].iter_mut().zip(g) {
                        *o += v;
                    }
                }
            }
        }
        cost
    }
}

/// The entries of a binding's pairs; false when one is not stored.
fn fill_slots(s: &BlockSystem, b: &Binding, slots: &mut [u32; PAIRS]) -> bool {
    for (slot, &(x, y)) in slots.iter_mut().zip(&SLOT_PAIRS) {
        *slot = if y < b.count {
            match s.entry(b.nodes[x] as usize, b.nodes[y] as usize) {
                Some(e) => e as u32,
                None => return false,
            }
        } else {
            NONE
        };
    }
    true
}

/// The two data terms of a match at offset `d = W(v) − q` from a target point with unit normal `n`:
/// ½ρ of point-to-plane (Tukey's c = `tukey`) plus ½ρ of point-to-point (`√pw d` under Tukey's
/// `c √pw`), and the IRLS weights ρ' of the first and `pw ρ'` of the second.
pub(crate) fn match_terms(
    d: &Vector3<f64>,
    n: &Vector3<f64>,
    tukey: f64,
    pw: f64,
) -> (f64, f64, f64) {
    let [rho1, w1, _] = Tukey(tukey).evaluate(n.dot(d).powi(2));
    if pw <= 0.0 {
        return (0.5 * rho1, w1, 0.0);
    }
    let [rho2, w2, _] = Tukey(tukey * pw.sqrt()).evaluate(pw * d.norm_squared());
    (0.5 * rho1 + 0.5 * rho2, w1, w2 * pw)
}

/// The data terms of point i: ½ρ of point-to-plane and of point-to-point, and, with `out`, their
/// reweighted 8 × 8 Gauss-Newton matrix and gradient with the scales of the point's pairs and
/// nodes (all 0 when the point adds nothing).
#[inline]
fn data_terms(
    terms: &WarpTerms<'_>,
    i: usize,
    dqs: &[DualQuaternion<f64>],
    mut out: Option<&mut PointTerms>,
) -> f64 {
    if let Some(t) = out.as_deref_mut() {
        t.scales = [0.0; PAIRS];
        t.node_scales = [0.0; MAX_NEIGHBOURS];
    }
    let Some((q, n)) = terms.matches[i] else {
        return 0.0;
    };
    let b = &terms.bindings[i];
    let k = b.count;
    let mut nodes = [DualQuaternion::identity(); MAX_NEIGHBOURS];
    for (o, &id) in nodes.iter_mut().zip(&b.nodes[..k]) {
        *o = dqs[id as usize];
    }
    let (blended, signs) = blend(&nodes[..k], &b.weights[..k]);
    let v = &terms.points[i];
    let Some(out) = out else {
        let p = transform_point(&blended, v);
        return match_terms(&(p - q), &n, terms.tukey, terms.point_weight).0
            + Photometric::cost_at(terms.photometric.as_ref(), i, &p)
            + Photometric::cost_at(terms.chroma.as_ref(), i, &p);
    };
    let (p, dp) = transform_point_jacobian(&blended, v);
    let d = p - q;
    let (mut cost, w1, w2) = match_terms(&d, &n, terms.tukey, terms.point_weight);
    // the photometric row: r₃ = I(π(p)) − I_ref, G₃ = dpᵀ ∂I/∂p, under weight w₃; the
    // chromaticity row r₄ likewise
    let (c3, r3, w3, u3) = Photometric::row(terms.photometric.as_ref(), i, &p, &dp);
    let (c4, r4, w4, u4) = Photometric::row(terms.chroma.as_ref(), i, &p, &dp);
    cost += c3 + c4;
    if w1 == 0.0 && w2 == 0.0 && w3 == 0.0 && w4 == 0.0 {
        return cost;
    }
    let r1 = n.dot(&d);
    let u = dp.transpose() * n;
    for y in 0..8 {
        let (uy, cy, vy, zy) = (u[y], dp.column(y), u3[y], u4[y]);
        for x in 0..=y {
            out.m[packed(x, y)] =
                w1 * u[x] * uy + w2 * dp.column(x).dot(&cy) + w3 * u3[x] * vy + w4 * u4[x] * zy;
        }
    }
    let g8 = u * (w1 * r1) + dp.transpose() * d * w2 + u3 * (w3 * r3) + u4 * (w4 * r4);
    out.g.copy_from_slice(g8.as_slice());
    for ((c, s), w) in out.node_scales.iter_mut().zip(&signs).zip(&b.weights[..k]) {
        *c = s * w;
    }
    let c = &out.node_scales;
    for (s, &(x, y)) in out.scales.iter_mut().zip(&SLOT_PAIRS) {
        if y >= k {
            continue;
        }
        // the same node twice in a binding gives J_xᵀJ_y and J_yᵀJ_x in one diagonal block
        let twice = if x != y && b.nodes[x] == b.nodes[y] {
            2.0
        } else {
            1.0
        };
        *s = c[x] * c[y] * twice;
    }
    cost
}

/// The cost ½Σρ at `motions` (with their dual quaternions `dqs`), data summed in the same four
/// chunks as [`WarpSystem::linearise`].
pub(crate) fn cost_at(
    terms: &WarpTerms<'_>,
    motions: &[Isometry3<f64>],
    dqs: &[DualQuaternion<f64>],
) -> f64 {
    let n = terms.points.len();
    let per = n.div_ceil(CHUNKS).max(1);
    let mut costs = [0.0; CHUNKS];
    costs.par_iter_mut().enumerate().for_each(|(c, cost)| {
        *cost = ((c * per).min(n)..((c + 1) * per).min(n))
            .map(|i| data_terms(terms, i, dqs, None))
            .sum();
    });
    costs.iter().sum::<f64>() + regulariser_cost(terms, motions)
}

/// ½ Σ |r|² of the as-rigid-as-possible edges and the stay priors.
fn regulariser_cost(terms: &WarpTerms<'_>, motions: &[Isometry3<f64>]) -> f64 {
    let mut cost = 0.0;
    for &(i, j, gj, weight) in terms.edges {
        let (ti, tj) = (&motions[i as usize], &motions[j as usize]);
        let r = ti * nalgebra::Point3::from(gj) - tj * nalgebra::Point3::from(gj);
        cost += 0.5 * weight * r.norm_squared();
    }
    if terms.stay_weight > 0.0 {
        for (anchor, motion) in terms.anchors.iter().zip(motions) {
            cost += 0.5 * terms.stay_weight * se3::log(&(anchor * motion)).norm_squared();
        }
    }
    cost
}

/// One regulariser's share of H and g: an edge's blocks (i, i), (j, j) and (min, max) and its
/// two gradients, or a stay prior's diagonal block and gradient (unused slots [`NONE`]). The
/// blocks are kept as the Jacobians they are products of ([`Self::block`]), under half the
/// memory.
#[derive(Clone, Copy)]
struct PriorTerms {
    cost: f64,
    jacobians: PriorJacobians,
    nodes: [u32; 2],
    grads: [[f64; 6]; 2],
}

/// The weighted Jacobians of one regulariser.
#[derive(Clone, Copy)]
enum PriorJacobians {
    /// An edge i → j: `√w ∂r/∂δ_i`, `√w ∂r/∂δ_j`, and whether i < j.
    Edge(SMatrix<f64, 3, 6>, SMatrix<f64, 3, 6>, bool),
    /// A stay prior: `J_r⁻¹(e)` and its weight.
    Stay(nalgebra::Matrix6<f64>, f64),
}

impl PriorTerms {
    /// Block `slot` of the regulariser's share of H (6 × 6, column-major).
    fn block(&self, slot: usize) -> nalgebra::Matrix6<f64> {
        match (self.jacobians, slot) {
            (PriorJacobians::Edge(ji, _, _), 0) => ji.transpose() * ji,
            (PriorJacobians::Edge(_, jj, _), 1) => jj.transpose() * jj,
            (PriorJacobians::Edge(ji, jj, true), _) => ji.transpose() * jj,
            (PriorJacobians::Edge(ji, jj, false), _) => jj.transpose() * ji,
            (PriorJacobians::Stay(jac, w), _) => jac.transpose() * jac * w,
        }
    }
}

impl Default for PriorTerms {
    fn default() -> Self {
        Self {
            cost: 0.0,
            jacobians: PriorJacobians::Stay(nalgebra::Matrix6::zeros(), 0.0),
            nodes: [NONE; 2],
            grads: [[0.0; 6]; 2],
        }
    }
}

/// Fills `out` with the terms of every as-rigid-as-possible edge (eq. 4.5-4.7), then of every
/// stay prior `√w Log(A₀⁻¹ A)` (when weighted), each computed in parallel.
fn prior_terms(
    terms: &WarpTerms<'_>,
    motions: &[Isometry3<f64>],
    stays: usize,
    out: &mut Vec<PriorTerms>,
) {
    out.resize(terms.edges.len() + stays, PriorTerms::default());
    out.par_iter_mut()
        .enumerate()
        .with_min_len(64)
        .for_each(|(x, p)| {
            if let Some(&(i, j, gj, weight)) = terms.edges.get(x) {
                let (i, j) = (i as usize, j as usize);
                let (r, ji, jj) = as_rigid_as_possible(&motions[i], &motions[j], &gj);
                p.cost = 0.5 * weight * r.norm_squared();
                let (ji, jj, r) = (ji * weight.sqrt(), jj * weight.sqrt(), r * weight.sqrt());
                p.jacobians = PriorJacobians::Edge(ji, jj, i < j);
                p.nodes = [i as u32, j as u32];
                p.grads[0].copy_from_slice((ji.transpose() * r).as_slice());
                p.grads[1].copy_from_slice((jj.transpose() * r).as_slice());
            } else {
                let k = x - terms.edges.len();
                let w = terms.stay_weight;
                let e = se3::log(&(terms.anchors[k] * motions[k]));
                p.cost = 0.5 * w * e.norm_squared();
                let jac = se3::right_jacobian_inv(&e);
                p.jacobians = PriorJacobians::Stay(jac, w);
                p.nodes = [k as u32, NONE];
                p.grads[0].copy_from_slice((jac.transpose() * e * w).as_slice());
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nonrigid::graph::{GraphParams, Node};
    use dynamap_residuals::deform::{
        dual_quaternion, AsRigidAsPossible, WarpedPointToPlane, WarpedPointToPoint,
    };
    use dynamap_residuals::pose_graph::Prior3;
    use dynamap_solver::{Jacobians, Manifold, Residual, Var, SE3};
    use nalgebra::DMatrix;
    use nalgebra::Matrix6;

    /// A graph over a wavy patch with nodes moved off the identity, points bound to it, and
    /// partners near their warped positions (some beyond Tukey's c, some unmatched).
    /// Each point's partner (point, unit normal), if any.
    type Matches = Vec<Option<(Vector3<f64>, Vector3<f64>)>>;

    fn scene() -> (DeformationGraph, Vec<Vector3<f64>>, Vec<Binding>, Matches) {
        scene_at(Vector3::zeros())
    }

    /// [`scene`] moved by `offset`.
    fn scene_at(
        offset: Vector3<f64>,
    ) -> (DeformationGraph, Vec<Vector3<f64>>, Vec<Binding>, Matches) {
        let points: Vec<Vector3<f64>> = (0..120)
            .map(|i| {
                let (x, y) = ((i % 12) as f64 * 0.02, (i / 12) as f64 * 0.02);
                Vector3::new(x, y, 0.02 * (8.0 * x).sin()) + offset
            })
            .collect();
        let mut graph = DeformationGraph::sample(
            &points,
            GraphParams {
                spacing: 0.05,
                ..GraphParams::default()
            },
        )
        .unwrap();
        for (k, node) in graph.nodes.iter_mut().enumerate() {
            let a = k as f64;
            let t = se3::exp(&Vector6::new(
                0.1 * a.sin(),
                0.2 * a.cos(),
                -0.1,
                0.01 * a,
                0.02,
                -0.01 * a.cos(),
            ));
            *node = Node {
                motion: dual_quaternion(&t),
                ..*node
            };
        }
        let bindings = graph.bind_all(&points);
        let matches = points
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let shift = 0.003 * (i as f64).sin() + if i % 17 == 0 { 0.2 } else { 0.0 };
                (i % 13 != 5).then(|| {
                    let n = Vector3::new(0.1 * (i as f64).cos(), 0.2, 1.0).normalize();
                    (p + Vector3::new(0.01, -0.02, 0.03) + n * shift, n)
                })
            })
            .collect();
        (graph, points, bindings, matches)
    }

    /// The graph's edges (weight 3) and anchors a small motion away from `motions`.
    #[allow(clippy::type_complexity)]
    fn edges_and_anchors(
        graph: &DeformationGraph,
        motions: &[Isometry3<f64>],
    ) -> (Vec<(u32, u32, Vector3<f64>, f64)>, Vec<Isometry3<f64>>) {
        let edges = graph
            .edges
            .iter()
            .enumerate()
            .flat_map(|(i, js)| {
                js.iter()
                    .map(move |&j| (i as u32, j, graph.nodes[j as usize].position, 3.0))
            })
            .collect();
        let anchors = motions
            .iter()
            .map(|m| (m * se3::exp(&Vector6::new(0.01, 0.0, -0.02, 0.0, 0.01, 0.0))).inverse())
            .collect();
        (edges, anchors)
    }

    /// JᵀWJ, JᵀWr and the cost ½ Σ ρ formed densely, one residual block at a time, at `xs`.
    struct DenseReference {
        xs: Vec<[f64; 7]>,
        dim: usize,
        h: DMatrix<f64>,
        g: DMatrix<f64>,
        cost: f64,
    }

    impl DenseReference {
        fn new(motions: &[Isometry3<f64>]) -> Self {
            let dim = 6 * motions.len();
            let xs = motions
                .iter()
                .map(|m| {
                    let mut x = [0.0; 7];
                    se3::to_slice(m, &mut x);
                    x
                })
                .collect();
            Self {
                xs,
                dim,
                h: DMatrix::zeros(dim, dim),
                g: DMatrix::zeros(dim, 1),
                cost: 0.0,
            }
        }

        /// Adds one residual block, reweighted by ρ'(‖r‖²) of `kernel` (None: least squares).
        fn add(&mut self, res: &dyn Residual, ids: &[usize], kernel: Option<Tukey>) {
            let (m, dim) = (res.dim(), self.dim);
            let vars: Vec<Var> = ids
                .iter()
                .map(|&k| Var {
                    value: &self.xs[k],
                    manifold: &SE3 as &dyn Manifold,
                })
                .collect();
            let cols = vec![6; ids.len()];
            let mut r = vec![0.0; m];
            let mut jac = vec![0.0; m * 6 * ids.len()];
            res.evaluate(&vars, &mut r, Some(&mut Jacobians::new(&mut jac, m, &cols)));
            let s: f64 = r.iter().map(|v| v * v).sum();
            let [rho, w, _] = kernel.map_or([s, 1.0, 0.0], |k| k.evaluate(s));
            self.cost += 0.5 * rho;
            let jm = DMatrix::from_fn(m, dim, |row, col| {
                ids.iter()
                    .position(|&k| k == col / 6)
                    .map_or(0.0, |p| jac[p * m * 6 + (col % 6) * m + row])
            });
            self.h += jm.transpose() * &jm * w;
            self.g += jm.transpose() * DMatrix::from_column_slice(m, 1, &r) * w;
        }
    }

    /// H and g of the fused assembly against JᵀWJ and JᵀWr formed densely from the residual
    /// types' own Jacobians (property-tested in `dynamap_residuals`), with the same IRLS weights.
    #[test]
    fn fused_assembly_matches_the_residual_types() {
        let (graph, points, bindings, matches) = scene();
        let motions: Vec<Isometry3<f64>> = graph
            .nodes
            .iter()
            .map(|n| dynamap_residuals::deform::rigid_motion(&n.motion))
            .collect();
        let (edges, anchors) = edges_and_anchors(&graph, &motions);
        let (tukey, pw, stay) = (0.05, 0.3, 0.2);
        let terms = WarpTerms {
            tukey,
            point_weight: pw,
            edges: &edges,
            anchors: &anchors,
            stay_weight: stay,
            ..data_only(&points, &bindings, &matches)
        };
        let mut ws = WarpSystem::default();
        ws.prepare(&graph, &bindings, FactorPrecision::Double)
            .unwrap();
        ws.set_motions(motions.iter().copied());
        let cost = ws.linearise(&terms);
        assert_eq!(cost, cost_at(&terms, &motions, &ws.dqs.clone()));

        let mut dense = DenseReference::new(&motions);
        let mut add =
            |res: &dyn Residual, ids: &[usize], kernel: Option<Tukey>| dense.add(res, ids, kernel);
        for (i, m) in matches.iter().enumerate() {
            let Some((q, n)) = m else { continue };
            let b = &bindings[i];
            let ids: Vec<usize> = b.nodes[..b.count].iter().map(|&k| k as usize).collect();
            let plane = WarpedPointToPlane {
                point: points[i],
                weights: b.weights,
                target: *q,
                normal: *n,
                scale: 1.0,
            };
            add(&plane, &ids, Some(Tukey(tukey)));
            let point = WarpedPointToPoint {
                point: points[i],
                weights: b.weights,
                target: *q,
                scale: pw.sqrt(),
            };
            add(&point, &ids, Some(Tukey(tukey * pw.sqrt())));
        }
        for &(i, j, gj, w) in &edges {
            let r = AsRigidAsPossible {
                position: gj,
                scale: w.sqrt(),
            };
            add(&r, &[i as usize, j as usize], None);
        }
        for (k, a) in anchors.iter().enumerate() {
            let prior = Prior3::new(a.inverse(), Matrix6::identity() * stay.sqrt());
            add(&prior, &[k], None);
        }
        let DenseReference {
            h,
            g,
            cost: expect_cost,
            dim,
            ..
        } = dense;
        assert!(
            (cost - expect_cost).abs() < 1e-12 * expect_cost.max(1.0),
            "{cost} {expect_cost}"
        );
        let s = ws.system();
        let scale = h.amax();
        for r in 0..dim {
            for c in 0..dim {
                let (got, want) = (s.get(r, c), h[(r, c)]);
                assert!(
                    (got - want).abs() < 1e-10 * scale,
                    "H({r}, {c}): {got} vs {want}"
                );
            }
            assert!((s.gradient()[r] - g[r]).abs() < 1e-10 * g.amax(), "g({r})");
        }
    }

    /// The photometric and chromaticity rows' gradient is the derivative of their cost: every
    /// node's six right-perturbation coordinates against central differences of `cost_at`, on a
    /// ramp (whose bilinear samples and central-difference gradients are exact but for the
    /// images' f32 rounding, so that only the chain through the projection and the blend is
    /// tested).
    #[test]
    fn the_photometric_gradient_is_the_derivative_of_its_cost() {
        use crate::camera::Camera;
        let (graph, points, bindings, matches) = scene_at(Vector3::new(-0.1, -0.1, 0.9));
        let motions: Vec<Isometry3<f64>> = graph
            .nodes
            .iter()
            .map(|n| dynamap_residuals::deform::rigid_motion(&n.motion))
            .collect();
        let camera = Camera::tum_default().level(1);
        let gray = ramp(&camera);
        let live = gray.live(&camera);
        let mut ws = WarpSystem::default();
        ws.prepare(&graph, &bindings, FactorPrecision::Double)
            .unwrap();
        ws.set_motions(motions.iter().copied());
        let reference = references_near(&points, &bindings, &ws.dqs, &live);
        let photometric = Photometric {
            target: PhotometricTarget {
                live,
                reference: &reference,
            },
            weight: 0.7,
            tukey: 1.0,
        };
        // the chromaticity rows beside them, on the same image with other references
        let other: Vec<f32> = reference
            .iter()
            .enumerate()
            .map(|(i, r)| r - 0.015 * (i as f32).sin())
            .collect();
        let chroma = Photometric {
            target: PhotometricTarget {
                live,
                reference: &other,
            },
            weight: 0.4,
            tukey: 1.0,
        };
        let mut terms = data_only(&points, &bindings, &matches);
        terms.photometric = Some(photometric);
        terms.chroma = Some(chroma);
        let cost = ws.linearise(&terms);
        let again = cost_at(&terms, &motions, &ws.dqs.clone());
        assert!((cost - again).abs() < 1e-12 * cost, "{cost} {again}");
        let without = cost_at(&data_only(&points, &bindings, &matches), &motions, &ws.dqs);
        assert!(cost > without, "the photometric rows add cost");
        let g = ws.system().gradient().to_vec();
        let at = |k: usize, a: usize, h: f64| {
            let mut m = motions.clone();
            m[k] *= se3::exp(&Vector6::ith(a, h));
            let dqs: Vec<_> = m.iter().map(dual_quaternion).collect();
            cost_at(&terms, &m, &dqs)
        };
        let scale = g.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        let h = 1e-5;
        for k in 0..motions.len() {
            for a in 0..6 {
                let numeric = (at(k, a, h) - at(k, a, -h)) / (2.0 * h);
                assert!(
                    (numeric - g[6 * k + a]).abs() < 1e-4 * scale,
                    "node {k} axis {a}: {numeric} against {}",
                    g[6 * k + a]
                );
            }
        }
    }

    /// An intensity ramp over the image, with its gradients.
    fn ramp(camera: &crate::camera::Camera) -> crate::nonrigid::photometric::tests::WithGradients {
        use crate::image::{GrayImage, Image};
        let mut gray: GrayImage = Image::new(camera.width, camera.height);
        for y in 0..camera.height {
            for x in 0..camera.width {
                let (u, v) = (x as f32, y as f32);
                gray.set(x, y, 0.3 + 0.001 * u + 0.0015 * v);
            }
        }
        crate::nonrigid::photometric::tests::WithGradients::of(gray)
    }

    /// References a little off the intensities the warped points show in `live`, point 7
    /// without any.
    fn references_near(
        points: &[Vector3<f64>],
        bindings: &[Binding],
        dqs: &[DualQuaternion<f64>],
        live: &crate::nonrigid::photometric::LiveIntensity<'_>,
    ) -> Vec<f32> {
        points
            .iter()
            .enumerate()
            .map(|(i, v)| {
                let b = &bindings[i];
                let nodes: Vec<_> = b.nodes[..b.count]
                    .iter()
                    .map(|&k| dqs[k as usize])
                    .collect();
                let p = transform_point(&blend(&nodes, &b.weights[..b.count]).0, v);
                let (value, _) = live.sample(&p).expect("in view");
                if i == 7 {
                    f32::NAN
                } else {
                    (value + 0.02 * (i as f64).cos()) as f32
                }
            })
            .collect()
    }

    /// Data terms alone (Tukey's c 5 cm, point-to-point weight 0.1).
    fn data_only<'a>(
        points: &'a [Vector3<f64>],
        bindings: &'a [Binding],
        matches: &'a Matches,
    ) -> WarpTerms<'a> {
        WarpTerms {
            points,
            bindings,
            matches,
            tukey: 0.05,
            point_weight: 0.1,
            edges: &[],
            anchors: &[],
            stay_weight: 0.0,
            photometric: None,
            chroma: None,
        }
    }

    /// A system prepared for `graph` and started from its nodes' motions.
    /// `iterations` Levenberg-Marquardt steps from τ = 1e-4, each on a new factorisation.
    fn exact_steps(iterations: usize) -> Steps {
        Steps {
            iterations,
            damping: 1e-4,
            linear: LinearSteps::Factorise,
        }
    }

    fn system_at(graph: &DeformationGraph, bindings: &[Binding]) -> WarpSystem {
        let mut ws = WarpSystem::default();
        ws.prepare(graph, bindings, FactorPrecision::Double)
            .unwrap();
        ws.set_motions(
            graph
                .nodes
                .iter()
                .map(|n| dynamap_residuals::deform::rigid_motion(&n.motion)),
        );
        ws
    }

    /// Levenberg-Marquardt lowers the cost, and the structure stays while the pairs fit.
    #[test]
    fn iterations_lower_the_cost_and_keep_the_structure() {
        let (graph, points, bindings, matches) = scene();
        let terms = data_only(&points, &bindings, &matches);
        let mut ws = system_at(&graph, &bindings);
        let before = cost_at(&terms, &ws.motions.clone(), &ws.dqs.clone());
        let mut seconds = 0.0;
        let taken = ws.minimise(&terms, exact_steps(5), &mut seconds).unwrap();
        assert!(taken.iterations >= 1 && taken.moved);
        let after = cost_at(&terms, &ws.motions.clone(), &ws.dqs.clone());
        assert!(after < 0.5 * before, "{before} -> {after}");
        let entries = ws.system().num_entries();
        ws.prepare(&graph, &bindings[..50], FactorPrecision::Double)
            .unwrap();
        assert_eq!(ws.system().num_entries(), entries);
    }

    /// Which points add to which entry is found again when the points' pairs change under the
    /// same structure: prepared again for fewer points, a system assembles them bit for bit as
    /// one built for them alone.
    #[test]
    fn a_system_prepared_again_for_fewer_points_assembles_only_them() {
        let (graph, points, bindings, matches) = scene();
        let mut ws = system_at(&graph, &bindings);
        ws.linearise(&data_only(&points, &bindings, &matches));
        let generation = ws.generation;
        ws.prepare(&graph, &bindings[..50], FactorPrecision::Double)
            .unwrap();
        assert_eq!(ws.generation, generation, "the structure is kept");
        let few_matches: Matches = matches[..50].to_vec();
        let few = data_only(&points[..50], &bindings[..50], &few_matches);
        let cost = ws.linearise(&few);
        let mut alone = system_at(&graph, &bindings[..50]);
        assert_eq!(cost, alone.linearise(&few));
        let dim = ws.system().dim();
        for r in 0..dim {
            for c in 0..dim {
                let (got, want) = (ws.system().get(r, c), alone.system().get(r, c));
                assert_eq!(got, want, "({r}, {c})");
            }
        }
        assert_eq!(ws.system().gradient(), alone.system().gradient());
    }

    /// The regularisers' entries are found again when the edges change under the same
    /// structure: linearised with every edge and then with every other one, a system assembles
    /// bit for bit as one that only ever saw the second set.
    #[test]
    fn a_system_linearised_with_other_edges_assembles_only_them() {
        let (graph, points, bindings, matches) = scene();
        let (edges, anchors) = edges_and_anchors(&graph, &system_at(&graph, &bindings).motions);
        let half: Vec<_> = edges.iter().copied().step_by(2).collect();
        let with = |edges| WarpTerms {
            edges,
            anchors: &anchors,
            stay_weight: 0.2,
            ..data_only(&points, &bindings, &matches)
        };
        let mut ws = system_at(&graph, &bindings);
        ws.linearise(&with(&edges));
        let cost = ws.linearise(&with(&half));
        let mut fresh = system_at(&graph, &bindings);
        assert_eq!(cost, fresh.linearise(&with(&half)));
        let dim = ws.system().dim();
        for r in 0..dim {
            for c in 0..dim {
                let (got, want) = (ws.system().get(r, c), fresh.system().get(r, c));
                assert_eq!(got, want, "({r}, {c})");
            }
        }
    }

    /// A trial step costed by linearising at it leaves H and g at the motions kept: at the
    /// trial's when taken, back at the old ones when rejected (an ascent step), bit for bit
    /// what a fresh linearisation there gives.
    #[test]
    fn a_trial_costed_by_linearising_leaves_h_and_g_at_the_motions_kept() {
        let (graph, points, bindings, matches) = scene();
        let terms = data_only(&points, &bindings, &matches);
        let fresh = |motions: &[Isometry3<f64>]| {
            let mut ws = system_at(&graph, &bindings);
            ws.set_motions(motions.iter().copied());
            let cost = ws.linearise(&terms);
            let h: Vec<f64> = (0..ws.system().dim())
                .map(|r| ws.system().get(r, r))
                .collect();
            (cost, h, ws.system().gradient().to_vec())
        };
        let now = |ws: &WarpSystem| {
            let h: Vec<f64> = (0..ws.system().dim())
                .map(|r| ws.system().get(r, r))
                .collect();
            (h, ws.system().gradient().to_vec())
        };
        for ascent in [false, true] {
            let mut ws = system_at(&graph, &bindings);
            let cost = ws.linearise(&terms);
            let start = ws.motions.clone();
            let mut step = vec![0.0; ws.system().dim()];
            ws.system
                .as_mut()
                .unwrap()
                .solve(Damping::Identity(1e-6), &mut step)
                .unwrap();
            if ascent {
                // the other way, and far: the cost rises although the model is told it falls
                step.iter_mut().for_each(|d| *d *= -3.0);
            }
            let trial = ws.try_step(&terms, &step, (1.0, cost), Costing::Linearise);
            let kept = ws.motions.clone();
            let (fresh_cost, h, g) = fresh(&kept);
            assert_eq!(now(&ws), (h, g), "ascent {ascent}");
            match trial {
                Trial::Taken { cost, .. } => {
                    assert!(!ascent && cost == fresh_cost && kept != start, "{cost}")
                }
                Trial::Rejected { .. } => assert!(ascent && kept == start),
            }
        }
    }

    /// Steps by block-Jacobi conjugate gradients lower the cost about as far as factorised ones
    /// in as many iterations, and never factorise; a single conjugate-gradient iteration a step
    /// still lowers it (each iterate is a descent step).
    #[test]
    fn block_jacobi_steps_lower_the_cost_as_factorised_ones_do() {
        let (graph, points, bindings, matches) = scene();
        let terms = data_only(&points, &bindings, &matches);
        let before = {
            let ws = system_at(&graph, &bindings);
            cost_at(&terms, &ws.motions.clone(), &ws.dqs.clone())
        };
        let mut after = Vec::new();
        for linear in [
            LinearSteps::Factorise,
            LinearSteps::BlockJacobi(100),
            LinearSteps::BlockJacobi(1),
        ] {
            let mut ws = system_at(&graph, &bindings);
            let steps = Steps {
                linear,
                ..exact_steps(5)
            };
            let taken = ws.minimise(&terms, steps, &mut 0.0).unwrap();
            assert!(taken.moved, "{linear}");
            // block-Jacobi steps are counted, those capped at one iteration as truncated
            let effort = taken.linear;
            match linear {
                LinearSteps::BlockJacobi(1) => {
                    assert!(
                        effort.steps > 0 && effort.truncated == effort.steps,
                        "{effort:?}"
                    )
                }
                LinearSteps::BlockJacobi(_) => assert!(
                    effort.steps > 0
                        && effort.iterations > effort.steps
                        && effort.truncated < effort.steps,
                    "{effort:?}"
                ),
                _ => assert_eq!(effort, LinearEffort::default()),
            }
            if linear != LinearSteps::Factorise {
                assert!(!ws.system().has_factorisation(), "{linear}");
            }
            after.push(cost_at(&terms, &ws.motions.clone(), &ws.dqs.clone()));
        }
        let [exact, jacobi, single] = after[..] else {
            unreachable!()
        };
        assert!(exact < 0.5 * before, "{before} -> {exact}");
        assert!(
            (jacobi - exact).abs() <= 0.01 * (before - exact),
            "{exact} {jacobi}"
        );
        assert!(single < before, "{before} -> {single}");
    }

    /// A block-Jacobi minimisation run again from where the first began starts each iteration's
    /// conjugate gradients at the step that iteration solved before, and lands where the first
    /// did; a graph grown by nodes keeps the old nodes' steps and starts the new ones at 0; a
    /// factorised step starts nowhere but 0.
    #[test]
    fn block_jacobi_steps_start_where_the_last_minimisation_solved() {
        let (graph, points, bindings, matches) = scene();
        let terms = data_only(&points, &bindings, &matches);
        let steps = Steps {
            linear: LinearSteps::BlockJacobi(100),
            ..exact_steps(3)
        };
        let mut ws = system_at(&graph, &bindings);
        let start: Vec<Isometry3<f64>> = ws.motions.clone();
        ws.minimise(&terms, steps, &mut 0.0).unwrap();
        let (first, solved) = (ws.motions.clone(), ws.last_steps.clone());
        assert!(solved.len() >= 2 && solved.iter().all(|s| s.iter().any(|&x| x != 0.0)));
        ws.set_motions(start.into_iter());
        let mut step = vec![7.0; solved[1].len()];
        assert_eq!(ws.start_at_last(1, steps.linear, &mut step), CgStart::Guess);
        assert_eq!(step, solved[1]);
        ws.minimise(&terms, steps, &mut 0.0).unwrap();
        for (a, b) in first.iter().zip(&ws.motions) {
            assert!((a.translation.vector - b.translation.vector).norm() < 1e-9);
        }
        let mut grown = vec![7.0; solved[0].len() + 6];
        ws.start_at_last(0, steps.linear, &mut grown);
        let (kept, added) = grown.split_at(solved[0].len());
        assert_eq!((kept, added), (&ws.last_steps[0][..], &[0.0; 6][..]));
        let mut fewer = vec![0.0; 6];
        assert_eq!(ws.start_at_last(0, steps.linear, &mut fewer), CgStart::Zero);
        let factorised = ws.start_at_last(0, LinearSteps::Factorise, &mut fewer);
        assert_eq!(factorised, CgStart::Zero);
    }

    /// At the optimum (every match where its point already lands) no step lowers the cost; the
    /// outcome says that nothing moved, so the caller can end its stage, and the motions are
    /// as they were.
    #[test]
    fn at_the_optimum_the_minimisation_reports_that_nothing_moved() {
        let (graph, points, bindings, _) = scene();
        let mut warped = Vec::new();
        let (mut wn, normals) = (Vec::new(), vec![Vector3::z(); points.len()]);
        graph.warp_all(&bindings, &points, &normals, &mut warped, &mut wn);
        let matches: Matches = warped
            .iter()
            .zip(&wn)
            .map(|(p, n)| Some((*p, *n)))
            .collect();
        let terms = data_only(&points, &bindings, &matches);
        let mut ws = system_at(&graph, &bindings);
        let start = ws.motions.clone();
        let mut seconds = 0.0;
        let done = ws.minimise(&terms, exact_steps(6), &mut seconds).unwrap();
        assert!(!done.moved && done.iterations >= 1, "{done:?}");
        assert_eq!(ws.motions, start);
        // one match moved off: the same call now moves
        let mut off = matches.clone();
        off[7] = off[7].map(|(p, n)| (p + n * 0.01, n));
        let terms = WarpTerms {
            matches: &off,
            ..terms
        };
        assert!(
            ws.minimise(&terms, exact_steps(6), &mut seconds)
                .unwrap()
                .moved
        );
        assert_ne!(ws.motions, start);
    }
}
