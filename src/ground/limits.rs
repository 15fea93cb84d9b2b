//! The sizes of the thermo stage's uniform tables, defined here alone: the config's limits on
//! its keys, the host's `ThermoParams` arrays and, through the prelude (`gpu::shaders`), the
//! WGSL struct's, which no shader repeats as a literal.

/// Most entries of `physics.sources` (the uniform's source table).
pub const MAX_SOURCES: usize = 8;
/// Most levels of `physics.wind.profile` (the uniform's wind table).
pub const MAX_WIND_LEVELS: usize = 16;
/// Most layers of the horizontal-mean buoyancy profile (four a row of the uniform).
pub const MAX_LAYERS: usize = 32;
/// Most layers of the forcing's table of rates (`sim::forces::forcing`, its uniform).
pub const MAX_FORCING_LAYERS: usize = 64;
/// Most levels of `physics.environment.profile` (the uniform's sounding table).
pub const MAX_ENVIRONMENT_LEVELS: usize = 16;
