//! Seeded randomness shared by the network initialisation ([`crate::net`]) and the PPO
//! rollouts ([`crate::ppo`]): standard normal samples from a ChaCha8 stream, and the
//! saveable state of such a stream (for checkpoints). Depends on no other learner module.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// A standard normal sample (Box–Muller).
pub fn randn(rng: &mut ChaCha8Rng) -> f32 {
    let u1: f64 = rng.random::<f64>().max(1e-300);
    let u2: f64 = rng.random::<f64>();
    ((-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()) as f32
}

/// The state of a ChaCha8 stream, enough to continue it exactly.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct RngState {
    /// Seed.
    pub seed: [u8; 32],
    /// Stream.
    pub stream: u64,
    /// Word position (as two halves for JSON).
    pub word_pos: [u64; 2],
}

impl RngState {
    /// Captures `rng`.
    pub fn of(rng: &ChaCha8Rng) -> Self {
        let wp = rng.get_word_pos();
        Self {
            seed: rng.get_seed(),
            stream: rng.get_stream(),
            word_pos: [(wp >> 64) as u64, wp as u64],
        }
    }
    /// Recreates the stream.
    pub fn restore(&self) -> ChaCha8Rng {
        let mut r = ChaCha8Rng::from_seed(self.seed);
        r.set_stream(self.stream);
        r.set_word_pos((u128::from(self.word_pos[0]) << 64) | u128::from(self.word_pos[1]));
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rng_state_round_trips_mid_stream() {
        let mut r = ChaCha8Rng::seed_from_u64(9);
        r.set_stream(4);
        let _: u64 = r.random();
        let _: u32 = r.random();
        let st = RngState::of(&r);
        let mut back = st.restore();
        for _ in 0..10 {
            assert_eq!(r.random::<u64>(), back.random::<u64>());
        }
    }
}
