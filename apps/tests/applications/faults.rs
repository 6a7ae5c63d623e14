//! Runs that meet what real streams do (issue 8): dropped, corrupt and blank frames, a sudden jump
//! of the camera, a stretch at a wall without texture, missing or cut depth files, and Ctrl-C.
//! Each runs `rigid_slam` as a user would, on a sequence rendered at 320×240.

use crate::common::{binary, result_json, run, scratch, text};
use dynamap_slam::camera::Camera;
use dynamap_slam::eval::{ate, Alignment, MAX_STAMP_DIFFERENCE};
use dynamap_slam::image::Image;
use dynamap_slam::io::images::write_depth;
use dynamap_slam::io::trajectory::Trajectory;
use dynamap_slam::synthetic::faults::{write_faulty, FaultPlan};
use dynamap_slam::synthetic::motion::{self, Motion};
use dynamap_slam::synthetic::noise::SensorNoise;
use dynamap_slam::synthetic::{scene::Scene, sequence};
use nalgebra::Isometry3;
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};

fn camera() -> Camera {
    Camera::tum_default().level(1)
}

/// Runs rigid_slam on `dir` writing `traj`; returns the JSON line and the trajectory.
fn track(dir: &Path, traj: &Path) -> (serde_json::Value, Trajectory) {
    let out = run(
        "rigid_slam",
        &[dir.to_str().unwrap(), "--output", traj.to_str().unwrap()],
    );
    assert!(
        out.status.success(),
        "rigid_slam failed on {}: {}",
        dir.display(),
        text(&out.stderr)
    );
    (result_json(&out), Trajectory::read_tum(traj).unwrap())
}

