//! What every application shares on its command line: a TOML config file whose keys are the
//! long flags, `--print-config`, `-v`/`-q` verbosity through `tracing`, a progress bar that stays
//! quiet off a terminal, and the exit codes (0 ok, 1 runtime failure, 2 bad input, 130
//! interrupted by Ctrl-C after writing the outputs so far).
//!
//! A binary calls [`run`] with its `clap` arguments type and its body:
//! ```text
//! fn main() -> ExitCode { cli::run(|args: Args, _: &Session| { ... Ok(()) }) }
//! ```
//! Options come, highest first, from the command line, the `--config` file, then the defaults
//! shown by `--help`. `--print-config` prints the merged options as TOML, a file `--config` reads
//! back to the same run.

use anyhow::{Context, Result};
use clap::parser::ValueSource;
use clap::ArgAction;
use dynamap_slam::io::sequence::Sequence;
use dynamap_slam::io::tum::IntrinsicsSource;
use indicatif::{ProgressBar, ProgressStyle};
use std::ffi::OsString;
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Mutex;

/// The flags every binary has.
#[derive(clap::Args, Debug, Clone)]
pub struct Common {
    /// Options from a TOML file whose keys are the long flags (`max-iterations = 50`); flags on
    /// the command line win over the file.
    #[arg(long, value_name = "FILE", global = true)]
    pub config: Option<PathBuf>,
    /// Print the effective options as TOML (a file for --config) and exit.
    #[arg(long, global = true)]
    pub print_config: bool,
    /// More log output on stderr: -v debug, -vv trace.
    #[arg(short, long, action = ArgAction::Count, global = true)]
    pub verbose: u8,
    /// Errors only: no progress bar, no tables, no log lines; the JSON line is still printed.
    #[arg(short, long, global = true)]
    pub quiet: bool,
}

/// Flags that are not options of a run, so never config keys.
const NOT_OPTIONS: [&str; 4] = ["config", "print-config", "help", "version"];

/// An error in what the user gave (a file, a flag, a config key): exit code 2.
#[derive(Debug)]
pub struct BadInput(pub anyhow::Error);

impl std::fmt::Display for BadInput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:#}", self.0)
    }
}

impl std::error::Error for BadInput {}

/// A run stopped by Ctrl-C (SIGINT) after writing what it had: exit code 130, as shells report a
/// process ended by SIGINT.
#[derive(Debug)]
pub struct Interrupted;

impl std::fmt::Display for Interrupted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "interrupted (the outputs hold the frames processed so far)"
        )
    }
}

impl std::error::Error for Interrupted {}

/// A flag that Ctrl-C (SIGINT) sets, for a loop to stop at the next frame and write its outputs; a
/// second Ctrl-C ends the process at once (exit code 130).
pub fn interrupt_flag() -> Result<std::sync::Arc<std::sync::atomic::AtomicBool>> {
    use std::sync::atomic::{AtomicBool, Ordering};
    let flag = std::sync::Arc::new(AtomicBool::new(false));
    let seen = flag.clone();
    ctrlc::set_handler(move || {
        if seen.swap(true, Ordering::SeqCst) {
            std::process::exit(130);
        }
        tracing::warn!("interrupted: stopping after this frame (Ctrl-C again to quit at once)");
    })
    .context("installing the Ctrl-C handler")?;
    Ok(flag)
}

/// Marks a failure as bad input (exit code 2).
pub trait InputError<T> {
    /// The error, kept with its message, now counted as bad input.
    fn bad_input(self) -> Result<T>;
}

impl<T, E: Into<anyhow::Error>> InputError<T> for std::result::Result<T, E> {
    fn bad_input(self) -> Result<T> {
        self.map_err(|e| anyhow::Error::new(BadInput(e.into())))
    }
}

/// Fails with bad input (exit code 2).
pub fn bad_input(message: impl std::fmt::Display) -> anyhow::Error {
    anyhow::Error::new(BadInput(anyhow::anyhow!("{message}")))
}

/// How a run over a sequence's frames went, for [`FrameCounts::check`].
#[derive(Clone, Debug, Default)]
pub struct FrameCounts {
    /// Frames taken from the sequence.
    pub taken: usize,
    /// Frames that could not be read.
    pub unreadable: usize,
    /// Why the first of them could not.
    pub first_unreadable: Option<String>,
    /// Frames whose result the run kept (tracked, or fused).
    pub kept: usize,
}

