//! Named random streams of one sample: every augmentation draws from its own stream, named by
//! the augmentation, so adding, removing or retuning one never shifts another's draws (the
//! generator's seed tree follows the same rule).

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// The random streams of one training sample, all derived from its seed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SampleStreams {
    seed: u64,
}

/// FNV-1a over the name's bytes: stable across platforms and Rust versions (unlike
/// `DefaultHasher`), so a stream name means the same numbers everywhere.
fn stream_id(name: &str) -> u64 {
    name.bytes().fold(0xCBF2_9CE4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01B3)
    })
}

impl SampleStreams {
    /// The streams of the sample whose seed is `seed` (the loader's per-sample seed).
    pub fn for_sample(seed: u64) -> Self {
        Self { seed }
    }

    /// The stream called `name`, from its start. ChaCha's stream number (its nonce) selects
    /// one of 2⁶⁴ independent keystreams of the sample's key, so streams share no state and
    /// asking for one never advances another.
    pub fn stream(&self, name: &str) -> ChaCha8Rng {
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        rng.set_stream(stream_id(name));
        rng
    }
}

#[cfg(test)]
mod tests {
    use rand::Rng;

    use super::*;

    #[test]
    fn a_stream_is_a_function_of_seed_and_name_only() {
        let streams = SampleStreams::for_sample(42);
        let first: Vec<u64> = streams.stream("swap").random_iter().take(8).collect();
        // Drawing from other streams in between changes nothing.
        let mut other = streams.stream("occlusion");
        let _: Vec<u64> = (&mut other).random_iter().take(100).collect();
        let again: Vec<u64> = streams.stream("swap").random_iter().take(8).collect();
        assert_eq!(first, again);
        let elsewhere = [
            SampleStreams::for_sample(43).stream("swap"),
            streams.stream("scale"),
            streams.stream("swap "),
        ];
        for mut rng in elsewhere {
            assert_ne!(rng.random::<u64>(), first[0]);
        }
    }
}