#[test]
fn a_run_through_dropped_corrupt_blank_frames_a_jump_and_a_plain_wall_keeps_its_accuracy() {
    let dir = scratch("faults");
    let plan = FaultPlan::standard();
    let noise = SensorNoise::default();
    let faulty = write_faulty(&dir.join("faulty"), &plan, &camera(), &noise).unwrap();
    write_faulty(
        &dir.join("clean"),
        &FaultPlan::clean(plan.frames),
        &camera(),
        &noise,
    )
    .unwrap();

    let (clean, clean_traj) = track(&dir.join("clean"), &dir.join("clean.txt"));
    assert_eq!(clean["failures"], 0, "{clean}");
    assert_eq!(clean_traj.len(), plan.frames);
    let (run, traj) = track(&dir.join("faulty"), &dir.join("faulty.txt"));
    eprintln!("clean: {clean}\nfaulty: {run}");

    // what the run saw: every listed frame, the corrupt ones skipped with a reason
    assert_eq!(run["frames"], plan.frames - plan.dropped.len());
    assert_eq!(run["skipped"], plan.corrupt.len());
    assert_eq!(run["tracked"], traj.len());
    let stamp_of = |k: usize| faulty.groundtruth.stamps[k];
    let tracked = |k: usize| traj.stamps.iter().any(|s| (s - stamp_of(k)).abs() < 1e-6);
    // blank frames and the wall stretch are reported, not tracked (nor fused)
    for k in plan.blank.iter().copied().chain(plan.wall.clone()) {
        assert!(!tracked(k), "frame {k} (blank or at the wall) was tracked");
    }
    let expected_failures = plan.blank.len() + plan.wall.len();
    let failures = run["failures"].as_u64().unwrap() as usize;
    assert!(
        (expected_failures..=expected_failures + 3).contains(&failures),
        "{failures} failures, {expected_failures} expected"
    );
    // tracking re-acquires right after the jump and right after the wall
    let jump = plan.jump_at.unwrap();
    assert!(
        tracked(jump) || tracked(jump + 1),
        "not relocalised after the jump"
    );
    assert!(
        tracked(plan.wall.end) || tracked(plan.wall.end + 1),
        "not relocalised after the wall"
    );
    assert!(run["relocalised"].as_u64().unwrap() >= 2, "{run}");
    // the frames reported as tracked are as accurate as the clean run's
    let err = |t: &Trajectory| {
        ate(&faulty.groundtruth, t, Alignment::Se3, MAX_STAMP_DIFFERENCE)
            .unwrap()
            .stats
            .rmse
    };
    let (e_clean, e_faulty) = (err(&clean_traj), err(&traj));
    assert!(
        e_faulty <= 2.0 * e_clean && e_faulty < 0.01,
        "ATE {e_faulty:.4} m with faults, {e_clean:.4} m clean"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// An orbit of `frames` frames at 320×240.
fn orbit(dir: &Path, frames: usize) {
    sequence::write_rigid(
        dir,
        &Scene::room(1),
        &camera(),
        &motion::procedural(Motion::Orbit, frames, 30.0),
        &Isometry3::identity(),
        &sequence::Sensor::Ideal(SensorNoise::default()),
        |_| {},
    )
    .unwrap();
}

/// A scratch folder for `test` and, in it, an orbit of `frames` frames without `intrinsics.txt`
/// (so that the command line must give them): (the folder, the sequence).
fn orbit_without_intrinsics(test: &str, frames: usize) -> (std::path::PathBuf, std::path::PathBuf) {
    let dir = scratch(test);
    let seq = dir.join("seq");
    orbit(&seq, frames);
    std::fs::remove_file(seq.join("intrinsics.txt")).unwrap();
    (dir, seq)
}

/// The depth images of the sequence in `seq`, in stamp order.
fn depth_files(seq: &Path) -> Vec<std::path::PathBuf> {
    let mut depth: Vec<_> = std::fs::read_dir(seq.join("depth"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    depth.sort();
    depth
}

#[test]
fn every_tenth_depth_file_deleted_or_cut_is_skipped_and_counted() {
    let dir = scratch("tenth");
    let seq = dir.join("seq");
    orbit(&seq, 40);
    let depth = depth_files(&seq);
    // frames 0, 10, 20, 30: deleted, cut, deleted, cut (the first one too: the run must still
    // find the image size)
    for (n, path) in depth.iter().step_by(10).enumerate() {
        if n % 2 == 0 {
            std::fs::remove_file(path).unwrap();
        } else {
            let bytes = std::fs::read(path).unwrap();
            std::fs::write(path, &bytes[..bytes.len() / 2]).unwrap();
        }
    }
    let out = run(
        "rigid_slam",
        &[
            seq.to_str().unwrap(),
            "--output",
            dir.join("t.txt").to_str().unwrap(),
        ],
    );
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    let summary = result_json(&out);
    assert_eq!(summary["skipped"], 4, "{summary}");
    assert_eq!(summary["frames"], 40);
    assert_eq!(summary["failures"], 0, "{summary}\n{stderr}");
    assert_eq!(summary["tracked"], 36);
    for frame in [0, 10, 20, 30] {
        assert!(
            stderr.contains(&format!("frame {frame} skipped")),
            "frame {frame} is not reported: {stderr}"
        );
    }
    assert!(summary["ate_rmse"].as_f64().unwrap() < 0.01, "{summary}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A run that tracks nothing does not exit 0: its only frames unreadable (the first two of the
/// sequence in 8 bits, `--max-frames 2`; the size is read from a later one) is bad input (exit 2,
/// naming the first frame's file), every depth image blank a runtime failure (exit 1). The
/// summary line is printed first either way, and the trajectory file written. A deforming
/// sequence whose depth is all blank fails `nonrigid_slam` the same way.
#[test]
fn a_run_that_tracks_no_frame_fails_and_says_why() {
    let dir = scratch("nothing");
    let seq = dir.join("seq");
    orbit(&seq, 4);
    let depth = depth_files(&seq);
    let traj = dir.join("t.txt");
    let (seq, out) = (seq.to_str().unwrap(), traj.to_str().unwrap());
    for path in &depth[..2] {
        image::GrayImage::new(320, 240).save(path).unwrap();
    }
    let unreadable = run("rigid_slam", &[seq, "--output", out, "--max-frames", "2"]);
    for path in &depth {
        write_depth(path, &Image::new(320, 240)).unwrap();
    }
    let blank = run("rigid_slam", &[seq, "--output", out]);
    let first = depth[0].display().to_string();
    for (what, run, code, says) in [
        (
            "unreadable",
            unreadable,
            2,
            ["none of the 2 frames", first.as_str()],
        ),
        (
            "blank",
            blank,
            1,
            ["was tracked", "4 of 4 read and not tracked"],
        ),
    ] {
        let stderr = text(&run.stderr);
        assert_eq!(run.status.code(), Some(code), "{what}: {stderr}");
        assert_eq!(result_json(&run)["tracked"], 0, "{what}");
        assert!(says.iter().all(|s| stderr.contains(s)), "{what}: {stderr}");
    }
    assert!(traj.exists(), "no trajectory file");
    // a deforming sequence whose depth is blank: nothing is fused
    let deforming = dir.join("deforming");
    let made = run(
        "generate",
        &[
            "-q",
            "deforming",
            deforming.to_str().unwrap(),
            "--frames",
            "3",
        ],
    );
    assert!(made.status.success(), "{}", text(&made.stderr));
    for entry in std::fs::read_dir(deforming.join("depth")).unwrap() {
        write_depth(entry.unwrap().path(), &Image::new(640, 480)).unwrap();
    }
    let fused = run("nonrigid_slam", &[deforming.to_str().unwrap()]);
    let stderr = text(&fused.stderr);
    assert_eq!(fused.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("3 of 3 read and not fused"), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A TUM folder of 320 × 240 frames without intrinsics would have been tracked with TUM's
/// 640 × 480 ones: it is refused by name, and runs once they are given on the command line or in
/// ETH3D's `calibration.txt`.
#[test]
fn a_folder_whose_size_tums_intrinsics_do_not_fit_is_refused_until_they_are_given() {
    let (dir, seq) = orbit_without_intrinsics("intrinsics", 4);
    let s = seq.to_str().unwrap();
    let refused = run("rigid_slam", &[s]);
    let stderr = text(&refused.stderr);
    assert_eq!(refused.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("320x240") && stderr.contains("--fx"),
        "{stderr}"
    );
    let c = camera();
    let k = [c.fx, c.fy, c.cx, c.cy].map(|v| v.to_string());
    let flags = ["--fx", "--fy", "--cx", "--cy"];
    let mut args = vec![s];
    args.extend(flags.iter().zip(&k).flat_map(|(f, v)| [*f, v.as_str()]));
    for (what, args) in [("flags", args), ("calibration.txt", vec![s])] {
        if what == "calibration.txt" {
            std::fs::write(seq.join(what), k.join(" ")).unwrap();
        }
        let out = run("rigid_slam", &args);
        assert_eq!(out.status.code(), Some(0), "{what}: {}", text(&out.stderr));
        let ate = result_json(&out)["ate_rmse"].as_f64().unwrap();
        assert!(ate < 0.01, "{what}: ATE {ate}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// An image's rows, `width` pixels each, in reverse order.
fn upside_down<T: Copy>(data: &mut Vec<T>, width: usize) {
    *data = data.chunks(width).rev().flatten().copied().collect();
}

/// Images stored upside down (ICL-NUIM's camera has fy = −480) are tracked when the intrinsics
/// given on the command line say so: a negative focal length, written either way, is a mirrored
/// axis, not bad input; a zero focal length is refused by name.
#[test]
fn frames_upside_down_are_tracked_with_a_negative_focal_length_given_as_flags() {
    use dynamap_slam::io::images::{read_color, read_depth, write_color};
    let (dir, seq) = orbit_without_intrinsics("mirrored", 8);
    for f in depth_files(&seq) {
        let mut d = read_depth(&f).unwrap();
        upside_down(&mut d.data, d.width);
        write_depth(&f, &d).unwrap();
    }
    for e in std::fs::read_dir(seq.join("rgb")).unwrap() {
        let f = e.unwrap().path();
        let mut c = read_color(&f).unwrap();
        upside_down(&mut c.data, c.width);
        write_color(&f, &c).unwrap();
    }
    let c = camera();
    let cy = (c.height - 1) as f64 - c.cy;
    let (fx, fy, cx, cy) = (
        c.fx.to_string(),
        (-c.fy).to_string(),
        c.cx.to_string(),
        cy.to_string(),
    );
    let s = seq.to_str().unwrap();
    let given = |fy: &[&str]| {
        let mut a = vec![s, "--fx", &fx, "--cx", &cx, "--cy", &cy, "-q"];
        a.extend_from_slice(fy);
        run("rigid_slam", &a)
    };
    let fy_eq = format!("--fy={fy}");
    for fy in [vec!["--fy", fy.as_str()], vec![fy_eq.as_str()]] {
        let out = given(&fy);
        assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
        let json = result_json(&out);
        let ate = json["ate_rmse"].as_f64().unwrap();
        assert!(ate < 0.005 && json["tracked"] == 8, "{fy:?}: {json}");
    }
    let zero = given(&["--fy", "0"]);
    assert_eq!(zero.status.code(), Some(2));
    assert!(text(&zero.stderr).contains("--fy must be a finite non-zero focal length"));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn ctrl_c_writes_the_trajectory_so_far_and_exits_130() {
    let dir = scratch("ctrlc");
    let seq = dir.join("seq");
    orbit(&seq, 120);
    let traj = dir.join("t.txt");
    let mut child = Command::new(binary("rigid_slam"))
        .args([
            seq.to_str().unwrap(),
            "--output",
            traj.to_str().unwrap(),
            "-v",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // wait for ten tracked frames, then interrupt
    let stderr = child.stderr.take().unwrap();
    let mut lines = BufReader::new(stderr).lines();
    let mut seen = 0;
    for line in lines.by_ref() {
        if line.unwrap().contains("rigid frame") {
            seen += 1;
            if seen == 10 {
                break;
            }
        }
    }
    assert_eq!(seen, 10, "the run ended before ten frames");
    let kill = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(kill.success());
    let rest: Vec<String> = lines.map_while(Result::ok).collect();
    let out = child.wait_with_output().unwrap();
    assert_eq!(out.status.code(), Some(130), "{}", rest.join("\n"));
    let summary = result_json(&out);
    assert_eq!(summary["interrupted"], true);
    let written = Trajectory::read_tum(&traj).unwrap();
    assert!(
        written.len() >= 10 && written.len() < 120,
        "{} poses written",
        written.len()
    );
    assert_eq!(summary["tracked"], written.len());
    assert!(rest.iter().any(|l| l.contains("interrupted")));
    let _ = std::fs::remove_dir_all(&dir);
}

/// The long run's guard (BENCHMARKS.md has the 10 000-frame curve): 900 frames under a budget
/// that the room exceeds many times over stay within it, keep tracking, and the resident memory
/// after warm-up grows by no more than the keyframes hold (each bounded, and at most
/// `max_keyframes` of them). The warm-up covers the first loops (about frame 470), whose
/// verification buffers (a raycast and a model pyramid, about 1.7 MiB) are allocated once.
#[test]
fn a_long_run_stays_within_its_block_budget_with_flat_memory() {
    let out = run(
        "long_run",
        &[
            "--frames",
            "900",
            "--max-blocks",
            "4000",
            "--warm-up",
            "600",
            "--every",
            "50",
        ],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let s = result_json(&out);
    eprintln!("{s}");
    assert_eq!(s["failures"], 0, "{s}");
    assert!(s["max_blocks"].as_u64().unwrap() <= 4000, "{s}");
    assert!(s["evicted"].as_u64().unwrap() > 0, "{s}");
    assert!(s["ate_rmse"].as_f64().unwrap() < 0.01, "{s}");
    let mib = |key: &str| s[key].as_f64().unwrap();
    let keyframes = mib("keyframe_mib_end") - mib("keyframe_mib_after_warm_up");
    let grow = mib("resident_mib_peak_after_warm_up") - mib("resident_mib_after_warm_up");
    assert!(
        grow - keyframes < 2.0,
        "resident memory grew {grow:.2} MiB after warm-up, the keyframes {keyframes:.2}: {s}"
    );
}

/// Corrupt and odd images: each is a clear error naming the file and frame, or a frame the
/// pipeline reports and does not fuse.
#[test]
fn odd_images_give_a_clear_error_or_a_reported_frame() {
    use dynamap_slam::image::Image;
    use dynamap_slam::io::images::read_depth;
    use dynamap_slam::io::tum::TumSequence;
    use dynamap_slam::rigid::{RigidSlam, SlamParams, TrackFailure};

    let dir = scratch("odd");
    let seq = dir.join("seq");
    orbit(&seq, 4);
    let opened = TumSequence::open(&seq).unwrap();
    let depth_of = |i: usize| opened.frames[i].depth.clone();
    // truncated PNG
    let cut = depth_of(0);
    let bytes = std::fs::read(&cut).unwrap();
    std::fs::write(&cut, &bytes[..bytes.len() / 3]).unwrap();
    let e = opened.load(0).unwrap_err().to_string();
    assert!(
        e.contains(&cut.display().to_string()) && e.contains("frame 0"),
        "{e}"
    );
    // wrong bit depth: an 8-bit depth image
    let eight = depth_of(1);
    image::GrayImage::new(320, 240).save(&eight).unwrap();
    let e = read_depth(&eight).unwrap_err().to_string();
    assert!(e.contains("16-bit"), "{e}");
    assert!(opened.load(1).unwrap_err().to_string().contains("frame 1"));
    // colour and depth of different sizes
    let small = &opened.frames[2].rgb;
    image::RgbImage::new(160, 120).save(small).unwrap();
    let e = opened.load(2).unwrap_err().to_string();
    assert!(e.contains("160x120") && e.contains("frame 2"), "{e}");

    // blank and out-of-range depth, and a mis-sized frame, handed to the pipeline
    let cam = camera();
    let good = opened.load(3).unwrap();
    for (what, depth) in [
        ("all zeros", Image::new(320, 240)),
        (
            "all at the sensor's maximum",
            Image::filled(320, 240, u16::MAX),
        ),
        ("a different size", Image::new(64, 48)),
    ] {
        // as the first frame, and after a good one
        let mut slam = RigidSlam::new(cam, SlamParams::default(), Isometry3::identity());
        let first = slam.process(&depth, None);
        assert!(
            first.failure().is_some(),
            "{what}: accepted as the first frame"
        );
        assert_eq!(slam.volume().num_blocks(), 0, "{what}: fused");
        let ok = slam.process(&good.depth, good.color.as_ref());
        assert!(ok.failure().is_none(), "{what}: {:?}", ok.outcome);
        let blocks = slam.volume().num_blocks();
        let after = slam.process(&depth, None);
        let why = after.failure().unwrap_or_else(|| panic!("{what}: tracked"));
        assert!(!why.to_string().is_empty());
        if what == "all zeros" {
            // named for what it is, not as a plain wall
            assert!(
                matches!(why, TrackFailure::NoDepth { points: 0 }),
                "{what}: {why}"
            );
        }
        assert_eq!(slam.volume().num_blocks(), blocks, "{what}: fused");
        assert_eq!(after.pose, ok.pose);
    }
    let _ = std::fs::remove_dir_all(&dir);
}