impl FrameCounts {
    /// A run that took frames and kept none fails (called once its outputs and summary are
    /// written): as bad input (exit code 2) when no frame could be read, naming the first one's
    /// fault, and as a runtime failure (exit code 1) when frames were read and none kept.
    /// `source` names the sequence, `kept` says what keeping is ("tracked", "fused").
    pub fn check(&self, source: impl std::fmt::Display, kept: &str) -> Result<()> {
        if self.taken == 0 || self.kept > 0 {
            return Ok(());
        }
        if self.unreadable == self.taken {
            let first = self.first_unreadable.as_deref().unwrap_or("unknown");
            return Err(bad_input(format!(
                "none of the {} frames of {source} could be read; the first: {first}",
                self.taken
            )));
        }
        anyhow::bail!(
            "no frame of {source} was {kept}: {} of {} read and not {kept}, {} unreadable (the warnings above say why)",
            self.taken - self.unreadable,
            self.taken,
            self.unreadable
        )
    }
}

/// Refuses a TUM-layout folder that gives no intrinsics (no `intrinsics.txt` or
/// `calibration.txt`) when its images are not 640 × 480, the size TUM's published intrinsics are
/// for; warns where TUM's default Kinect intrinsics are assumed for a folder whose name names no
/// TUM sensor. `flags` is whether all of `--fx --fy --cx --cy` were given (which settles it), or
/// `None` for a command without them.
pub fn check_tum_intrinsics(dir: &Path, seq: &Sequence, flags: Option<bool>) -> Result<()> {
    let given = flags == Some(true);
    let Some(source) = seq.intrinsics_source().filter(|s| s.is_tums() && !given) else {
        return Ok(());
    };
    let (c, dir) = (seq.camera(), dir.display());
    let or_flags = if flags.is_some() {
        ", or give --fx --fy --cx --cy"
    } else {
        ""
    };
    if (c.width, c.height) != (640, 480) {
        return Err(bad_input(format!(
            "{dir}: the images are {}x{} and the folder gives no intrinsics; TUM's published \
             ones are for 640x480 images: write intrinsics.txt (fx fy cx cy depth_scale) or \
             calibration.txt (fx fy cx cy) into the folder{or_flags}",
            c.width, c.height
        )));
    }
    if source == IntrinsicsSource::Assumed {
        tracing::warn!(
            "{dir}: no intrinsics.txt or calibration.txt, and the folder's name names no TUM \
             sensor (freiburg1, 2 or 3): TUM's default Kinect intrinsics are assumed (fx = fy = \
             525, cx = 319.5, cy = 239.5){or_flags}"
        );
    }
    Ok(())
}

/// What a run's body gets besides its arguments.
pub struct Session {
    /// `-q` was given.
    pub quiet: bool,
}

impl Session {
    /// A progress bar over `len` steps of `unit` (frames, iterations) with their rate; hidden
    /// under `-q` or when stderr is not a terminal (CI logs, pipes). Log lines printed while it is
    /// shown go above it.
    pub fn progress(&self, len: u64, unit: &str) -> ProgressBar {
        let bar = if self.quiet || !std::io::stderr().is_terminal() {
            ProgressBar::hidden()
        } else {
            ProgressBar::new(len)
        };
        let template = format!("{{bar:40}} {{pos}}/{{len}} {unit} {{per_sec}} {{msg}}");
        bar.set_style(ProgressStyle::with_template(&template).expect("a valid template"));
        *BAR.lock().unwrap_or_else(|e| e.into_inner()) = Some(bar.clone());
        bar
    }
}

/// The bar log lines must step around.
static BAR: Mutex<Option<ProgressBar>> = Mutex::new(None);

/// Log output to stderr, printed above the progress bar when one is shown.
struct LogWriter;

impl Write for LogWriter {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let bar = BAR.lock().unwrap_or_else(|e| e.into_inner()).clone();
        match bar {
            Some(b) if !b.is_hidden() && !b.is_finished() => {
                b.suspend(|| std::io::stderr().write(buf))
            }
            _ => std::io::stderr().write(buf),
        }
    }
    fn flush(&mut self) -> std::io::Result<()> {
        std::io::stderr().flush()
    }
}

