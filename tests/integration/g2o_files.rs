//! The g2o reader on damaged input (never a panic, always file:line and the field), writing through a
//! temporary file, and the initialisations that fill in missing vertices.

use dynamap::residuals::pose_graph::synthetic::{self, max_pose_error, SyntheticOptions};
use dynamap::residuals::pose_graph::{g2o, init};
use dynamap::solver::{Options, Solver};
use proptest::prelude::*;

/// A small valid file: a 2-ring sphere graph (3D) or circle graph (2D).
fn sample(planar: bool) -> String {
    let o = SyntheticOptions {
        rings: 2,
        per_ring: 4,
        ..SyntheticOptions::default()
    };
    let s = if planar {
        synthetic::circle(&o)
    } else {
        synthetic::sphere(&o)
    };
    g2o::format(&s.graph, &s.graph.vertices)
}

/// Parses, and if that succeeds builds and solves: none of it may panic, and a parse error names
/// `f.g2o` and a line within the file.
fn exercise(text: &str) {
    match g2o::parse(text, "f.g2o") {
        Ok(graph) => {
            for start in [Ok(graph.vertices.clone()), init::odometry(&graph)] {
                let Ok(start) = start else { continue };
                if let Ok(mut pg) = graph.build_problem(&start) {
                    let _ = Solver::new(Options {
                        max_iterations: 3,
                        ..Options::default()
                    })
                    .solve(&mut pg.problem);
                }
            }
        }
        Err(e) => {
            assert_eq!(e.path, "f.g2o");
            assert!(e.line <= text.lines().count(), "{e}");
            // a fault of the whole file (line 0, e.g. an empty one) is named without a line
            let place = if e.line == 0 {
                "f.g2o: ".to_string()
            } else {
                format!("f.g2o:{}: ", e.line)
            };
            assert!(e.to_string().starts_with(&place), "{e}");
        }
    }
}

/// The truncation at 0 bytes, which the property below draws only now and then (it failed CI's
/// third run this session: the assertion expected `f.g2o:0: ` where the message, rightly, names
/// no line).
#[test]
fn an_empty_file_is_refused_as_a_whole() {
    exercise("");
    let e = g2o::parse("", "f.g2o").unwrap_err();
    assert_eq!(e.line, 0);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    #[test]
    fn truncated_files_never_panic(cut in 0usize..4000, planar in any::<bool>()) {
        let text = sample(planar);
        let cut = cut.min(text.len());
        exercise(&text[..cut]);
    }

    #[test]
    fn corrupted_tokens_never_panic(line in 0usize..64, token in 0usize..40, junk in prop::sample::select(vec![
        "nan", "NaN", "inf", "-inf", "1e999", "", "x", "-3", "0", "1e-320", "VERTEX_SE2", "FIX", "99999999999999999999999",
    ])) {
        let text = sample(false);
        let mut lines: Vec<Vec<String>> = text.lines().map(|l| l.split_whitespace().map(String::from).collect()).collect();
        let n = lines.len();
        let l = &mut lines[line % n];
        let k = token % l.len();
        l[k] = junk.to_string();
        let damaged: String = lines.iter().map(|l| l.join(" ") + "\n").collect();
        exercise(&damaged);
    }

    #[test]
    fn shuffled_and_duplicated_lines_never_panic(picks in prop::collection::vec(0usize..64, 1..40)) {
        let text = sample(true);
        let lines: Vec<&str> = text.lines().collect();
        let damaged: String = picks.iter().map(|&i| lines[i % lines.len()].to_string() + "\n").collect();
        exercise(&damaged);
    }
}

#[test]
fn missing_vertices_are_named_and_odometry_fills_them() {
    let s = synthetic::circle(&SyntheticOptions {
        rings: 3,
        per_ring: 10,
        rotation_noise: 0.0,
        translation_noise: 0.0,
        ..SyntheticOptions::default()
    });
    let text = g2o::format(&s.graph, &s.graph.vertices);
    // Drop the vertex lines of 5 and 17.
    let text: String = text
        .lines()
        .filter(|l| !(l.starts_with("VERTEX_SE2 5 ") || l.starts_with("VERTEX_SE2 17 ")))
        .map(|l| format!("{l}\n"))
        .collect();
    let graph = g2o::parse(&text, "holes.g2o").unwrap();
    let err = graph.build_problem(&graph.vertices).err().unwrap();
    assert!(
        err.starts_with("holes.g2o:") && err.contains("refers to vertex 5, which has no pose"),
        "{err}"
    );
    // Exact measurements: the spanning tree reproduces the ground truth, holes included.
    let start = init::odometry(&graph).unwrap();
    let (dt, dr) = max_pose_error(&start, &s.truth);
    assert!(dt < 1e-9 && dr < 1e-9, "{dt} {dr}");
}

#[test]
fn chordal_initialisation_recovers_exact_graphs() {
    for s in [
        synthetic::sphere(&SyntheticOptions {
            rings: 6,
            per_ring: 12,
            ..SyntheticOptions::default()
        }),
        synthetic::circle(&SyntheticOptions {
            rings: 6,
            per_ring: 12,
            ..SyntheticOptions::default()
        }),
    ] {
        let start = init::chordal(&s.graph).unwrap();
        let (dt, dr) = max_pose_error(&start, &s.truth);
        assert!(dt < 1e-8 && dr < 1e-8, "{}: {dt} {dr}", s.graph.source);
    }
}

