//! The prepared shot: its issues placed like the config's own, and the keys the stages below
//! trust refused here.
use super::*;
use crate::error::Error;

const BASE: &str = "shot: t\noutput: {frames: {start: 1, end: 2}}\n\
                    domain: {size: [1000, 800, 1000], spacing: 50}\n";

#[test]
fn a_missing_heat_map_is_placed_at_its_key() {
    let text = format!(
        "{BASE}physics:\n  sources:\n    - shape: image\n      image: /nonexistent/heat.png\n"
    );
    let e = load_str(&text, "t.yaml", &[]).unwrap_err();
    assert!(matches!(e, Error::Config(_)), "{e:?}");
    assert_eq!(
        e.to_string(),
        "t.yaml:7:7: physics.sources[0].image: /nonexistent/heat.png: no such file"
    );
    // the config reads no file; prepared from code, the issue names its key alone
    let cfg = crate::config::read_str(&text, "t.yaml", &[])
        .unwrap()
        .config;
    let e = Shot::prepare(cfg).unwrap_err();
    assert_eq!(
        e.to_string(),
        "physics.sources[0].image: /nonexistent/heat.png: no such file"
    );
}

/// `AdaptiveParams::new`, `AdaptiveStage::new`, `Simulation::from_state`, the smoothing's
/// parameters, the capacity and the checkpoint pruning no longer check or clamp these: a shot
/// that breaks them is never prepared.
#[test]
fn the_keys_the_stages_trust_are_refused_here() {
    let ok = load_str(BASE, "t.yaml", &[]).unwrap().into_config();
    assert!(Shot::prepare(ok.clone()).is_ok());
    type Edit = fn(&mut ShotConfig);
    let breakers: [(Edit, &str); 9] = [
        (
            |c| c.adaptive.merge_threshold = c.adaptive.split_threshold,
            "adaptive.merge_threshold",
        ),
        (|c| c.adaptive.min_distance = 0.9, "adaptive.min_distance"),
        (|c| c.adaptive.split_offset = 0.0, "adaptive.split_offset"),
        (|c| c.adaptive.kc = f64::NAN, "adaptive.kc"),
        (|c| c.output.substeps = 0, "output.substeps"),
        (
            |c| c.physics.smoothing.iterations = 0,
            "physics.smoothing.iterations",
        ),
        (
            |c| {
                c.adaptive.enabled = true;
                c.adaptive.capacity_factor = 0.5;
            },
            "adaptive.capacity_factor",
        ),
        (|c| c.checkpoint.keep = 0, "checkpoint.keep"),
        (
            |c| {
                c.domain.size[0] = 250.0;
                c.domain.periodic = vec![crate::config::Axis::X];
            },
            "domain.periodic",
        ),
    ];
    for (edit, key) in breakers {
        let mut c = ok.clone();
        edit(&mut c);
        let e = Shot::prepare(c).unwrap_err();
        assert!(matches!(e, Error::Config(_)), "{e:?}");
        assert!(e.to_string().starts_with(&format!("{key}: ")), "{key}: {e}");
    }
}
