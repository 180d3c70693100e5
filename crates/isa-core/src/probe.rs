//! The depth probe of the split function (Eq. 5, see [`features`](crate::features)): the depth
//! at a part's pixel moved by a depth-normalised offset, or [`BACKGROUND_MM`] outside the image
//! and on missing depth. One scalar form ([`probe`]) for training and the portable traversal,
//! one 8-lane AVX2 form ([`Probe8`]) for the vectorised binning and traversal; both do the same
//! `f32` operations, so they read the same pixels (a test compares them).

use crate::depth::ImageRef;
use crate::features::BACKGROUND_MM;

/// `floor(v)` as i32 without a libm call (baseline x86-64 has no SSE4.1 `roundss`): exact for
/// `|v| <= 1e9`; beyond that (and for NaN) any value far outside every image.
#[inline(always)]
pub(crate) fn floor_i32(v: f32) -> i32 {
    let v = v.clamp(-1e9, 1e9);
    let t = v as i32;
    t - ((t as f32) > v) as i32
}

/// Depth (mm, as `f32`) at `(x + round(off[0] * inv), y + round(off[1] * inv))`, rounding half
/// up (`floor(· + 0.5)`), or [`BACKGROUND_MM`] outside the image or on missing depth.
#[inline(always)]
pub(crate) fn probe(img: &ImageRef<'_>, x: i32, y: i32, off: [f32; 2], inv: f32) -> f32 {
    let px = x + floor_i32(off[0] * inv + 0.5);
    let py = y + floor_i32(off[1] * inv + 0.5);
    let d = img.get(px, py);
    if d == 0 {
        BACKGROUND_MM
    } else {
        f32::from(d)
    }
}