/// Output piped into a reader that stops early (`| head`) ends the process as it does any Unix
/// tool, rather than panicking in `println!` (Rust ignores SIGPIPE by default). Outputs are written
/// to a temporary file and renamed, so none is left half-written.
fn die_quietly_on_a_closed_pipe() {
    #[cfg(unix)]
    // SAFETY: called first in `main`, before any other thread starts; SIG_DFL is a valid action.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

/// Refuses, before a run, output paths it could not write after it (bad input, exit 2): a file
/// flag (`files`) naming a folder, or in a folder that does not exist; a folder flag
/// (`folders`) naming a file, or under one. Without this a run of hours failed at its end on a
/// mistyped `--output` folder, and lost that output.
pub fn check_outputs(
    files: &[(&str, Option<&Path>)],
    folders: &[(&str, Option<&Path>)],
) -> Result<()> {
    for (flag, path) in files.iter().filter_map(|(f, p)| p.map(|p| (f, p))) {
        if path.is_dir() {
            return Err(bad_input(format!(
                "{flag} {}: is a folder; give a file name",
                path.display()
            )));
        }
        let parent = path.parent().filter(|p| !p.as_os_str().is_empty());
        if let Some(folder) = parent.filter(|p| !p.is_dir()) {
            return Err(bad_input(format!(
                "{flag} {}: the folder {} does not exist",
                path.display(),
                folder.display()
            )));
        }
    }
    for (flag, path) in folders.iter().filter_map(|(f, p)| p.map(|p| (f, p))) {
        // the nearest part of the path that exists must be a folder for it to be created
        if let Some(file) = path
            .ancestors()
            .find(|a| a.exists())
            .filter(|a| !a.is_dir())
        {
            return Err(bad_input(format!(
                "{flag} {}: {} is a file, not a folder",
                path.display(),
                file.display()
            )));
        }
    }
    Ok(())
}

/// The most threads `--threads` may ask for: more than any machine's cores, and few enough to
/// start at once (100 000 did not start within 30 s).
pub const MAX_THREADS: usize = 1024;

/// `--threads N`: rayon's global pool with N threads (0 keeps rayon's default, one per core; at
/// most [`MAX_THREADS`]).
pub fn set_threads(threads: usize) -> Result<()> {
    if threads > MAX_THREADS {
        return Err(bad_input(format!(
            "--threads must be at most {MAX_THREADS}, not {threads}"
        )));
    }
    if threads > 0 {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build_global()
            .context("setting up the thread pool")?;
    }
    Ok(())
}

/// Parses the arguments (with `--config` merged in), sets up logging, runs `body`, and turns its
/// result into the exit code: 0 ok, 1 runtime failure, 2 bad input (usage errors, unreadable or
/// malformed files, invalid options). `A` must flatten [`Common`] as `common`.
pub fn run<A, F>(body: F) -> ExitCode
where
    A: clap::Parser + HasCommon,
    F: FnOnce(A, &Session) -> Result<()>,
{
    run_with(|c| c, body)
}

/// [`run`] with the command adjusted first by `tweak` (e.g. defaults known only at run time, so
/// that `--help` shows them).
pub fn run_with<A, F>(tweak: impl Fn(clap::Command) -> clap::Command, body: F) -> ExitCode
where
    A: clap::Parser + HasCommon,
    F: FnOnce(A, &Session) -> Result<()>,
{
    die_quietly_on_a_closed_pipe();
    let argv: Vec<OsString> = std::env::args_os().collect();
    let args = match parse::<A>(&argv, &tweak) {
        Ok(Parsed::Run(a)) => a,
        Ok(Parsed::Exit(code)) => return code,
        Err(e) => {
            eprintln!("error: {e:#}");
            return ExitCode::from(2);
        }
    };
    let common = args.common().clone();
    let level = match (common.quiet, common.verbose) {
        (true, _) => tracing::Level::ERROR,
        (false, 0) => tracing::Level::INFO,
        (false, 1) => tracing::Level::DEBUG,
        _ => tracing::Level::TRACE,
    };
    let _ = tracing_subscriber::fmt()
        .with_max_level(level)
        .with_target(false)
        .without_time()
        .with_ansi(std::io::stderr().is_terminal())
        .with_writer(|| LogWriter)
        .try_init();
    let session = Session {
        quiet: common.quiet,
    };
    let result = body(args, &session);
    if let Some(bar) = BAR.lock().unwrap_or_else(|e| e.into_inner()).take() {
        bar.finish_and_clear();
    }
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            if e.chain().any(|c| c.is::<Interrupted>()) {
                ExitCode::from(130)
            } else if e.chain().any(|c| c.is::<BadInput>()) {
                ExitCode::from(2)
            } else {
                ExitCode::from(1)
            }
        }
    }
}

