//! Checks of the art-direction keys: `physics.sources` (which keys each shape takes, where it
//! sits), `physics.wind` (levels, and no wind into a wall) and `control.target` (one shape, the
//! scale's form). Ranges are in `validate::FLOAT_RANGES`; these are the rules between keys. Each
//! issue names its key. The files these keys name (heat maps, the target's mesh or VDB) are read
//! and checked by the prepared shot (`shot`).
use super::schema::*;
use super::validate::Issue;

/// Most levels of `physics.wind.profile` (the thermo uniform's table; `ground::limits`).
pub use crate::ground::limits::MAX_WIND_LEVELS;

fn num(x: f64) -> String {
    super::node::fmt_float(x)
}

struct Out(Vec<Issue>);

impl Out {
    fn fail(&mut self, keys: &[&str], msg: String) {
        self.0.push(Issue {
            keys: keys.iter().map(|k| k.to_string()).collect(),
            msg,
        });
    }
}

pub(crate) fn issues(p: &PhysicsConfig, c: &ShotConfig) -> Vec<Issue> {
    let mut out = Out(Vec::new());
    for (i, src) in p.sources.iter().enumerate() {
        check_source(&mut out, i, src, c);
    }
    if let Some(w) = &p.wind {
        check_wind(&mut out, w, c);
    }
    if let Some(f) = &p.forcing {
        check_forcing(&mut out, f, c);
    }
    if !p.environment.profile.is_empty() {
        check_profile(&mut out, &p.environment);
    }
    out.0
}

pub use crate::ground::limits::MAX_ENVIRONMENT_LEVELS;

fn check_profile(out: &mut Out, env: &EnvironmentConfig) {
    let levels = &env.profile;
    check_levels(
        out,
        "physics.environment.profile",
        &levels.iter().map(|l| l.height).collect::<Vec<_>>(),
        MAX_ENVIRONMENT_LEVELS,
    );
    let with_vapor = levels.iter().filter(|l| l.vapor.is_some()).count();
    if with_vapor != 0 && with_vapor != levels.len() {
        let k = levels.iter().position(|l| l.vapor.is_none()).unwrap_or(0);
        out.fail(
            &[&format!("physics.environment.profile[{k}]")],
            "gives no vapor: give it at every level or at none (then physics.initial_vapor sets it)"
                .into(),
        );
    }
    for (key, set) in [
        (
            "physics.environment.inversion_height",
            env.inversion_height.is_some(),
        ),
        (
            "physics.environment.lapse_rate_above",
            env.lapse_rate_above.is_some(),
        ),
        (
            "physics.environment.humidity_above",
            env.humidity_above.is_some(),
        ),
    ] {
        if set {
            out.fail(
                &[key],
                "is not read with physics.environment.profile, which gives the whole environment"
                    .into(),
            );
        }
    }
}

/// Most levels of `physics.forcing.profile` (the host builds the layer table from them).
pub const MAX_FORCING_LEVELS: usize = 16;

/// Longest frame with `physics.forcing` (s): the forcing is applied once a frame, a step of
/// the frame's length (docs/CONFIG.md "Forcing").
pub const MAX_FORCING_FRAME: f64 = 300.0;

/// A profile's levels: at most `max`, heights increasing (`key` the list's key).
fn check_levels(out: &mut Out, key: &str, heights: &[f64], max: usize) {
    if heights.len() > max {
        out.fail(
            &[key],
            format!("{} levels; at most {max} are supported", heights.len()),
        );
    }
    for (k, pair) in heights.windows(2).enumerate() {
        if pair[1] <= pair[0] {
            out.fail(
                &[&format!("{key}[{}].height", k + 1)],
                format!(
                    "heights must increase: {} m is not above the level before it ({} m)",
                    num(pair[1]),
                    num(pair[0])
                ),
            );
        }
    }
}

fn check_forcing(out: &mut Out, f: &ForcingConfig, c: &ShotConfig) {
    check_levels(
        out,
        "physics.forcing.profile",
        &f.profile.iter().map(|l| l.height).collect::<Vec<_>>(),
        MAX_FORCING_LEVELS,
    );
    if let Some(d) = f.surface_layer {
        let height = c.domain.size[1];
        if d.is_finite() && height.is_finite() && d >= height {
            out.fail(
                &["physics.forcing.surface_layer"],
                format!(
                    "{} m reaches the ceiling of the domain ({} m high)",
                    num(d),
                    num(height)
                ),
            );
        }
    }
    let fs = c.output.frame_seconds;
    if fs.is_finite() && fs > MAX_FORCING_FRAME {
        out.fail(
            &["output.frame_seconds", "physics.forcing"],
            format!(
                "frames of {} s: physics.forcing is applied once a frame, so frames may be at most {} s long",
                num(fs),
                num(MAX_FORCING_FRAME)
            ),
        );
    }
}