#[cfg(target_arch = "x86_64")]
pub(crate) use avx2::Probe8;

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::*;
    use std::arch::x86_64::*;

    /// [`probe`] on 8 lanes at once for one image (its constants set up once).
    #[derive(Clone, Copy)]
    pub(crate) struct Probe8 {
        base: *const i32,
        w: __m256i,
        h: __m256i,
        half: __m256,
        minus1: __m256i,
        zero: __m256i,
        lo16: __m256i,
        bg: __m256,
    }

    impl Probe8 {
        /// # Safety
        /// AVX2 must be available, and `img.data` must be followed in memory by at least one
        /// readable `u16` (a [`DepthStore`](crate::depth::DepthStore) image is: the store keeps
        /// a padding pixel after its last image), as depths are read by 32-bit gathers.
        #[target_feature(enable = "avx2")]
        #[inline]
        pub(crate) unsafe fn new(img: &ImageRef<'_>) -> Self {
            Probe8 {
                base: img.data.as_ptr() as *const i32,
                w: _mm256_set1_epi32(img.width),
                h: _mm256_set1_epi32(img.height),
                half: _mm256_set1_ps(0.5),
                minus1: _mm256_set1_epi32(-1),
                zero: _mm256_setzero_si256(),
                lo16: _mm256_set1_epi32(0xFFFF),
                bg: _mm256_set1_ps(BACKGROUND_MM),
            }
        }

        /// Per lane, [`probe`] of pixel `(x, y)` with offset `(ox, oy)` and normalisation `inv`
        /// (a float beyond the i32 range converts to i32::MIN: outside the image, like the
        /// scalar path's clamped value).
        ///
        /// # Safety
        /// AVX2 must be available; `self` from [`Probe8::new`] on an image still borrowed.
        #[target_feature(enable = "avx2")]
        #[inline]
        pub(crate) unsafe fn depth(
            &self,
            x: __m256i,
            y: __m256i,
            inv: __m256,
            ox: __m256,
            oy: __m256,
        ) -> __m256 {
            let round = |o: __m256| {
                _mm256_cvttps_epi32(_mm256_floor_ps(_mm256_add_ps(
                    _mm256_mul_ps(o, inv),
                    self.half,
                )))
            };
            let qx = _mm256_add_epi32(x, round(ox));
            let qy = _mm256_add_epi32(y, round(oy));
            let inside = _mm256_and_si256(
                _mm256_and_si256(
                    _mm256_cmpgt_epi32(self.w, qx),
                    _mm256_cmpgt_epi32(qx, self.minus1),
                ),
                _mm256_and_si256(
                    _mm256_cmpgt_epi32(self.h, qy),
                    _mm256_cmpgt_epi32(qy, self.minus1),
                ),
            );
            let idx =
                _mm256_and_si256(_mm256_add_epi32(_mm256_mullo_epi32(qy, self.w), qx), inside);
            // 32-bit gathers at byte offset 2 * idx: the low half is the pixel.
            let raw = _mm256_mask_i32gather_epi32::<2>(self.zero, self.base, idx, inside);
            let d = _mm256_and_si256(raw, self.lo16);
            let missing = _mm256_castsi256_ps(_mm256_cmpeq_epi32(d, self.zero));
            _mm256_blendv_ps(_mm256_cvtepi32_ps(d), self.bg, missing)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::depth::DepthStore;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn floor_matches_std() {
        for v in [
            -3.5f32, -3.0, -2.9, -0.5, -0.0, 0.0, 0.49, 0.5, 1.0, 2.5, 1e5, -1e5, 123456.7, 1e9,
        ] {
            assert_eq!(floor_i32(v), v.floor() as i32, "{v}");
        }
        assert!(floor_i32(1e20) >= 1_000_000_000 && floor_i32(-1e20) <= -1_000_000_000);
    }

    #[test]
    fn scalar_probe_reads_the_rounded_pixel_or_background() {
        let mut s = DepthStore::new();
        let mut px: Vec<u16> = (0..20).map(|i| 1000 + i).collect();
        px[13] = 0;
        s.push(5, 4, &px).unwrap();
        let img = s.image(0);
        // 0.5 px rounds up, -0.5 px rounds up (to 0), 1.49 px to 1.
        assert_eq!(probe(&img, 1, 1, [1.0, 0.0], 0.5), 1007.0);
        assert_eq!(probe(&img, 1, 1, [-1.0, 0.0], 0.5), 1006.0);
        assert_eq!(probe(&img, 1, 1, [1.49, 1.0], 1.0), 1012.0);
        assert_eq!(probe(&img, 1, 1, [2.0, 1.0], 1.0), BACKGROUND_MM); // missing
        assert_eq!(probe(&img, 1, 1, [-2.0, 0.0], 1.0), BACKGROUND_MM); // outside
        assert_eq!(probe(&img, 4, 3, [0.0, 0.0], 1.0), 1019.0);
        assert_eq!(probe(&img, 4, 3, [1e30, 0.0], 1.0), BACKGROUND_MM);
    }

    /// The AVX2 probe reads what the scalar one reads: random images with holes, offsets
    /// running off every border (and far beyond the i32 range), missing-depth lanes (inv 0).
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_probe_matches_scalar() {
        use std::arch::x86_64::*;
        if !std::arch::is_x86_feature_detected!("avx2") {
            eprintln!("(no AVX2 here: only the scalar probe is tested)");
            return;
        }
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut s = DepthStore::new();
        for (w, h) in [(7usize, 5usize), (33, 21)] {
            let px: Vec<u16> = (0..w * h)
                .map(|_| {
                    if rng.random_range(0.0..1.0) < 0.2 {
                        0
                    } else {
                        rng.random_range(1..u16::MAX)
                    }
                })
                .collect();
            s.push(w, h, &px).unwrap();
        }
        for i in 0..s.len() {
            let img = s.image(i);
            // SAFETY: AVX2 is available; a DepthStore image.
            let p8 = unsafe { Probe8::new(&img) };
            for _ in 0..2000 {
                let x: [i32; 8] = std::array::from_fn(|_| rng.random_range(-2..img.width + 2));
                let y: [i32; 8] = std::array::from_fn(|_| rng.random_range(-2..img.height + 2));
                let inv: [f32; 8] = std::array::from_fn(|_| match rng.random_range(0..8) {
                    0 => 0.0,
                    _ => 1000.0 / rng.random_range(300.0..8000.0f32),
                });
                let off = |rng: &mut ChaCha8Rng| -> [f32; 8] {
                    std::array::from_fn(|_| match rng.random_range(0..16) {
                        0 => rng.random_range(-1e12..1e12f32),
                        _ => rng.random_range(-150.0..150.0f32),
                    })
                };
                let (ox, oy) = (off(&mut rng), off(&mut rng));
                let mut got = [0f32; 8];
                // SAFETY: AVX2 is available; `img` outlives `p8`.
                unsafe {
                    let d = p8.depth(
                        _mm256_loadu_si256(x.as_ptr() as *const __m256i),
                        _mm256_loadu_si256(y.as_ptr() as *const __m256i),
                        _mm256_loadu_ps(inv.as_ptr()),
                        _mm256_loadu_ps(ox.as_ptr()),
                        _mm256_loadu_ps(oy.as_ptr()),
                    );
                    _mm256_storeu_ps(got.as_mut_ptr(), d);
                }
                let want: [f32; 8] =
                    std::array::from_fn(|l| probe(&img, x[l], y[l], [ox[l], oy[l]], inv[l]));
                assert_eq!(got, want, "x {x:?} y {y:?} inv {inv:?} ox {ox:?} oy {oy:?}");
            }
        }
    }
}
