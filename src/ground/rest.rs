//! Rest positions as data: the u16 codec over the domain box, the reset schedule of the two
//! rest fields, and one frame of rest positions (the tracker that keeps them is `sim::rest`).

/// Maps rest positions (m, simulation frame) to u16 per axis and back.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RestCodec {
    pub size: [f64; 3],
    pub periodic: [bool; 3],
}

const Q: f64 = 65535.0;

impl RestCodec {
    pub fn new(size: [f64; 3], periodic_xz: [bool; 2]) -> Self {
        Self {
            size,
            periodic: [periodic_xz[0], false, periodic_xz[1]],
        }
    }
    pub fn encode(&self, p: [f64; 3]) -> [u16; 3] {
        [0, 1, 2].map(|a| {
            let mut x = p[a];
            if self.periodic[a] {
                x = x.rem_euclid(self.size[a]);
            }
            (x / self.size[a] * Q).round().clamp(0.0, Q) as u16
        })
    }
    pub fn decode(&self, q: [u16; 3]) -> [f64; 3] {
        [0, 1, 2].map(|a| q[a] as f64 / Q * self.size[a])
    }
    /// Minimum-image difference `a - b` (periodic axes wrapped).
    pub fn diff(&self, a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|k| {
            let d = a[k] - b[k];
            if self.periodic[k] {
                d - (d / self.size[k]).round() * self.size[k]
            } else {
                d
            }
        })
    }
}

/// The reset schedule of the two rest fields.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RestClock {
    pub start: u32,
    /// Frames between resets of one field; 0: never reset.
    pub period: u32,
}

impl RestClock {
    /// Age in frames of field A and B at `frame`.
    pub fn ages(&self, frame: u32) -> [u32; 2] {
        let f = frame.saturating_sub(self.start);
        if self.period == 0 {
            return [f, f];
        }
        let p = self.period;
        let half = p / 2;
        let b = if f < half {
            f + p - half
        } else {
            (f - half) % p
        };
        [f % p, b]
    }
    /// Whether field A and B are reset on `frame` (both on the first frame).
    pub fn resets(&self, frame: u32) -> [bool; 2] {
        if frame <= self.start {
            return [true, true];
        }
        if self.period == 0 {
            return [false, false];
        }
        self.ages(frame).map(|a| a == 0)
    }
    /// Blend weights of field A and B at `frame`, summing to 1 (`[1, 0]` with one field).
    pub fn weights(&self, frame: u32) -> [f64; 2] {
        if self.period == 0 {
            return [1.0, 0.0];
        }
        let p = self.period as f64;
        let tri = |age: u32| 1.0 - (2.0 * age as f64 / p - 1.0).abs();
        let [a, b] = self.ages(frame).map(tri);
        if a + b <= 0.0 {
            // period 1: both reset every frame
            return [0.5, 0.5];
        }
        [a / (a + b), b / (a + b)]
    }
    /// Whether the second field is in use.
    pub fn dual(&self) -> bool {
        self.period > 0
    }
}

/// Rest positions of one frame, in the order of that frame's `ParticleState`: fields A and B,
/// quantised (`RestCodec`).
pub type RestFrame = Vec<[u16; 6]>;