/// Access to the shared flags inside a binary's arguments.
pub trait HasCommon {
    /// The shared flags.
    fn common(&self) -> &Common;
}

/// What parsing the command line gave: the arguments of a run, or an exit (help, --print-config, a
/// usage error).
pub enum Parsed<A> {
    /// Run with these arguments.
    Run(A),
    /// Exit with this code.
    Exit(ExitCode),
}

/// Parses `argv`; with `--config`, the file's options not given on the command line are added
/// before them (after the subcommand's name, when there is one: the file then holds that
/// subcommand's options) and the whole parsed again, so the file passes the same checks as flags.
fn parse<A: clap::Parser>(
    argv: &[OsString],
    tweak: &dyn Fn(clap::Command) -> clap::Command,
) -> Result<Parsed<A>> {
    parse_with(argv, tweak, &|path| {
        std::fs::read_to_string(path)
            .with_context(|| format!("reading {}", path.display()))
            .bad_input()
    })
}

/// `parse` with the config file's text from `load` (the fuzz target gives it from memory).
pub fn parse_with<A: clap::Parser>(
    argv: &[OsString],
    tweak: &dyn Fn(clap::Command) -> clap::Command,
    load: &dyn Fn(&Path) -> Result<String>,
) -> Result<Parsed<A>> {
    let first = match tweak(A::command()).try_get_matches_from(argv) {
        Ok(m) => m,
        Err(e) => return Ok(Parsed::Exit(clap_exit(e))),
    };
    let mut cmd = tweak(A::command());
    cmd.build();
    let (sub, given, at) = match first.subcommand() {
        Some((name, m)) => {
            let sub = cmd
                .find_subcommand(name)
                .expect("a parsed subcommand exists")
                .clone();
            let at = 1 + argv.iter().skip(1).position(|a| a == name).unwrap_or(0) + 1;
            (sub, m, at)
        }
        None => (cmd, &first, 1),
    };
    let mut full = argv.to_vec();
    let config = given.get_one::<PathBuf>("config").cloned();
    if let Some(path) = &config {
        let injected = config_args(&sub, given, &load(path)?, path)?;
        full.splice(at..at, injected);
    }
    let matches = match tweak(A::command()).try_get_matches_from(&full) {
        Ok(m) => m,
        Err(e) => {
            let path = config.expect("only --config adds arguments");
            let message = e.render().to_string();
            let first = message.lines().next().unwrap_or_default();
            let first = first.trim_start_matches("error: ");
            return Err(bad_input(format!("{}: {first}", path.display())));
        }
    };
    let leaf = matches.subcommand().map_or(&matches, |(_, m)| m);
    if leaf.get_flag("print_config") {
        print!("{}", effective_config(&sub, leaf));
        return Ok(Parsed::Exit(ExitCode::SUCCESS));
    }
    Ok(Parsed::Run(
        A::from_arg_matches(&matches).map_err(|e| bad_input(e.render()))?,
    ))
}

/// Prints clap's message (help, version or usage error) and gives its exit code (0 or 2).
fn clap_exit(e: clap::Error) -> ExitCode {
    let _ = e.print();
    ExitCode::from(e.exit_code().clamp(0, 255) as u8)
}

/// The options of a run: the arguments with a long flag, but not --config and its kin.
fn options(cmd: &clap::Command) -> impl Iterator<Item = &clap::Arg> {
    cmd.get_arguments().filter(|a| {
        !a.is_positional()
            && a.get_long().is_some_and(|l| !NOT_OPTIONS.contains(&l))
            && !matches!(
                a.get_action(),
                ArgAction::Help | ArgAction::HelpLong | ArgAction::HelpShort | ArgAction::Version
            )
    })
}

