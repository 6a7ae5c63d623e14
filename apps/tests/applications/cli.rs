//! The example binaries' command line (issue 7): `--help` with defaults, the config round trip
//! (`--print-config` then `--config` gives the same run), quiet output off a terminal, and the exit
//! codes (0 ok, 1 runtime failure, 2 bad input). Runs the binaries `cargo test` builds.

use crate::common::{result_json, run, scratch, text};
use std::path::Path;
use std::process::Output;

const BINARIES: [&str; 12] = [
    "rigid_slam",
    "nonrigid_slam",
    "nonrigid_register",
    "pose_graph",
    "bundle_adjustment",
    "curve_fitting",
    "generate",
    "evaluate",
    "preprocess_bench",
    "tsdf_bench",
    "long_run",
    "generate_problem",
];

#[test]
fn every_binary_has_help_with_defaults_and_the_shared_flags() {
    for name in BINARIES {
        // the binaries with subcommands show their options under a subcommand
        let args: &[&str] = match name {
            "generate" => &["rigid", "--help"],
            "evaluate" => &["ate", "--help"],
            "generate_problem" => &["bal", "--help"],
            "nonrigid_register" => &["meshes", "--help"],
            _ => &["--help"],
        };
        let out = run(name, args);
        let help = text(&out.stdout);
        assert!(
            out.status.success(),
            "{name} --help failed: {}",
            text(&out.stderr)
        );
        for needle in [
            "Usage:",
            "[default: ",
            "--config <FILE>",
            "--print-config",
            "-q, --quiet",
            "-v, --verbose",
        ] {
            assert!(
                help.contains(needle),
                "{name} --help lacks `{needle}`:\n{help}"
            );
        }
    }
}

#[test]
fn print_config_then_config_gives_the_same_options_and_the_same_run() {
    let dir = scratch("roundtrip");
    for (name, flags) in [
        (
            "pose_graph",
            &[
                "--max-iterations",
                "7",
                "--algorithm",
                "lm",
                "--tau",
                "1e-5",
            ][..],
        ),
        (
            "bundle_adjustment",
            &[
                "--max-iterations",
                "50",
                "--huber",
                "2.5",
                "--linear-solver",
                "schur-sparse",
            ][..],
        ),
        (
            "curve_fitting",
            &["--points", "120", "--outliers", "0.1", "--seed", "7"][..],
        ),
    ] {
        let printed = run(name, &[flags, &["--print-config"]].concat());
        assert!(
            printed.status.success(),
            "{name}: {}",
            text(&printed.stderr)
        );
        let toml_text = text(&printed.stdout);
        let file = dir.join(format!("{name}.toml"));
        std::fs::write(&file, &toml_text).unwrap();
        let file_arg = file.to_str().unwrap();
        let reprinted = run(name, &["--config", file_arg, "--print-config"]);
        assert_eq!(
            text(&reprinted.stdout),
            toml_text,
            "{name}: the config does not read back"
        );
        let by_flags = run(name, &[flags, &["-q"]].concat());
        let by_file = run(name, &["--config", file_arg, "-q"]);
        assert!(
            by_flags.status.success() && by_file.status.success(),
            "{name}: {}",
            text(&by_file.stderr)
        );
        assert_eq!(
            result_json(&by_flags),
            result_json(&by_file),
            "{name}: different runs"
        );
    }
    // a flag on the command line wins over the file
    let file = dir.join("pose_graph.toml");
    let out = run(
        "pose_graph",
        &[
            "--config",
            file.to_str().unwrap(),
            "--max-iterations",
            "3",
            "--print-config",
        ],
    );
    let table: toml::Table = toml::from_str(&text(&out.stdout)).expect("TOML");
    assert_eq!(table["max-iterations"].as_integer(), Some(3));
    assert_eq!(table["algorithm"].as_str(), Some("lm"));
    let _ = std::fs::remove_dir_all(&dir);
}

fn assert_exit(out: &Output, code: i32, mentions: &[&str]) {
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(code), "stderr: {stderr}");
    assert!(!stderr.contains("panicked"), "a panic: {stderr}");
    for m in mentions {
        assert!(
            stderr.contains(m),
            "the message does not name `{m}`: {stderr}"
        );
    }
}