fn shape_name(s: SourceShape) -> &'static str {
    match s {
        SourceShape::Disc => "disc",
        SourceShape::Ellipse => "ellipse",
        SourceShape::Box => "box",
        SourceShape::Sphere => "sphere",
        SourceShape::Image => "image",
    }
}

fn check_source(out: &mut Out, i: usize, src: &HeatSource, c: &ShotConfig) {
    let key = |f: &str| format!("physics.sources[{i}].{f}");
    let name = shape_name(src.shape);
    if let Some(end) = src.end {
        if end < src.start + 2.0 * src.ramp {
            out.fail(
                &[&key("end")],
                format!(
                    "end {} s leaves no room for the ramps: it must be at least start + 2 ramp = {} s",
                    num(end),
                    num(src.start + 2.0 * src.ramp)
                ),
            );
        }
    }
    // which keys the shape takes: (key, set, needed)
    let ground = src.on_ground();
    let center_len: &[usize] = match src.shape {
        SourceShape::Disc | SourceShape::Ellipse => &[2],
        SourceShape::Sphere => &[3],
        SourceShape::Box => &[2, 3],
        SourceShape::Image => &[0],
    };
    let keys: [(&str, bool, bool); 7] = [
        (
            "radius",
            src.radius.is_some(),
            matches!(src.shape, SourceShape::Disc | SourceShape::Sphere),
        ),
        (
            "radii",
            src.radii.is_some(),
            src.shape == SourceShape::Ellipse,
        ),
        ("size", src.size.is_some(), src.shape == SourceShape::Box),
        (
            "image",
            src.image.is_some(),
            src.shape == SourceShape::Image,
        ),
        (
            "image_sha256",
            src.image_sha256.is_some(),
            src.shape == SourceShape::Image,
        ),
        (
            "angle",
            src.angle.is_some(),
            matches!(src.shape, SourceShape::Ellipse | SourceShape::Box),
        ),
        ("height", src.height.is_some(), ground),
    ];
    for (k, set, allowed) in keys {
        if set && !allowed {
            let why = if k == "height" {
                format!(
                    "a {name} in the air has no heated layer (height is for shapes on the ground)"
                )
            } else {
                format!("a {name} source does not take {k}")
            };
            out.fail(&[&key(k)], why);
        }
    }
    for (k, set) in [
        ("radius", src.radius.is_some()),
        ("radii", src.radii.is_some()),
        ("size", src.size.is_some()),
        ("image", src.image.is_some()),
    ] {
        let needed = match k {
            "radius" => matches!(src.shape, SourceShape::Disc | SourceShape::Sphere),
            "radii" => src.shape == SourceShape::Ellipse,
            "size" => src.shape == SourceShape::Box,
            _ => src.shape == SourceShape::Image,
        };
        if needed && !set {
            out.fail(
                &[&key("shape")],
                format!("a {name} source needs {k} (docs/CONFIG.md \"physics.sources\")"),
            );
        }
    }
    if !center_len.contains(&src.center.len()) {
        let want = match src.shape {
            SourceShape::Image => "no centre (a heat map covers the whole ground)".to_string(),
            SourceShape::Box => {
                "a centre of 2 values (x, z) on the ground or 3 (x, y, z) in the air".to_string()
            }
            _ if center_len[0] == 2 => "a centre of 2 values (x, z)".to_string(),
            _ => "a centre of 3 values (x, y, z)".to_string(),
        };
        let at = if src.center.is_empty() {
            key("shape")
        } else {
            key("center")
        };
        out.fail(
            &[&at],
            format!(
                "a {name} source takes {want}, got {} values",
                src.center.len()
            ),
        );
        return;
    }
    if let Some(size) = &src.size {
        if size.len() != src.center.len() {
            out.fail(
                &[&key("size")],
                format!(
                    "a box with a centre of {} values takes {} edge lengths, got {}",
                    src.center.len(),
                    src.center.len(),
                    size.len()
                ),
            );
        }
    }
    // The centre must lie in the domain (along y too, for shapes in the air).
    let s = c.domain.size;
    let axes: Vec<(&str, f64)> = if src.center.len() == 3 {
        vec![("x", s[0]), ("y", s[1]), ("z", s[2])]
    } else {
        vec![("x", s[0]), ("z", s[2])]
    };
    for (&x, (axis, size)) in src.center.iter().zip(axes) {
        if !(0.0..=size).contains(&x) {
            out.fail(
                &[&key("center")],
                format!(
                    "centre {} m is outside the domain along {axis} [0, {}]",
                    num(x),
                    num(size)
                ),
            );
        }
    }
    if let Some(h) = src.height {
        if h > s[1] {
            out.fail(
                &[&key("height")],
                format!(
                    "the heated layer's top {} m is above the domain ({} m)",
                    num(h),
                    num(s[1])
                ),
            );
        }
    }
}