/// The command-line arguments a config file stands for, leaving out what the command line gives.
fn config_args(
    cmd: &clap::Command,
    given: &clap::ArgMatches,
    text: &str,
    path: &Path,
) -> Result<Vec<OsString>> {
    let table: toml::Table = toml::from_str(text)
        .with_context(|| format!("{}: not a TOML table of options", path.display()))
        .bad_input()?;
    let mut out = Vec::new();
    for (key, value) in &table {
        let Some(arg) = options(cmd).find(|a| a.get_long() == Some(key.as_str())) else {
            let keys: Vec<&str> = options(cmd).filter_map(|a| a.get_long()).collect();
            return Err(bad_input(format!(
                "{}: unknown key `{key}` (the keys are the long flags: {})",
                path.display(),
                keys.join(", ")
            )));
        };
        if given.value_source(arg.get_id().as_str()) == Some(ValueSource::CommandLine) {
            continue;
        }
        let flag = format!("--{key}");
        let wrong = |what: &str| {
            bad_input(format!(
                "{}: `{key}` must be {what}, not `{value}`",
                path.display()
            ))
        };
        match arg.get_action() {
            ArgAction::SetTrue | ArgAction::SetFalse => match value.as_bool() {
                Some(b) if b == matches!(arg.get_action(), ArgAction::SetTrue) => {
                    out.push(flag.into())
                }
                Some(_) => {}
                None => return Err(wrong("true or false")),
            },
            ArgAction::Count => {
                let n = value
                    .as_integer()
                    .filter(|n| (0..=255).contains(n))
                    .ok_or_else(|| wrong("a count"))?;
                out.extend((0..n).map(|_| OsString::from(&flag)));
            }
            _ => {
                let items = match value {
                    toml::Value::Array(a) => a.iter().map(scalar).collect::<Option<Vec<_>>>(),
                    v => scalar(v).map(|s| vec![s]),
                }
                .ok_or_else(|| wrong("a number, a string, a boolean or an array of them"))?;
                match arg.get_value_delimiter() {
                    Some(d) => out.push(format!("{flag}={}", items.join(&d.to_string())).into()),
                    None => out.extend(items.iter().map(|v| OsString::from(format!("{flag}={v}")))),
                }
            }
        }
    }
    Ok(out)
}

/// A TOML scalar as its command-line text.
fn scalar(v: &toml::Value) -> Option<String> {
    match v {
        toml::Value::String(s) => Some(s.clone()),
        toml::Value::Integer(i) => Some(i.to_string()),
        toml::Value::Float(f) => Some(f.to_string()),
        toml::Value::Boolean(b) => Some(b.to_string()),
        _ => None,
    }
}

/// The merged options as TOML, one key per long flag with a value (unset options are listed as
/// comments).
fn effective_config(cmd: &clap::Command, m: &clap::ArgMatches) -> String {
    let mut table = toml::Table::new();
    let mut unset = Vec::new();
    for arg in options(cmd) {
        let (id, key) = (
            arg.get_id().as_str(),
            arg.get_long().expect("options have one"),
        );
        let value = match arg.get_action() {
            ArgAction::SetTrue | ArgAction::SetFalse => toml::Value::Boolean(m.get_flag(id)),
            ArgAction::Count => toml::Value::Integer(m.get_count(id) as i64),
            _ => match m.get_raw(id) {
                None => {
                    unset.push(key);
                    continue;
                }
                Some(raw) => {
                    let items: Vec<toml::Value> =
                        raw.map(|s| typed(&s.to_string_lossy())).collect();
                    let many = arg.get_value_delimiter().is_some()
                        || matches!(arg.get_action(), ArgAction::Append);
                    if many {
                        toml::Value::Array(items)
                    } else {
                        items.into_iter().next().expect("a raw value")
                    }
                }
            },
        };
        table.insert(key.to_string(), value);
    }
    let mut text = toml::to_string(&table).expect("a table of scalars serialises");
    for key in unset {
        text.push_str(&format!("# {key}: not set\n"));
    }
    text
}

/// A command-line value as the TOML value that reads back to the same text.
fn typed(s: &str) -> toml::Value {
    if let Ok(i) = s.parse::<i64>() {
        if i.to_string() == s {
            return toml::Value::Integer(i);
        }
    }
    if let Ok(f) = s.parse::<f64>() {
        // exponent notation is kept as a number: Rust prints 1e-9 as 0.000000001, same value
        if f.is_finite() && (f.to_string() == s || s.contains(['e', 'E'])) {
            return toml::Value::Float(f);
        }
    }
    match s {
        "true" => toml::Value::Boolean(true),
        "false" => toml::Value::Boolean(false),
        _ => toml::Value::String(s.to_string()),
    }
}

/// Implements [`HasCommon`] for an arguments type with a flattened `common: Common` field.
macro_rules! has_common {
    ($t:ty) => {
        impl cli::HasCommon for $t {
            fn common(&self) -> &cli::Common {
                &self.common
            }
        }
    };
}
pub(crate) use has_common;
