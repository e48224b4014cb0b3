//! Counter-based random streams: every random decision draws from a ChaCha8 stream keyed by
//! (seed, sweep, phase, entity), so results do not depend on which thread makes the draw.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// What a stream is used for; part of its key.
#[derive(Clone, Copy, Debug)]
#[repr(u64)]
pub enum Phase {
    Init = 1,
    Assign = 2,
    LengthScales = 3,
    Alpha = 4,
    Predict = 5,
    Simulate = 6,
    SplitMerge = 7,
    Noise = 8,
    Sticky = 9,
    /// The sub-cluster sampler's draws: mixture weights, fields, labels, split–merge moves.
    Weights = 10,
    Fields = 11,
    Labels = 12,
    Launch = 13,
    Peel = 14,
}

fn splitmix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// The stream for one (sweep, phase, entity) under `seed`.
pub fn stream(seed: u64, sweep: u64, phase: Phase, entity: u64) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(splitmix(splitmix(splitmix(sweep) ^ phase as u64) ^ entity));
    rng
}

/// A uniform in `[0, 1)` for one (sweep, phase, entity) under `seed`, from the same key as
/// [`stream`] hashed once more: a few nanoseconds, where a stream costs a ChaCha set-up, for
/// passes that draw one number for each of millions of frames.
pub fn uniform(seed: u64, sweep: u64, phase: Phase, entity: u64) -> f64 {
    uniform_code(seed, sweep, phase as u64, entity)
}

/// [`uniform`] with the phase as its number (`phase as u64`), for requests that carry it.
pub fn uniform_code(seed: u64, sweep: u64, phase: u64, entity: u64) -> f64 {
    let key = splitmix(splitmix(splitmix(splitmix(sweep) ^ phase) ^ entity) ^ seed);
    (key >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}
