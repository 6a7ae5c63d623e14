//! The warp-field flags shared by `nonrigid_register` and `nonrigid_slam` (each application sets
//! its own defaults first; a flag given overrides them).

use crate::flag_checks;
use dynamap_slam::nonrigid::{GraphParams, LinearSteps, RegisterParams};

/// Settings of the deformation graph and the warp-field optimiser.
#[derive(clap::Args, Debug)]
pub struct WarpFlags {
    /// Node spacing, metres.
    #[arg(long)]
    pub spacing: Option<f64>,
    /// Regulariser weights, one optimisation stage each, largest first (e.g. 100,10).
    #[arg(long, value_delimiter = ',')]
    pub schedule: Option<Vec<f64>>,
    /// Association rounds per stage.
    #[arg(long)]
    pub rounds: Option<usize>,
    /// Levenberg-Marquardt iterations per round.
    #[arg(long)]
    pub iterations: Option<usize>,
    /// Gauss-Newton iterations of the rigid pre-alignment (0: none).
    #[arg(long)]
    pub rigid_iterations: Option<usize>,
    /// Association distance gate, metres.
    #[arg(long)]
    pub max_distance: Option<f64>,
    /// Association normal-angle gate, degrees.
    #[arg(long)]
    pub max_angle: Option<f64>,
    /// Tukey's c of the data terms, metres.
    #[arg(long)]
    pub tukey: Option<f64>,
    /// Weight of the point-to-point term beside point-to-plane.
    #[arg(long)]
    pub point_weight: Option<f64>,
    /// Weight of the prior holding each node at its motion after the rigid pre-alignment.
    #[arg(long)]
    pub stay_weight: Option<f64>,
    /// Levenberg-Marquardt's initial damping, as a fraction of H's largest diagonal element.
    #[arg(long)]
    pub damping: Option<f64>,
    /// How each step solves its linear system: `factorise` (a sparse Cholesky factorisation
    /// each step), `refine:N` (up to N conjugate-gradient iterations on the last factorisation
    /// before factorising anew) or `jacobi:N` (up to N conjugate-gradient iterations
    /// preconditioned by H's diagonal blocks, never factorising).
    #[arg(long)]
    pub linear: Option<LinearSteps>,
    /// Coverage matches onto a whole-shape target (a mesh or a cloud, not a depth frame): a
    /// target point farther than this many of the source's point spacings from every warped
    /// point pulls the nearest one (0: none).
    #[arg(long)]
    pub cover: Option<f64>,
}

impl WarpFlags {
    /// The flags' argument ids with the values `graph` and `register` give them, as text.
    fn values(graph: &GraphParams, register: &RegisterParams) -> [(&'static str, String); 13] {
        let schedule: Vec<String> = register.schedule.iter().map(|w| w.to_string()).collect();
        [
            ("spacing", graph.spacing.to_string()),
            ("schedule", schedule.join(",")),
            ("rounds", register.rounds.to_string()),
            ("iterations", register.iterations.to_string()),
            ("rigid_iterations", register.rigid_iterations.to_string()),
            ("max_distance", register.max_distance.to_string()),
            ("max_angle", register.max_normal_angle_deg.to_string()),
            ("tukey", register.tukey.to_string()),
            ("point_weight", register.point_weight.to_string()),
            ("stay_weight", register.stay_weight.to_string()),
            ("damping", register.damping.to_string()),
            ("linear", register.linear.to_string()),
            ("cover", register.cover.to_string()),
        ]
    }

    /// Shows `graph` and `register` as the flags' defaults (in `--help` and `--print-config`).
    pub fn show_defaults(
        cmd: clap::Command,
        graph: &GraphParams,
        register: &RegisterParams,
    ) -> clap::Command {
        Self::values(graph, register)
            .into_iter()
            .fold(cmd, |cmd, (id, value)| {
                cmd.mut_arg(id, |a| a.default_value(value))
            })
    }

    /// Describes in `--help` defaults whose lengths scale with the input: `graph` and
    /// `register` are the settings for a unit length, shown as multiples of `unit` (e.g. `D`, the
    /// source's bounding-box diagonal).
    pub fn describe_relative_defaults(
        cmd: clap::Command,
        graph: &GraphParams,
        register: &RegisterParams,
        unit: &str,
    ) -> clap::Command {
        let lengths = ["spacing", "max_distance", "tukey"];
        Self::values(graph, register)
            .into_iter()
            .fold(cmd, |cmd, (id, value)| {
                let unit = if lengths.contains(&id) { unit } else { "" };
                append_help(
                    cmd,
                    id,
                    format!("[default: {value} {unit}]")
                        .replace(" ]", "]")
                        .as_str(),
                )
            })
    }

    /// Overrides the settings with the flags given, and refuses settings outside what they mean.
    pub fn apply(
        &self,
        graph: &mut GraphParams,
        register: &mut RegisterParams,
    ) -> anyhow::Result<()> {
        fn set<T: Clone>(flag: &Option<T>, field: &mut T) {
            if let Some(v) = flag {
                *field = v.clone();
            }
        }
        set(&self.spacing, &mut graph.spacing);
        set(&self.schedule, &mut register.schedule);
        set(&self.rounds, &mut register.rounds);
        set(&self.iterations, &mut register.iterations);
        set(&self.rigid_iterations, &mut register.rigid_iterations);
        set(&self.max_distance, &mut register.max_distance);
        set(&self.max_angle, &mut register.max_normal_angle_deg);
        set(&self.tukey, &mut register.tukey);
        set(&self.point_weight, &mut register.point_weight);
        set(&self.stay_weight, &mut register.stay_weight);
        set(&self.damping, &mut register.damping);
        set(&self.linear, &mut register.linear);
        set(&self.cover, &mut register.cover);
        check(graph, register)
    }
}

/// Refuses settings outside what they mean ([`flag_checks`]), named by their flags.
fn check(graph: &GraphParams, register: &RegisterParams) -> anyhow::Result<()> {
    use flag_checks::{angle, iterations, non_negative, positive};
    non_negative("--cover", register.cover)?;
    positive("--damping", register.damping)?;
    positive("--spacing", graph.spacing)?;
    for &w in &register.schedule {
        non_negative("--schedule", w)?;
    }
    if register.schedule.is_empty() {
        anyhow::bail!("--schedule needs a stage");
    }
    // with no round or no iteration the field never moves, and every frame would pass as met
    iterations("--rounds", &[register.rounds], true)?;
    iterations("--iterations", &[register.iterations], true)?;
    iterations("--rigid-iterations", &[register.rigid_iterations], false)?;
    positive("--max-distance", register.max_distance)?;
    angle("--max-angle", register.max_normal_angle_deg)?;
    positive("--tukey", register.tukey)?;
    non_negative("--point-weight", register.point_weight)?;
    non_negative("--stay-weight", register.stay_weight)
}

/// `cmd` with `text` appended to the help of its argument `id` (for defaults known only at run
/// time).
pub fn append_help(cmd: clap::Command, id: &'static str, text: &str) -> clap::Command {
    cmd.mut_arg(id, |a| {
        let help = a.get_help().map(|h| h.to_string()).unwrap_or_default();
        a.help(format!("{help} {text}"))
    })
}
