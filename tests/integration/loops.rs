//! Loop detection (issue 24, point 3): keyframes of a second pass along an orbit, offered at
//! poses that drifted half a metre from the first pass's, find the first pass's keyframes of the
//! same places by fern code and features, and the relative pose they measure is the true one
//! (what the graph does with the loops is tested in `slam::rigid::loops`).

use dynamap::slam::camera::Camera;
use dynamap::slam::features::FeatureParams;
use dynamap::slam::rigid::keyframes::{Candidate, KeyframeParams, Keyframes};
use dynamap::slam::rigid::loops::{find_loop, KeyframeGraph, LoopParams};
use dynamap::slam::synthetic::motion::{self, Motion};
use dynamap::slam::synthetic::render::render;
use dynamap::slam::synthetic::scene::Scene;
use nalgebra::{Isometry3, Translation3};

#[test]
fn a_second_pass_finds_the_first_passes_keyframes_with_their_true_relative_pose() {
    let cam = Camera::new(262.5, 262.5, 159.5, 119.5, 320, 240);
    let gt = motion::procedural(Motion::Orbit, 100, 30.0);
    let scene = Scene::room(7);
    let features = FeatureParams::default();
    let params = LoopParams::default();
    let mut keys = Keyframes::new(KeyframeParams::default());
    let mut graph = KeyframeGraph::new(params.clone());
    let drift = Translation3::new(0.5, 0.0, 0.0);
    let (mut found, mut first_pass) = (Vec::new(), 0);
    for pass in 0..2 {
        for k in (0..100).step_by(2) {
            let truth = gt.poses[k];
            let r = render(&scene, &cam, &truth);
            // the second pass was tracked with a drift: its poses are far from the first's
            let pose: Isometry3<f64> = if pass == 0 { truth } else { drift * truth };
            let frame = 1000 * pass + k;
            let c = Candidate {
                frame,
                pose,
                agreement: Some(0.6),
                color: Some(&r.color),
                depth: &r.depth,
                camera: &cam,
            };
            if !keys.offer(&c, &features, 5.0) {
                continue;
            }
            graph.add_keyframe(frame, pose);
            if pass == 0 {
                first_pass += 1;
            }
            if let Some(l) = find_loop(&keys, &params, &features) {
                assert!(pass == 1, "a loop on the first pass: {l:?}");
                let (a, b) = (gt.poses[l.from], gt.poses[l.to - 1000]);
                let err = (a.inverse() * b).inverse() * l.relative;
                let (t, r) = (err.translation.vector.norm(), err.rotation.angle());
                assert!(
                    t < 0.03 && r.to_degrees() < 2.0,
                    "{l:?}: {t:.3} m, {r:.3} rad off"
                );
                assert!(graph.add_loop(&l));
                found.push(l);
            }
        }
    }
    let second_pass = keys.frames().len() - first_pass;
    assert!(first_pass >= 8, "{first_pass} keyframes on the first pass");
    assert!(
        found.len() * 2 >= second_pass,
        "{} loops for {second_pass} keyframes of the second pass",
        found.len()
    );
    assert_eq!(graph.loop_count(), found.len());
}
