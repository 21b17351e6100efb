//! Hierarchical seeding: every random decision draws from a stream named by its place in the
//! scene (seed → index → "objects" → 3 → "material"), so any sample can be planned alone and
//! adding a draw in one place never shifts the draws of another.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// A node of the seed tree.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SeedTree {
    key: u64,
}

/// SplitMix64 finaliser: a bijective mixer with good avalanche, enough to decorrelate children.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// FNV-1a over the label bytes; stable across platforms and Rust versions (unlike `DefaultHasher`).
fn label_hash(label: &str) -> u64 {
    label.bytes().fold(0xCBF2_9CE4_8422_2325u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01B3)
    })
}

impl SeedTree {
    /// The root for one sample of a dataset.
    pub fn for_sample(seed: u64, index: u64) -> Self {
        Self {
            key: mix(mix(seed) ^ mix(index.wrapping_add(0x5EED))),
        }
    }

    /// A named child stream.
    pub fn child(self, label: &str) -> Self {
        Self {
            key: mix(self.key ^ label_hash(label)),
        }
    }

    /// A numbered child stream (object 0, 1, ...).
    pub fn nth(self, n: u64) -> Self {
        Self {
            key: mix(self.key.wrapping_add(mix(n ^ 0xA5A5_A5A5))),
        }
    }

    /// The random stream of this node.
    pub fn rng(self) -> ChaCha8Rng {
        ChaCha8Rng::seed_from_u64(self.key)
    }

    /// A 31-bit integer for seeds of external tools (Cycles takes a signed int).
    pub fn small_seed(self) -> u32 {
        (mix(self.key ^ 0x00C1_C1E5) >> 33) as u32
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;

    #[test]
    fn streams_are_reproducible_and_distinct() {
        let a = SeedTree::for_sample(7, 3).child("objects").nth(2);
        let b = SeedTree::for_sample(7, 3).child("objects").nth(2);
        assert_eq!(a.rng().random::<u64>(), b.rng().random::<u64>());
        let others = [
            SeedTree::for_sample(7, 4).child("objects").nth(2),
            SeedTree::for_sample(8, 3).child("objects").nth(2),
            SeedTree::for_sample(7, 3).child("lights").nth(2),
            SeedTree::for_sample(7, 3).child("objects").nth(3),
        ];
        for o in others {
            assert_ne!(a.rng().random::<u64>(), o.rng().random::<u64>());
        }
    }
}
