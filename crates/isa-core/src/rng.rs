//! Deterministic seeding: every random choice of training draws from a ChaCha8 stream seeded
//! by mixing (seed, tree, node id, purpose), so results do not depend on thread scheduling.

/// SplitMix64 finaliser.
#[inline]
pub fn splitmix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Mixes a list of words into one 64-bit seed.
pub fn mix(words: &[u64]) -> u64 {
    let mut h = 0x243F_6A88_85A3_08D3u64;
    for &w in words {
        h = splitmix(h ^ splitmix(w));
    }
    h
}