#[test]
fn bad_input_exits_2_and_runtime_failure_exits_1() {
    let dir = scratch("exit");
    let path = |name: &str| dir.join(name).to_str().unwrap().to_string();
    // config: unknown key, ill-typed value, missing file
    std::fs::write(dir.join("unknown.toml"), "max-iterations = 5\nbogus = 1\n").unwrap();
    assert_exit(
        &run("pose_graph", &["--config", &path("unknown.toml")]),
        2,
        &["unknown.toml", "bogus"],
    );
    std::fs::write(dir.join("typed.toml"), "max-iterations = \"many\"\n").unwrap();
    assert_exit(
        &run("pose_graph", &["--config", &path("typed.toml")]),
        2,
        &["typed.toml", "many"],
    );
    assert_exit(
        &run("pose_graph", &["--config", &path("absent.toml")]),
        2,
        &["absent.toml"],
    );
    // a usage error
    assert_exit(
        &run("bundle_adjustment", &["--linear-solver", "magic"]),
        2,
        &["magic"],
    );
    // malformed input files name the file and line
    std::fs::write(
        dir.join("bad.g2o"),
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 zero 0\n",
    )
    .unwrap();
    assert_exit(
        &run("pose_graph", &[&path("bad.g2o")]),
        2,
        &["bad.g2o", "2"],
    );
    std::fs::write(dir.join("bad.txt"), "1 1 1\n0 0 1.0 2.0\n").unwrap();
    assert_exit(
        &run("bundle_adjustment", &[&path("bad.txt")]),
        2,
        &["bad.txt"],
    );
    assert_exit(
        &run("rigid_slam", &[&path("no-such-sequence")]),
        2,
        &["no-such-sequence"],
    );
    // a tracking grid with stride 0 on a level
    assert_exit(
        &run("rigid_slam", &["--strides", "3,0,2"]),
        2,
        &["--strides"],
    );
    // a degeneracy floor that is not a ratio of eigenvalues (NaN included)
    for floor in ["-0.1", "1.5", "NaN"] {
        assert_exit(
            &run("rigid_slam", &[&format!("--min-conditioning={floor}")]),
            2,
            &["--min-conditioning"],
        );
    }
    assert_exit(
        &run("evaluate", &["ate", &path("none.txt"), &path("none.txt")]),
        2,
        &["none.txt"],
    );
    // a run that cannot write its output when it ends (procfs takes no new file) is a runtime
    // failure
    assert_exit(
        &run("pose_graph", &["--output", "/proc/dynamap-out.g2o", "-q"]),
        1,
        &["dynamap-out.g2o"],
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// An output in a folder that does not exist, or that is a folder, is refused before the run
/// (NOTES 171): before, the run went to its end and then failed, losing that output.
#[test]
fn outputs_that_could_not_be_written_are_refused_before_the_run() {
    let dir = scratch("outputs");
    let missing = dir.join("no-such-folder/out.g2o");
    let folder = dir.to_str().unwrap();
    for (app, flags, named) in [
        (
            "pose_graph",
            ["--output", missing.to_str().unwrap()],
            "does not exist",
        ),
        ("pose_graph", ["--output", folder], "is a folder"),
        (
            "rigid_slam",
            ["--mesh", missing.to_str().unwrap()],
            "no-such-folder",
        ),
        ("bundle_adjustment", ["--output", folder], "is a folder"),
    ] {
        let started = std::time::Instant::now();
        assert_exit(&run(app, &[&flags[..], &["-q"]].concat()), 2, &[named]);
        // before the default sequence is rendered or the default problem solved
        let seconds = started.elapsed().as_secs_f64();
        assert!(seconds < 5.0, "{app} {flags:?}: {seconds:.1} s");
    }
    let file = dir.join("a-file");
    std::fs::write(&file, "").unwrap();
    let under = file.join("preview");
    let preview = ["--preview", under.to_str().unwrap(), "-q"];
    assert_exit(&run("rigid_slam", &preview), 2, &["is a file"]);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Flag values outside what their settings mean are refused before anything runs, naming the
/// flag and the value. Before, a voxel of 0.01 mm or a truncation of 10⁹ voxels ran for hours,
/// negative weights and gates ran (a negative distance gate squared into the positive one),
/// zero iterations fused frames never registered, a frame of 100 000² pixels aborted on its
/// allocation (and 10¹² frames through the Python binding was killed for memory), 100 000 threads did not start in 30 s, and an RPE over an interval of 0 frames
/// gave figures as if over one.
#[test]
fn flags_outside_their_range_are_refused_before_a_run() {
    let cases: [(&str, &[&str], &str); 20] = [
        ("rigid_slam", &["--voxel-size", "1e-5"], "--voxel-size"),
        ("rigid_slam", &["--truncation", "1e9"], "--truncation"),
        ("rigid_slam", &["--iterations", "0,0,0"], "--iterations"),
        ("rigid_slam", &["--iterations", "1000000000"], "1000000000"),
        ("rigid_slam", &["--lambda=-1"], "--lambda"),
        ("rigid_slam", &["--lambda", "NaN"], "--lambda"),
        ("rigid_slam", &["--max-distance=-0.1"], "-0.1"),
        ("rigid_slam", &["--max-angle", "200"], "--max-angle"),
        ("rigid_slam", &["--fx=0"], "--fx"),
        ("nonrigid_slam", &["--rounds", "0"], "--rounds"),
        ("nonrigid_slam", &["--tukey", "NaN"], "--tukey"),
        ("nonrigid_slam", &["--data-level", "99"], "--data-level"),
        ("nonrigid_slam", &["--voxel-size", "1e-5"], "--voxel-size"),
        ("nonrigid_slam", &["--schedule=-1,2"], "--schedule"),
        (
            "nonrigid_slam",
            &["--max-frames", "1000000000000"],
            "--max-frames",
        ),
        (
            "nonrigid_register",
            &["sheets", "--columns", "100000"],
            "--columns",
        ),
        (
            "nonrigid_register",
            &["pairs", "--seeds", "1000000000"],
            "--seeds",
        ),
        ("pose_graph", &["--tau", "0"], "--tau"),
        (
            "pose_graph",
            &["--function-tolerance", "NaN"],
            "--function-tolerance",
        ),
        ("bundle_adjustment", &["--threads", "100000"], "--threads"),
    ];
    for (app, flags, named) in cases {
        let started = std::time::Instant::now();
        let out = run(app, &[flags, &["-q"]].concat());
        assert_exit(&out, 2, &[named]);
        // refused before the default sequence is rendered or a graph is solved
        let seconds = started.elapsed().as_secs_f64();
        assert!(seconds < 5.0, "{app} {flags:?}: {seconds:.1} s");
    }
    let dir = scratch("huge");
    let out = dir.join("out").to_str().unwrap().to_string();
    let huge = ["rigid", &out, "--width", "100000", "--height", "100000"];
    assert_exit(
        &run("generate", &[&huge[..], &["-q"]].concat()),
        2,
        &["--width"],
    );
    let long = ["rigid", &out, "--frames", "1000000000000", "-q"];
    assert_exit(&run("generate", &long), 2, &["--frames"]);
    // an RPE over no interval, and a stamp limit no pair can meet
    let gt = dir.join("gt.txt");
    std::fs::write(&gt, "0 0 0 0 0 0 0 1\n0.1 0.1 0 0 0 0 0 1\n").unwrap();
    let gt = gt.to_str().unwrap();
    for (flags, named) in [
        (["rpe", gt, gt, "--delta", "0"], "--delta"),
        (
            ["ate", gt, gt, "--max-difference=-1", "-q"],
            "--max-difference",
        ),
    ] {
        assert_exit(&run("evaluate", &flags), 2, &[named]);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// An empty trajectory is named, not left to a stamp search that finds nothing; a folder of no
/// sequence layout is named with the layouts it could be.
#[test]
fn an_empty_trajectory_and_a_folder_of_no_layout_are_named() {
    let dir = scratch("named");
    let path = |name: &str| dir.join(name).to_str().unwrap().to_string();
    std::fs::write(path("empty.txt"), "# timestamp tx ty tz qx qy qz qw\n").unwrap();
    let one = path("one.txt");
    std::fs::write(&one, "0 0 0 0 0 0 0 1\n").unwrap();
    assert_exit(
        &run("evaluate", &["rpe", &one, &path("empty.txt")]),
        2,
        &["empty.txt: no poses"],
    );
    let bare = dir.to_str().unwrap();
    assert_exit(
        &run("rigid_slam", &[bare]),
        2,
        &["no sequence layout", "rgb.txt"],
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn nonrigid_register_takes_one_subcommand_per_input_with_its_own_flags() {
    use dynamap_slam::io::ply;
    use dynamap_slam::synthetic::plate::{flat_grid, PlateDeformation};
    let dir = scratch("register");
    let path = |f: &str| dir.join(f).to_str().unwrap().to_string();
    let source = flat_grid();
    ply::write(dir.join("flat.ply"), &source).unwrap();
    ply::write(
        dir.join("bent.ply"),
        &PlateDeformation::ALL[0].deformed(&source),
    )
    .unwrap();
    // the grid's vertices keep their order, so vertex k's partner is vertex k
    let map: String = (0..source.vertices.len())
        .map(|k| format!("{k}\n"))
        .collect();
    std::fs::write(dir.join("map.txt"), map).unwrap();
    let out = run(
        "nonrigid_register",
        &[
            "meshes",
            &path("flat.ply"),
            &path("bent.ply"),
            "--ground-truth",
            &path("map.txt"),
            "--output",
            &path("warped.ply"),
            "-q",
        ],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let json = result_json(&out);
    let (before, after) = (
        json["error_before"]["mean"].as_f64().unwrap(),
        json["error_after"]["mean"].as_f64().unwrap(),
    );
    assert!(after < 0.2 * before, "{json}");
    let warped = dynamap_slam::io::meshes::read_mesh(dir.join("warped.ply")).unwrap();
    assert_eq!(warped.vertices.len(), source.vertices.len());
    // a frame's flag given to meshes, and a frame without its intrinsics, are usage errors
    let flow = run(
        "nonrigid_register",
        &[
            "meshes",
            &path("flat.ply"),
            &path("bent.ply"),
            "--flow",
            "f",
        ],
    );
    assert_exit(&flow, 2, &["--flow"]);
    let cover = run(
        "nonrigid_register",
        &["meshes", &path("flat.ply"), &path("bent.ply"), "--cover=-1"],
    );
    assert_exit(&cover, 2, &["--cover"]);
    let frames = run(
        "nonrigid_register",
        &[
            "frames",
            &path("a.png"),
            &path("b.png"),
            "--depth-scale",
            "1000",
        ],
    );
    assert_exit(&frames, 2, &["--intrinsics"]);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A source mesh without normals whose triangles are wound some one way, some the other (an OFF
/// file stitched from pieces), has them turned alike before its normals are computed: the JSON
/// counts them per mesh, and the plate registers as the consistently wound one does.
#[test]
fn a_mesh_wound_against_itself_is_counted_and_registers_as_the_consistent_one() {
    use dynamap_slam::io::ply;
    use dynamap_slam::synthetic::plate::{flat_grid, PlateDeformation};
    let dir = scratch("winding");
    let path = |f: &str| dir.join(f).to_str().unwrap().to_string();
    let source = flat_grid();
    let target = PlateDeformation::ALL[0].deformed(&source);
    ply::write(dir.join("bent.ply"), &target).unwrap();
    let corners: String = source
        .vertices
        .iter()
        .map(|p| format!("{} {} {}\n", p.x, p.y, p.z))
        .collect();
    let off = |turn_every: usize| {
        let faces: String = source
            .faces
            .iter()
            .enumerate()
            .map(|(k, &[a, b, c])| match k % turn_every {
                0 => format!("3 {a} {c} {b}\n"),
                _ => format!("3 {a} {b} {c}\n"),
            })
            .collect();
        let counts = format!("{} {} 0\n", source.vertices.len(), source.faces.len());
        format!("OFF\n{counts}{corners}{faces}")
    };
    let map: String = (0..source.vertices.len())
        .map(|k| format!("{k}\n"))
        .collect();
    std::fs::write(dir.join("map.txt"), map).unwrap();
    let register = |turn_every: usize| {
        std::fs::write(dir.join("flat.off"), off(turn_every)).unwrap();
        let out = run(
            "nonrigid_register",
            &[
                "meshes",
                &path("flat.off"),
                &path("bent.ply"),
                "--ground-truth",
                &path("map.txt"),
                "-q",
            ],
        );
        assert!(out.status.success(), "{}", text(&out.stderr));
        result_json(&out)
    };
    // every face's index is a multiple of `faces + 1` only for face 0: one triangle turned
    let (once, mixed) = (register(source.faces.len() + 1), register(4));
    let turned = source.faces.len().div_ceil(4);
    assert_eq!(
        once["faces_turned"],
        serde_json::json!({"source": 1, "target": 0})
    );
    assert_eq!(
        mixed["faces_turned"],
        serde_json::json!({"source": turned, "target": 0})
    );
    let error = |json: &serde_json::Value| json["error_after"]["mean"].as_f64().unwrap();
    assert!(
        (error(&mixed) - error(&once)).abs() <= 1e-9 + 1e-6 * error(&once),
        "{mixed}"
    );
    assert_eq!(mixed["registered"], once["registered"], "{mixed}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A Möbius strip cannot be wound alike throughout: the run says so, naming the file.
#[test]
fn a_surface_that_cannot_be_oriented_is_warned_of_by_name() {
    let dir = scratch("mobius");
    let path = |f: &str| dir.join(f).to_str().unwrap().to_string();
    let n = 24;
    let mut strip = format!("OFF\n{} {} 0\n", 2 * n, 2 * n);
    for k in 0..n {
        let t = std::f64::consts::TAU * k as f64 / n as f64;
        for w in [-0.2, 0.2] {
            let r = 1.0 + w * (t / 2.0).cos();
            strip += &format!("{} {} {}\n", r * t.cos(), r * t.sin(), w * (t / 2.0).sin());
        }
    }
    for k in 0..n {
        let (a, b) = (2 * k, 2 * k + 1);
        // the last quad joins the strip's ends with its sides swapped
        let (c, d) = if k + 1 == n { (1, 0) } else { (a + 2, b + 2) };
        strip += &format!("3 {a} {c} {b}\n3 {b} {c} {d}\n");
    }
    std::fs::write(dir.join("strip.off"), strip).unwrap();
    let out = run(
        "nonrigid_register",
        &["meshes", &path("strip.off"), &path("strip.off")],
    );
    let says = text(&out.stderr);
    assert!(
        says.contains("strip.off") && says.contains("cannot be wound alike"),
        "{says}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A plate registered onto a third of its bent copy covers the target but most of it lies off
/// it: the run writes its warped mesh and JSON line, says why it did not register, and exits 1, so
/// that no script takes it for a registration.
#[test]
fn a_registration_that_did_not_register_writes_its_outputs_and_exits_1() {
    use dynamap_slam::io::ply;
    use dynamap_slam::mesh::Mesh;
    use dynamap_slam::synthetic::plate::{flat_grid, PlateDeformation};
    let dir = scratch("unregistered");
    let path = |f: &str| dir.join(f).to_str().unwrap().to_string();
    let source = flat_grid();
    let bent = PlateDeformation::ALL[0].deformed(&source);
    let x = |k: usize| source.vertices[k].x;
    let (lo, hi) = (0..source.vertices.len())
        .map(x)
        .fold((f32::MAX, f32::MIN), |(a, b), v| (a.min(v), b.max(v)));
    let kept: Vec<bool> = (0..source.vertices.len())
        .map(|k| x(k) <= lo + (hi - lo) / 3.0 + 1e-6)
        .collect();
    let mut index = vec![usize::MAX; kept.len()];
    let mut part = Mesh::default();
    for (k, _) in kept.iter().enumerate().filter(|(_, &keep)| keep) {
        index[k] = part.vertices.len();
        part.vertices.push(bent.vertices[k]);
    }
    part.faces = bent
        .faces
        .iter()
        .filter(|f| f.iter().all(|&v| kept[v as usize]))
        .map(|f| f.map(|v| index[v as usize] as u32))
        .collect();
    ply::write(dir.join("flat.ply"), &source).unwrap();
    ply::write(dir.join("part.ply"), &part).unwrap();
    let out = run(
        "nonrigid_register",
        &[
            "meshes",
            &path("flat.ply"),
            &path("part.ply"),
            "--output",
            &path("warped.ply"),
        ],
    );
    let says = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{says}");
    assert_eq!(result_json(&out)["registered"], false);
    assert!(says.contains("not registered"), "{says}");
    let warped = ply::read(dir.join("warped.ply")).unwrap();
    assert_eq!(warped.vertices.len(), source.vertices.len());
    let _ = std::fs::remove_dir_all(&dir);
}

/// Vertices that no face uses (legal in PLY and OFF files) do not make a mesh larger: its
/// settings and its score scale with the surface itself, so a plate with two stray vertices
/// far off registers as the plate does. A surface with no extent, and a point cloud without
/// normals, are refused by name.
#[test]
fn stray_vertices_leave_a_registration_as_it_was_and_a_point_sized_mesh_is_refused() {
    use dynamap_slam::io::ply;
    use dynamap_slam::synthetic::plate::{flat_grid, PlateDeformation};
    let dir = scratch("stray");
    let path = |f: &str| dir.join(f).to_str().unwrap().to_string();
    let source = flat_grid();
    let bent = PlateDeformation::ALL[0].deformed(&source);
    let mut stray = source.clone();
    stray
        .vertices
        .push(nalgebra::Point3::new(100.0, 100.0, 100.0));
    stray
        .vertices
        .push(nalgebra::Point3::new(-100.0, 0.0, 50.0));
    stray.normals.clear();
    let mut point = source.clone();
    point
        .vertices
        .iter_mut()
        .for_each(|p| *p = nalgebra::Point3::origin());
    point.normals.clear();
    let mut cloud = bent.clone();
    cloud.faces.clear();
    cloud.normals.clear();
    for (name, mesh) in [
        ("flat", &source),
        ("bent", &bent),
        ("stray", &stray),
        ("point", &point),
        ("cloud", &cloud),
    ] {
        ply::write(dir.join(format!("{name}.ply")), mesh).unwrap();
    }
    let map = |n: usize| (0..n).map(|k| format!("{k}\n")).collect::<String>();
    std::fs::write(dir.join("map.txt"), map(source.vertices.len())).unwrap();
    // the strays' own partners: vertex 0, scored like any other
    std::fs::write(
        dir.join("map_stray.txt"),
        map(source.vertices.len()) + "0\n0\n",
    )
    .unwrap();
    let register = |from: &str, gt: &str| {
        let out = run(
            "nonrigid_register",
            &[
                "meshes",
                &path(from),
                &path("bent.ply"),
                "--ground-truth",
                &path(gt),
                "-q",
            ],
        );
        assert!(out.status.success(), "{}", text(&out.stderr));
        result_json(&out)
    };
    let (plain, with_strays) = (
        register("flat.ply", "map.txt"),
        register("stray.ply", "map_stray.txt"),
    );
    let tolerance = |j: &serde_json::Value| j["fit"]["tolerance"].as_f64().unwrap();
    let median = |j: &serde_json::Value| j["fit"]["median_distance"].as_f64().unwrap();
    assert_eq!(
        tolerance(&plain),
        tolerance(&with_strays),
        "{plain}\n{with_strays}"
    );
    assert!(
        median(&with_strays) <= 1.5 * median(&plain),
        "{plain}\n{with_strays}"
    );
    let refused = run(
        "nonrigid_register",
        &["meshes", &path("point.ply"), &path("bent.ply")],
    );
    assert_exit(&refused, 2, &["point.ply", "no extent"]);
    // a cloud has no triangles to compute its normals from
    let refused = run(
        "nonrigid_register",
        &["meshes", &path("flat.ply"), &path("cloud.ply")],
    );
    assert_exit(&refused, 2, &["cloud.ply", "needs normals"]);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A vertex that is not a place (NaN, or infinite) made the centroid or the extent NaN or
/// infinite, and the whole registration failed; now it is left out. A mesh whose triangles all
/// lie on one line was registered onto as a line; now it is refused, on either side.
#[test]
fn a_vertex_that_is_not_finite_is_left_out_and_a_mesh_without_area_is_refused() {
    use dynamap_slam::io::ply;
    use dynamap_slam::synthetic::plate::{flat_grid, PlateDeformation};
    let dir = scratch("unplaced");
    let path = |f: &str| dir.join(f).to_str().unwrap().to_string();
    let source = flat_grid();
    let mut unplaced = source.clone();
    unplaced.vertices[3] = nalgebra::Point3::new(f32::NAN, 0.0, 0.0);
    unplaced.vertices[7] = nalgebra::Point3::new(f32::INFINITY, 0.0, 0.0);
    unplaced.normals.clear();
    let mut line = source.clone();
    (line.vertices.iter_mut().enumerate()).for_each(|(k, p)| *p = [k as f32, 0.0, 0.0].into());
    line.normals.clear();
    let bent = PlateDeformation::ALL[0].deformed(&source);
    for (name, mesh) in [
        ("flat", &source),
        ("bent", &bent),
        ("unplaced", &unplaced),
        ("line", &line),
    ] {
        ply::write(dir.join(format!("{name}.ply")), mesh).unwrap();
    }
    let register = |from: &str| {
        let out = run(
            "nonrigid_register",
            &["meshes", &path(from), &path("bent.ply"), "-q"],
        );
        assert!(out.status.success(), "{}", text(&out.stderr));
        result_json(&out)
    };
    let (plain, unplaced) = (register("flat.ply"), register("unplaced.ply"));
    // … and the run says so
    let told = run(
        "nonrigid_register",
        &["meshes", &path("unplaced.ply"), &path("bent.ply")],
    );
    let stderr = text(&told.stderr);
    assert!(
        stderr.contains("2 of") && stderr.contains("not finite"),
        "{stderr}"
    );
    let fit = |j: &serde_json::Value, key: &str| j["fit"][key].as_f64().unwrap();
    assert_eq!(
        fit(&plain, "tolerance"),
        fit(&unplaced, "tolerance"),
        "{unplaced}"
    );
    let median = |j: &serde_json::Value| fit(j, "median_distance");
    assert!(
        median(&unplaced) <= 1.5 * median(&plain),
        "{plain}\n{unplaced}"
    );
    assert_eq!(unplaced["registered"], true, "{unplaced}");
    for (source, target) in [("line.ply", "bent.ply"), ("flat.ply", "line.ply")] {
        let refused = run(
            "nonrigid_register",
            &["meshes", &path(source), &path(target)],
        );
        assert_exit(&refused, 2, &["line.ply", "no area"]);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_reader_that_stops_early_ends_the_run_without_a_panic() {
    use std::process::{Command, Stdio};
    // the grid experiment prints a table row per target; its reader is gone before the first
    let mut child = Command::new(crate::common::binary("nonrigid_register"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let stderr = text(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
}

/// Writes a generated bundle adjustment of 8 cameras with outliers to `path` as BAL.
fn generate_small_bal(path: &str) {
    let gen = run(
        "generate_problem",
        &[
            "bal",
            path,
            "--cameras",
            "8",
            "--points-per-camera",
            "10",
            "--views",
            "3:6",
            "-q",
        ],
    );
    assert!(gen.status.success(), "{}", text(&gen.stderr));
}

#[test]
fn robust_kernels_from_the_command_line_and_generated_problems() {
    let dir = scratch("robust");
    let path = |name: &str| dir.join(name).to_string_lossy().into_owned();
    // a bundle adjustment with outliers, written as BAL, solved under Cauchy
    let bal = path("bal.txt");
    generate_small_bal(&bal);
    let solved = run("bundle_adjustment", &[&bal, "--kernel", "cauchy:2", "-q"]);
    assert!(solved.status.success(), "{}", text(&solved.stderr));
    let d = result_json(&solved);
    assert_eq!(d["kernel"], "cauchy:2");
    let costs = d["costs"].as_array().unwrap();
    assert_eq!(costs.len(), d["iterations"].as_u64().unwrap() as usize + 1);
    assert!(d["cost_final"].as_f64().unwrap() < d["cost_initial"].as_f64().unwrap());
    // a pose graph with wrong loops under DCS converges
    let g2o = path("pg.g2o");
    let gen = run(
        "generate_problem",
        &[
            "pose-graph",
            &g2o,
            "--rings",
            "3",
            "--per-ring",
            "20",
            "--false-loops",
            "5",
            "-q",
        ],
    );
    assert!(gen.status.success(), "{}", text(&gen.stderr));
    let solved = run("pose_graph", &[&g2o, "--kernel", "dcs:1", "-q"]);
    assert!(solved.status.success(), "{}", text(&solved.stderr));
    assert_eq!(result_json(&solved)["converged"], true);
    // bad kernels and counts are refused with the flag named
    assert_exit(
        &run("bundle_adjustment", &[&bal, "--kernel", "l2:1"]),
        2,
        &["unknown robust kernel 'l2'"],
    );
    assert_exit(
        &run("pose_graph", &[&g2o, "--kernel", "dcs:-1"]),
        2,
        &["positive finite"],
    );
    assert_exit(
        &run("generate_problem", &["bal", &bal, "--cameras", "1"]),
        2,
        &["--cameras"],
    );
    assert_exit(
        &run("generate_problem", &["bal", &bal, "--views", "5:2"]),
        2,
        &["LO <= HI"],
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bundle_adjustment_writes_the_solved_problem_that_starts_where_it_ended() {
    let dir = scratch("bal-output");
    let path = |name: &str| dir.join(name).to_string_lossy().into_owned();
    let (bal, out) = (path("bal.txt"), path("solved.txt"));
    generate_small_bal(&bal);
    let solved = run(
        "bundle_adjustment",
        &[&bal, "--huber", "2", "-q", "--output", &out],
    );
    assert!(solved.status.success(), "{}", text(&solved.stderr));
    let d = result_json(&solved);
    let cost_final = d["cost_final"].as_f64().unwrap();
    assert!(cost_final < d["cost_initial"].as_f64().unwrap());
    let again = run(
        "bundle_adjustment",
        &[&out, "--huber", "2", "-q", "--max-iterations", "1"],
    );
    assert!(again.status.success(), "{}", text(&again.stderr));
    let start = result_json(&again)["cost_initial"].as_f64().unwrap();
    assert!(
        (start - cost_final).abs() <= 1e-9 * cost_final,
        "{start} against {cost_final}"
    );
    // an output that cannot be written is an error naming it
    let blocked = path("no-such-folder/solved.txt");
    let failed = run("bundle_adjustment", &[&bal, "-q", "--output", &blocked]);
    assert!(!failed.status.success());
    assert!(
        text(&failed.stderr).contains("no-such-folder"),
        "{}",
        text(&failed.stderr)
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn tum_calibrations_by_name_and_the_association_limit() {
    let dir = scratch("calibration");
    let seq = dir.join("seq");
    let seq = seq.to_str().unwrap();
    let gen = run(
        "generate",
        &["rigid", seq, "--frames", "3", "--gain-drift", "0.15", "-q"],
    );
    assert!(gen.status.success(), "{}", text(&gen.stderr));
    // fr1's published calibration, lens distortion included: the frames are undistorted and run
    let out = run("rigid_slam", &[seq, "--calibration", "fr1", "-q"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(result_json(&out)["frames"], 3);
    assert_exit(
        &run("rigid_slam", &[seq, "--calibration", "fr9"]),
        2,
        &["fr9"],
    );
    assert_exit(
        &run("rigid_slam", &[seq, "--max-difference=-1"]),
        2,
        &["--max-difference"],
    );
    // the generator's associations.txt pairs each capture's frames, whatever the stamp limit
    let listed = run("rigid_slam", &[seq, "--max-difference", "0", "-q"]);
    assert!(listed.status.success(), "{}", text(&listed.stderr));
    assert_eq!(result_json(&listed)["frames"], 3);
    odd_association_lines_are_left_out_or_warned_of(seq);
    // paired by stamps, pairs must be strictly closer than the limit (associate.py): 0 pairs
    // nothing, and says so
    let by_stamps = |limit: &str, quiet: bool| {
        let mut a = vec![seq, "--no-associations", "--max-difference", limit];
        if quiet {
            a.push("-q");
        }
        run("rigid_slam", &a)
    };
    assert_exit(&by_stamps("0", false), 2, &["depth.txt", "within 0 s"]);
    // the Kinect model's colour is taken 10-20 ms after the depth: 5 ms pairs nothing, 25 ms all
    assert_exit(
        &by_stamps("0.005", false),
        2,
        &["depth.txt", "within 0.005 s"],
    );
    let loose = by_stamps("0.025", true);
    assert!(loose.status.success(), "{}", text(&loose.stderr));
    assert_eq!(result_json(&loose)["frames"], 3);
    // evo's name for the stamp limit
    let gt = format!("{seq}/groundtruth.txt");
    let ev = run("evaluate", &["ate", &gt, &gt, "--t-max-diff", "0.01", "-q"]);
    assert!(ev.status.success(), "{}", text(&ev.stderr));
    assert_exit(
        &run("generate", &["rigid", seq, "--gain-drift", "1.5"]),
        2,
        &["--gain-drift"],
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// `rigid_slam` on the generated sequence `seq` with its `associations.txt` changed: a listed
/// pair further apart than a frame interval is left out with a warning; a line repeated word for
/// word is not warned of; a line whose stamp is not its list's is. The file is put back.
fn odd_association_lines_are_left_out_or_warned_of(seq: &str) {
    let list = format!("{seq}/associations.txt");
    let lines: Vec<String> = std::fs::read_to_string(&list)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(str::to_string)
        .collect();
    let (first, last) = (field_pair(&lines[0]), field_pair(&lines[2]));
    let stale = format!("{}\n{}\n{} {}\n", lines[0], lines[1], first.0, last.1);
    std::fs::write(&list, stale).unwrap();
    let far = run("rigid_slam", &[seq]);
    assert!(far.status.success(), "{}", text(&far.stderr));
    assert_eq!(result_json(&far)["frames"], 2);
    let says = text(&far.stderr);
    assert!(
        says.contains("associations.txt lines that pair frames more than")
            && says.contains("): 1;"),
        "{says}"
    );
    // a line repeated word for word loses nothing and is not warned of; a line whose stamp is
    // not its list's pairs its frames by the lists' stamps, with a warning
    let f: Vec<&str> = lines[1].split_whitespace().collect();
    let late: f64 = f[0].parse::<f64>().unwrap() + 0.5;
    let restamped = format!("{late:.6} {} {} {}", f[1], f[2], f[3]);
    let odd = format!("{}\n{}\n{restamped}\n{}\n", lines[0], lines[0], lines[2]);
    std::fs::write(&list, odd).unwrap();
    let out = run("rigid_slam", &[seq]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(result_json(&out)["frames"], 3);
    let says = text(&out.stderr);
    assert!(
        says.contains("stamps differ from rgb.txt's or depth.txt's")
            && says.contains(": 1 (up to 0.500 s)"),
        "{says}"
    );
    assert!(!says.contains("pair a frame another line pairs"), "{says}");
    std::fs::write(&list, lines.join("\n")).unwrap();
}

/// An `associations.txt` line's two halves, `stamp file` each, in the line's order.
fn field_pair(line: &str) -> (String, String) {
    let f: Vec<&str> = line.split_whitespace().collect();
    (format!("{} {}", f[0], f[1]), format!("{} {}", f[2], f[3]))
}

/// No carriage returns or bar glyphs: what a progress bar leaves in a log.
fn assert_no_bar(name: &str, stderr: &str) {
    assert!(
        !stderr.contains('\r') && !stderr.contains('█') && !stderr.contains("frames/s"),
        "{name} drew a progress bar into a pipe:\n{stderr}"
    );
}

#[test]
fn no_progress_bars_when_output_is_not_a_terminal() {
    let dir = scratch("quiet");
    let seq = dir.join("seq");
    let gen = run(
        "generate",
        &[
            "rigid",
            seq.to_str().unwrap(),
            "--frames",
            "4",
            "--width",
            "160",
            "--height",
            "120",
        ],
    );
    assert!(gen.status.success(), "{}", text(&gen.stderr));
    assert_no_bar("generate", &text(&gen.stderr));
    // without -q: log lines, but no bar (stderr is a pipe here, as in CI)
    let slam = run("rigid_slam", &[seq.to_str().unwrap()]);
    assert!(slam.status.success(), "{}", text(&slam.stderr));
    let stderr = text(&slam.stderr);
    assert_no_bar("rigid_slam", &stderr);
    assert!(
        stderr.contains("per frame"),
        "the stage log is missing: {stderr}"
    );
    // with -q: nothing on stderr, the JSON line on stdout
    let quiet = run("rigid_slam", &[seq.to_str().unwrap(), "-q"]);
    assert!(quiet.status.success());
    assert_eq!(text(&quiet.stderr), "", "-q printed on stderr");
    assert_eq!(result_json(&quiet)["frames"], 4);
    let solve = run("pose_graph", &[]);
    assert_no_bar("pose_graph", &text(&solve.stderr));
    assert!(
        text(&solve.stdout).contains("iter"),
        "the iteration table is missing"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// The README's pictures come from `--preview`: a run writes every one, as non-trivial PNGs.
#[test]
fn preview_writes_the_pictures() {
    let dir = scratch("preview");
    let out = run(
        "bundle_adjustment",
        &["--preview", dir.to_str().unwrap(), "-q"],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let img = dynamap_slam::io::images::read_color(dir.join("cost.png")).expect("a PNG");
    // a white page with a plotted line: not one colour
    let first = img.data[0];
    assert!(img.data.iter().filter(|p| **p != first).count() > 1000);
    let _ = std::fs::remove_dir_all(Path::new(&dir));
}

/// Each case within the 10 % largest and 3 % mean error, the target meshed apart; the
/// saddle alone within 4 % mean, as its rim is placed by a convention the generated saddle does
/// not follow (NOTES 84).
/// `nonrigid_register sheets`' table: a header, ten cases (five shapes, alone and moved
/// rigidly), the worst; each case within the bounds above.
fn assert_sheet_rows(stdout: &str) {
    assert_eq!(stdout.lines().count(), 12, "{stdout}");
    let percentages = |line: &str| -> Vec<f64> {
        line.split('|')
            .nth(1)
            .unwrap_or("")
            .split_whitespace()
            .filter_map(|w| w.parse().ok())
            .collect()
    };
    for line in stdout.lines().skip(1).take(10) {
        let errors = percentages(line);
        assert_eq!(errors.len(), 2, "{line}");
        let mean_bound = if line.starts_with("saddle") && !line.contains("rigid") {
            4.0
        } else {
            3.0
        };
        assert!(errors[0] <= 10.0 && errors[1] <= mean_bound, "{line}");
        assert!(line.ends_with(" yes"), "registered: {line}");
    }
    let worst = stdout.lines().last().unwrap();
    assert!(worst.starts_with("worst: max"), "{worst}");
}

/// An OFF file of a flat 0.8 × 0.48 m sheet at (5, −2, 3), a grid of `columns` × `rows`
/// vertices whose cells are split along alternating diagonals.
fn checkerboard_sheet_off(columns: usize, rows: usize) -> String {
    let mut off = format!(
        "OFF\n{} {} 0\n",
        columns * rows,
        2 * (columns - 1) * (rows - 1)
    );
    for j in 0..rows {
        for i in 0..columns {
            let x = 5.0 + 0.8 * i as f64 / (columns - 1) as f64;
            let y = -2.0 + 0.48 * j as f64 / (rows - 1) as f64;
            off += &format!("{x} {y} 3\n");
        }
    }
    for j in 0..rows - 1 {
        for i in 0..columns - 1 {
            let v = j * columns + i;
            let (a, b, c, d) = (v, v + 1, v + columns + 1, v + columns);
            if (i + j) % 2 == 0 {
                off += &format!("3 {a} {b} {c}\n3 {a} {c} {d}\n");
            } else {
                off += &format!("3 {a} {b} {d}\n3 {b} {c} {d}\n");
            }
        }
    }
    off
}

#[test]
fn nonrigid_register_sheets_prints_each_case_and_the_worst() {
    let sheets = |extra: &[&str]| {
        let mut args = vec!["sheets", "--sizes", "0.3", "--columns", "21", "-q"];
        args.extend_from_slice(extra);
        let out = run("nonrigid_register", &args);
        assert!(out.status.success(), "{}", text(&out.stderr));
        assert_sheet_rows(&text(&out.stdout));
    };
    sheets(&["--remeshed"]);
    // a flat mesh made elsewhere: another size and place, the grid's diagonals alternating
    let dir = scratch("sheets");
    let flat = dir.join("flat.off");
    std::fs::write(&flat, checkerboard_sheet_off(27, 17)).unwrap();
    sheets(&["--target-mesh", flat.to_str().unwrap()]);
    let tetrahedron = dir.join("solid.off");
    std::fs::write(
        &tetrahedron,
        "OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n",
    )
    .unwrap();
    assert_exit(
        &run(
            "nonrigid_register",
            &["sheets", "--target-mesh", tetrahedron.to_str().unwrap()],
        ),
        2,
        &["solid.off", "flat sheet"],
    );
    let _ = std::fs::remove_dir_all(&dir);
    assert_exit(
        &run("nonrigid_register", &["sheets", "--sizes=-1"]),
        2,
        &["--sizes"],
    );
    assert_exit(
        &run("nonrigid_register", &["sheets", "--columns", "2"]),
        2,
        &["--columns"],
    );
}

/// `pairs`: one row per generated pair (three surfaces × three fields for one seed) and the
/// mean; no seeds and a negative `--nearest-within` are bad input.
#[test]
fn nonrigid_register_pairs_prints_each_pair_and_the_mean() {
    let out = run(
        "nonrigid_register",
        &["pairs", "--seeds", "1", "--first-seed", "4", "-q"],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 11, "{stdout}");
    assert!(
        lines[0].starts_with("pair") && lines[1].starts_with("plane-bend-4"),
        "{stdout}"
    );
    assert!(
        lines[10].starts_with("mean EPE") && lines[10].ends_with("not registered"),
        "{stdout}"
    );
    // the pairs have colour: each row ends with its colour check, "<fraction off> of <patches>"
    for line in &lines[1..10] {
        let words: Vec<&str> = line.split_whitespace().rev().take(3).collect();
        assert!(
            words[1] == "of"
                && words[0].parse::<usize>().is_ok()
                && words[2].parse::<f64>().is_ok(),
            "{line}"
        );
    }
    assert_exit(
        &run("nonrigid_register", &["pairs", "--seeds", "0"]),
        2,
        &["--seeds"],
    );
    assert_exit(
        &run("nonrigid_register", &["pairs", "--nearest-within=-1"]),
        2,
        &["--nearest-within"],
    );
}

/// `frames` without a mask: the object from graph nodes, the verdict and the surface distance in
/// the JSON, and the picture; a cut nodes file is bad input naming the file, and so are a
/// negative `--nearest-within`, a colour image of another size and a blank source depth.
#[test]
fn nonrigid_register_frames_masks_by_nodes_and_reports_its_verdict() {
    use dynamap_slam::image::{ColorImage, Image};
    use dynamap_slam::io::deepdeform::encode_graph_nodes;
    use dynamap_slam::io::images::{read_color, write_color, write_depth};
    use nalgebra::Vector3;

    let dir = scratch("frames_nodes");
    let path = |name: &str| dir.join(name).to_str().unwrap().to_string();
    // a wall with a bump in the middle, and the same bump 1 cm nearer: millimetres, 160 × 120
    let wall = |shift: f64| {
        let data = (0..160 * 120)
            .map(|i| {
                let (x, y) = ((i % 160) as f64 - 80.0, (i / 160) as f64 - 60.0);
                let bump = 60.0 * (-(x * x + y * y) / 800.0).exp();
                (1000.0 - bump - shift) as u16
            })
            .collect();
        Image::from_vec(160, 120, data).unwrap()
    };
    write_depth(path("a.png"), &wall(0.0)).unwrap();
    write_depth(path("b.png"), &wall(10.0)).unwrap();
    let nodes = [Vector3::new(0.0, 0.0, 0.95)];
    std::fs::write(path("nodes.bin"), encode_graph_nodes(&nodes)).unwrap();
    let args = |nodes: &str| {
        vec![
            "frames".to_string(),
            path("a.png"),
            path("b.png"),
            "--intrinsics".into(),
            "150".into(),
            "150".into(),
            "79.5".into(),
            "59.5".into(),
            "--depth-scale".into(),
            "1000".into(),
            "--mask-nodes".into(),
            path(nodes),
            "--spacing".into(),
            "0.1".into(),
            "--picture".into(),
            path("pair.png"),
            "-q".into(),
        ]
    };
    let run_with = |a: Vec<String>| {
        let a: Vec<&str> = a.iter().map(String::as_str).collect();
        run("nonrigid_register", &a)
    };
    let out = run_with(args("nodes.bin"));
    assert!(out.status.success(), "{}", text(&out.stderr));
    let json = result_json(&out);
    assert_eq!(json["registered"], true, "{json}");
    assert!(
        json["colour_check"].is_null(),
        "no colour, no colour check: {json}"
    );
    let d = &json["surface_distance"];
    let (before, after) = (d["before"].as_f64().unwrap(), d["after"].as_f64().unwrap());
    assert!(before > 0.005 && after < 0.5 * before, "{json}");
    // only the pixels near the node are the object: far fewer than the frame's
    assert!(json["points"].as_u64().unwrap() < 160 * 120 / 2, "{json}");
    let picture = read_color(path("pair.png")).unwrap();
    assert_eq!((picture.width, picture.height), (320, 120));
    let bytes = std::fs::read(path("nodes.bin")).unwrap();
    std::fs::write(path("cut.bin"), &bytes[..bytes.len() - 2]).unwrap();
    assert_exit(&run_with(args("cut.bin")), 2, &["cut.bin"]);
    let mut both = args("nodes.bin");
    both.extend(["--mask".to_string(), path("a.png")]);
    assert_exit(&run_with(both), 2, &["--mask"]);
    let mut negative = args("nodes.bin");
    negative.push("--nearest-within=-0.1".to_string());
    assert_exit(&run_with(negative), 2, &["--nearest-within", "-0.1"]);
    // a colour of another size than the depth, and a mask with no depth in it: bad input
    write_color(path("small.png"), &ColorImage::filled(80, 60, [9, 9, 9])).unwrap();
    let mut small = args("nodes.bin");
    small.extend(["--color".to_string(), path("small.png")]);
    assert_exit(&run_with(small), 2, &["80×60", "160×120"]);
    write_depth(path("blank.png"), &Image::new(160, 120)).unwrap();
    let mut blank = args("nodes.bin");
    blank[1] = path("blank.png");
    assert_exit(&run_with(blank), 2, &["no valid depth"]);
    let _ = std::fs::remove_dir_all(Path::new(&dir));
}

#[test]
fn curve_fitting_fits_observations_from_a_file_and_names_a_bad_line() {
    let dir = scratch("curve_fitting_data");
    // exact samples of exp(0.3 x + 0.1) with two gross outliers: the Cauchy fit recovers (m, c)
    let mut lines = String::from("# x y\n");
    for i in 0..60 {
        let x = i as f64 / 12.0;
        let y = if i % 29 == 5 {
            7.5
        } else {
            (0.3 * x + 0.1f64).exp()
        };
        lines.push_str(&format!("{x} {y}\n"));
    }
    let good = dir.join("points.txt");
    std::fs::write(&good, &lines).unwrap();
    let out = run("curve_fitting", &["--data", good.to_str().unwrap(), "-q"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let json = result_json(&out);
    assert_eq!(json["points"], 60);
    assert!(json["robust_error"].as_f64().unwrap() < 1e-3, "{json}");
    assert!(json["robust_iterations"].as_u64().unwrap() > 0);
    // the same file saved with a byte-order mark and CRLF line ends reads the same points
    let marked = dir.join("marked.txt");
    std::fs::write(&marked, format!("\u{feff}{}", lines.replace('\n', "\r\n"))).unwrap();
    let out = run("curve_fitting", &["--data", marked.to_str().unwrap(), "-q"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(result_json(&out)["points"], 60);
    let bad = dir.join("bad.txt");
    std::fs::write(&bad, "0 1\n1 2\n2 3 x\n").unwrap();
    let out = run("curve_fitting", &["--data", bad.to_str().unwrap(), "-q"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        text(&out.stderr).contains("bad.txt:3: expected two finite numbers"),
        "{}",
        text(&out.stderr)
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// The generated sequence from the structured-light sensor model: a waving plate is tracked
/// with every frame fused and within a centimetre; a bad sensor name and photometric settings
/// out of range are refused as bad input.
#[test]
fn nonrigid_slam_tracks_a_wave_seen_by_the_kinect_model() {
    let out = run(
        "nonrigid_slam",
        &[
            "--field",
            "wave",
            "--sensor",
            "kinect",
            "--max-frames",
            "12",
            "--quiet",
        ],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let v = result_json(&out);
    assert_eq!(v["failures"], 0, "{v}");
    let worst = v["error_max_frame"].as_f64().expect("an error");
    assert!(worst < 0.01, "worst frame {worst} m");
    // the camera sees the whole plate, so the error over the samples it sees is the error over
    // all of them, and no fused frame is off by a centimetre
    let field = |k: &str| v[k].as_f64().unwrap_or_else(|| panic!("no {k} in {v}"));
    let (mean, seen) = (field("error_mean"), field("error_seen_mean"));
    assert!(seen > 0.0 && (seen - mean).abs() <= 0.1 * mean, "{v}");
    assert!(field("error_seen_max_frame") <= worst + 1e-6, "{v}");
    assert!(field("error_seen_max_fused") < 0.01, "{v}");
    assert_exit(
        &run("nonrigid_slam", &["--sensor", "tof", "--quiet"]),
        2,
        &["tof"],
    );
    assert_exit(
        &run("nonrigid_slam", &["--photometric-weight=-1", "--quiet"]),
        2,
        &["--photometric-weight"],
    );
    assert_exit(
        &run("nonrigid_slam", &["--photometric-tukey", "0", "--quiet"]),
        2,
        &["--photometric-tukey"],
    );
    assert_exit(
        &run(
            "nonrigid_slam",
            &["--photometric-keyframe-every", "0", "--quiet"],
        ),
        2,
        &["--photometric-keyframe-every"],
    );
    assert_exit(
        &run("nonrigid_slam", &["--chroma-weight", "nan", "--quiet"]),
        2,
        &["--chroma-weight"],
    );
    assert_exit(
        &run("nonrigid_slam", &["--chroma-tukey=-0.1", "--quiet"]),
        2,
        &["--chroma-tukey"],
    );
}