/// A graph in two pieces (no edge joins them, as the maps of a SLAM run that no loop joined) has
/// a gauge freedom in each: each piece is held by its lowest vertex where the file puts it, the
/// initialisers start from those, and the solve reaches each piece's optimum. A vertex that no
/// edge touches is still refused by name.
#[test]
fn a_graph_in_two_pieces_is_held_by_the_lowest_vertex_of_each() {
    let o = SyntheticOptions {
        rings: 3,
        per_ring: 8,
        ..SyntheticOptions::default()
    };
    for s in [synthetic::circle(&o), synthetic::sphere(&o)] {
        let shift = 1000;
        let mut graph = s.graph.clone();
        let mut truth = s.truth.clone();
        for (id, pose) in &s.graph.vertices {
            graph.vertices.insert(id + shift, *pose);
            truth.insert(id + shift, s.truth[id]);
        }
        for e in &s.graph.edges {
            let mut e = e.clone();
            (e.from, e.to) = (e.from + shift, e.to + shift);
            graph.edges.push(e);
        }
        let first = *s.graph.vertices.keys().next().unwrap();
        assert_eq!(graph.components(), 2);
        assert_eq!(graph.anchors(), vec![first, first + shift]);
        for start in [
            graph.vertices.clone(),
            init::odometry(&graph).unwrap(),
            init::chordal(&graph).unwrap(),
        ] {
            let mut pg = graph.build_problem(&start).unwrap();
            let summary = Solver::new(Options::default())
                .solve(&mut pg.problem)
                .unwrap();
            assert!(summary.termination.converged(), "{summary:?}");
            let poses = pg.poses();
            assert!(graph.chi2(&poses) < 1e-12, "{}", graph.chi2(&poses));
            let anchors = |p: &std::collections::BTreeMap<usize, _>| {
                graph.anchors().iter().map(|a| (*a, p[a])).collect()
            };
            let (dt, dr) = max_pose_error(&anchors(&poses), &anchors(&graph.vertices));
            assert!(dt < 1e-12 && dr < 1e-12, "the anchors moved: {dt} {dr}");
            // each piece's optimum is the truth moved rigidly; its anchor starts on the truth
            let (dt, dr) = max_pose_error(&poses, &truth);
            assert!(dt < 1e-6 && dr < 1e-6, "{}: {dt} {dr}", s.graph.source);
        }
    }
    let text = format!("{}VERTEX_SE2 100 5 5 0\n", sample(true));
    let graph = g2o::parse(&text, "lone.g2o").unwrap();
    assert_eq!(graph.components(), 1);
    let err = init::odometry(&graph).unwrap_err();
    assert!(err.contains("vertex 100 is touched by no edge"), "{err}");
    assert!(init::chordal(&graph).is_err());
}

#[test]
fn writing_goes_through_a_temporary_file_and_round_trips() {
    let dir = std::env::temp_dir().join(format!("dynamap-g2o-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("out.g2o");
    let s = synthetic::sphere(&SyntheticOptions {
        rings: 3,
        per_ring: 5,
        ..SyntheticOptions::default()
    });
    g2o::write(&path, &s.graph, &s.truth).unwrap();
    let back = g2o::read(&path).unwrap();
    assert_eq!(
        back.vertices, s.truth,
        "full precision: every coordinate reads back exactly"
    );
    assert_eq!(
        std::fs::read_dir(&dir).unwrap().count(),
        1,
        "no temporary file left behind"
    );
    // A directory that does not exist: an error naming the path, nothing written.
    let bad = dir.join("missing").join("x.g2o");
    let err = g2o::write(&bad, &s.graph, &s.truth).unwrap_err();
    assert!(err.to_string().contains("missing/x.g2o"), "{err}");
    let missing = g2o::read(dir.join("nope.g2o")).unwrap_err();
    assert!(
        missing.to_string().contains("nope.g2o: cannot read"),
        "{missing}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A file saved by a Windows editor: a byte-order mark before the first vertex and CRLF line
/// ends. It is the same graph, read from text and from a file (the mark used to make the first
/// tag unknown).
#[test]
fn a_byte_order_mark_and_crlf_lines_read_as_the_same_graph() {
    for planar in [true, false] {
        let text = sample(planar);
        let plain = g2o::parse(&text, "f.g2o").unwrap();
        let marked = format!("\u{feff}{}", text.replace('\n', "\r\n"));
        let from_text = g2o::parse(&marked, "f.g2o").unwrap();
        assert_eq!(from_text.vertices, plain.vertices);
        assert_eq!(from_text.edges.len(), plain.edges.len());
        let dir = std::env::temp_dir().join(format!("dynamap-g2o-bom-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("marked.g2o");
        std::fs::write(&path, &marked).unwrap();
        let from_file = g2o::read(&path).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(from_file.vertices, plain.vertices);
        assert_eq!(from_file.edges.len(), plain.edges.len());
        // a mark anywhere else is content, and the line is named
        let inside = text.replacen("\nEDGE", "\n\u{feff}EDGE", 1);
        let e = g2o::parse(&inside, "f.g2o").unwrap_err();
        assert!(e.line > 1, "{e}");
    }
}