fn check_wind(out: &mut Out, w: &WindConfig, c: &ShotConfig) {
    if w.profile.is_empty() {
        out.fail(
            &["physics.wind.profile"],
            "expected at least one level ({height, speed, direction})".into(),
        );
        return;
    }
    check_levels(
        out,
        "physics.wind.profile",
        &w.profile.iter().map(|l| l.height).collect::<Vec<_>>(),
        MAX_WIND_LEVELS,
    );
    let periodic = |a: Axis| c.domain.periodic.contains(&a);
    if w.coriolis.is_some() {
        // the relaxation's key has a default, so only a value other than it can be told apart
        if w.time_constant != d_wind_time() {
            out.fail(
                &["physics.wind.time_constant", "physics.wind.coriolis"],
                "a geostrophic wind (coriolis) turns the air about the profile and does not relax it: remove time_constant".into(),
            );
        }
        if !(periodic(Axis::X) && periodic(Axis::Z)) {
            out.fail(
                &["physics.wind.coriolis", "domain.periodic"],
                "the Coriolis force turns the wind through every heading: it needs periodic x and z (domain.periodic)".into(),
            );
        }
    }
    for (axis, u, name) in [
        (Axis::X, w.ground_velocity[0], "x"),
        (Axis::Z, w.ground_velocity[1], "z"),
    ] {
        if u != 0.0 && !periodic(axis) {
            out.fail(
                &["physics.wind.ground_velocity", "domain.periodic"],
                format!("the ground moves along {name}, which is walled (domain.periodic)"),
            );
        }
    }
    check_wind_levels(out, "physics.wind.profile", &w.profile, c);
    if !w.initial.is_empty() {
        check_levels(
            out,
            "physics.wind.initial",
            &w.initial.iter().map(|l| l.height).collect::<Vec<_>>(),
            MAX_WIND_LEVELS,
        );
        check_wind_levels(out, "physics.wind.initial", &w.initial, c);
    }
}

/// Each level's speed against `solver.max_speed`, and no wind into a wall.
fn check_wind_levels(out: &mut Out, name: &str, levels: &[WindLevel], c: &ShotConfig) {
    let periodic = |a: Axis| c.domain.periodic.contains(&a);
    for (k, l) in levels.iter().enumerate() {
        let at = |f: &str| format!("{name}[{k}].{f}");
        if l.speed > c.solver.max_speed {
            out.fail(
                &[&at("speed"), "solver.max_speed"],
                format!(
                    "wind speed {} m/s is above solver.max_speed {} m/s",
                    num(l.speed),
                    num(c.solver.max_speed)
                ),
            );
        }
        let a = l.direction.to_radians();
        let (ux, uz) = (l.speed * a.cos(), l.speed * a.sin());
        for (axis, u, name) in [(Axis::X, ux, "x"), (Axis::Z, uz, "z")] {
            if !periodic(axis) && u.abs() > 1e-6 * l.speed.max(1e-300) {
                out.fail(
                    &[&at("direction"), "domain.periodic"],
                    format!(
                        "direction {} degrees blows along {name}, which is walled (domain.periodic); wind needs periodic faces to pass through",
                        num(l.direction)
                    ),
                );
            }
        }
    }
}

/// `control.target`: one shape (a mesh or a VDB), the keys that shape takes and the scale's form.
/// The voxel grid's size, the file and where it lands are the prepared shot's (`shot::target`).
pub(crate) fn target_issues(c: &ShotConfig) -> Vec<Issue> {
    let mut out = Out(Vec::new());
    let Some(t) = &c.control.target else {
        return out.0;
    };
    match (&t.mesh, &t.vdb) {
        (Some(_), Some(_)) => {
            out.fail(
                &["control.target.vdb", "control.target.mesh"],
                "give the target as either mesh (OBJ) or vdb, not both".into(),
            );
            return out.0;
        }
        (None, None) => {
            out.fail(
                &["control.target"],
                "the target needs a shape: mesh (a closed OBJ mesh) or vdb (a fog volume or level set)".into(),
            );
            return out.0;
        }
        (Some(_), None) => {
            for (key, given) in [
                ("control.target.grid", t.grid.is_some()),
                ("control.target.iso", t.iso.is_some()),
            ] {
                if given {
                    out.fail(&[key], "applies to a vdb target only, not to a mesh".into());
                    return out.0;
                }
            }
        }
        (None, Some(_)) => {}
    }
    if !matches!(t.scale.len(), 1 | 3) {
        out.fail(
            &["control.target.scale"],
            format!(
                "expected one value (uniform) or three (x, y, z), got {}",
                t.scale.len()
            ),
        );
        return out.0;
    }
    out.0
}
