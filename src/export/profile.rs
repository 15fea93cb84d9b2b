//! Renderer profiles: the conventions each renderer expects of a volume file, as its own
//! documentation states them (sources in docs/RENDERING.md "Renderer profiles").
//!
//! All five read the house grid names (`density`, `temperature`, `vel`), so a profile keeps the
//! names and sets what differs: the up axis, the velocity's time basis and grid class, and extra
//! aliases.
use crate::config::{Profile, UpAxis, VectorClass, VelocityTime};

/// What a profile sets; each is overridden by its own key when that key is set.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ProfileDefaults {
    pub up_axis: UpAxis,
    pub velocity_time: VelocityTime,
    pub velocity_class: VectorClass,
    /// (alias, grid key) pairs added to `export.grids.aliases`; the grid key is one of
    /// `density`, `temperature`, `vapor`, `velocity` and resolves to that grid's name.
    pub aliases: &'static [(&'static str, &'static str)],
}

/// The conventions without a profile: nimbus's own frame (y-up, metres, playback seconds).
pub const NONE: ProfileDefaults = ProfileDefaults {
    up_axis: UpAxis::Y,
    velocity_time: VelocityTime::Playback,
    velocity_class: VectorClass::Unknown,
    aliases: &[],
};

pub fn defaults(profile: Option<Profile>) -> ProfileDefaults {
    match profile {
        None => NONE,
        // Houdini pyro and Karma (Solaris): y-up, `vel` in units per second of playback, class
        // free; Karma blurs volumes by their velocity grid.
        Some(Profile::Houdini) | Some(Profile::Karma) => NONE,
        // Blender: z-up scenes; an imported Volume finds `vel` as its velocity grid and reads
        // it per frame (`Volume.velocity_unit` defaults to FRAME); `heat` is what Blender's own
        // fire caches and shaders name the temperature.
        Some(Profile::Blender) => ProfileDefaults {
            up_axis: UpAxis::Z,
            velocity_time: VelocityTime::PerFrame,
            aliases: &[("heat", "temperature")],
            ..NONE
        },
        // Arnold: per-second velocities, divided into per-frame by the volume's velocity_fps.
        Some(Profile::Arnold) => NONE,
        // RenderMan: the OpenVDB plugin needs the velocity grid as a Vec3f fog volume, and
        // PxrVolume takes velocity per frame.
        Some(Profile::Renderman) => ProfileDefaults {
            velocity_time: VelocityTime::PerFrame,
            velocity_class: VectorClass::FogVolume,
            ..NONE
        },
    }
}

pub fn name(profile: Option<Profile>) -> &'static str {
    match profile {
        None => "none",
        Some(Profile::Houdini) => "houdini",
        Some(Profile::Blender) => "blender",
        Some(Profile::Arnold) => "arnold",
        Some(Profile::Renderman) => "renderman",
        Some(Profile::Karma) => "karma",
    }
}
