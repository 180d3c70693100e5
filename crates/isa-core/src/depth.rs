//! Compact depth-image store and part sampling.
//!
//! All images live in one `u16` buffer (millimetres, 0 = missing), so ~2,500 training crops
//! cost two bytes a pixel and nothing per image beyond a 16-byte index entry. A part is
//! `[image index, u, v]` in that image's pixels; its centre depth is the pixel's depth.

use rand::seq::index::sample;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::error::{IsaError, Result};

/// A part: `[image index, u (column), v (row)]`.
pub type Part = [i32; 3];

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct ImageInfo {
    offset: usize,
    width: u32,
    height: u32,
}

/// Borrowed view of one depth image of a [`DepthStore`].
#[derive(Clone, Copy, Debug)]
pub struct ImageRef<'a> {
    pub data: &'a [u16],
    pub width: i32,
    pub height: i32,
}

impl<'a> ImageRef<'a> {
    /// Depth in mm at (u, v); 0 when outside the image or missing.
    #[inline(always)]
    pub fn get(&self, u: i32, v: i32) -> u16 {
        if (u as u32) < (self.width as u32) && (v as u32) < (self.height as u32) {
            // SAFETY: bounds checked above; width*height == data.len() by construction.
            unsafe { *self.data.get_unchecked((v * self.width + u) as usize) }
        } else {
            0
        }
    }
}

/// Many depth images (uint16 mm, row-major) in one contiguous buffer.
#[derive(Clone, Debug, Default)]
pub struct DepthStore {
    data: Vec<u16>,
    index: Vec<ImageInfo>,
}

impl DepthStore {
    pub fn new() -> Self {
        Self::default()
    }

    /// An empty store with room for `images` images of `pixels` pixels in all (no reallocation
    /// while they are pushed, so peak memory is what they need).
    pub fn with_capacity(images: usize, pixels: usize) -> Self {
        DepthStore {
            data: Vec::with_capacity(pixels + 1),
            index: Vec::with_capacity(images),
        }
    }

    /// Appends a `height` x `width` row-major image; returns its index.
    pub fn push(&mut self, width: usize, height: usize, pixels: &[u16]) -> Result<usize> {
        if width == 0 || height == 0 || width > 1 << 15 || height > 1 << 15 {
            return Err(IsaError::InvalidInput(format!(
                "image {}: size {height}x{width} must be between 1x1 and 32768x32768",
                self.index.len()
            )));
        }
        if pixels.len() != width * height {
            return Err(IsaError::InvalidInput(format!(
                "image {}: {} pixels for a {height}x{width} image",
                self.index.len(),
                pixels.len()
            )));
        }
        // `data` always ends with one padding pixel after the last image, so a 32-bit gather
        // at any pixel stays inside the buffer (see `splitter::bins_row`).
        self.data.pop();
        self.index.push(ImageInfo {
            offset: self.data.len(),
            width: width as u32,
            height: height as u32,
        });
        self.data.extend_from_slice(pixels);
        self.data.push(0);
        Ok(self.index.len() - 1)
    }

    pub fn len(&self) -> usize {
        self.index.len()
    }

    pub fn is_empty(&self) -> bool {
        self.index.is_empty()
    }

    /// Total pixels held.
    pub fn n_pixels(&self) -> usize {
        self.data.len().saturating_sub(1)
    }

    /// `(width, height)` of image `i`.
    pub fn dims(&self, i: usize) -> (usize, usize) {
        let info = self.index[i];
        (info.width as usize, info.height as usize)
    }

    /// View of image `i` (panics if out of range; parts are validated before use).
    #[inline(always)]
    pub fn image(&self, i: usize) -> ImageRef<'_> {
        let info = self.index[i];
        let n = info.width as usize * info.height as usize;
        ImageRef {
            data: &self.data[info.offset..info.offset + n],
            width: info.width as i32,
            height: info.height as i32,
        }
    }

    /// Depth of a part's centre pixel (0 if the part is invalid).
    #[inline]
    pub fn center_depth(&self, p: &Part) -> u16 {
        if p[0] < 0 || p[0] as usize >= self.index.len() {
            return 0;
        }
        self.image(p[0] as usize).get(p[1], p[2])
    }

    /// Checks that every part names an existing image, lies inside it and has depth > 0.
    pub fn validate_parts(&self, parts: &[Part]) -> Result<()> {
        for (k, p) in parts.iter().enumerate() {
            if p[0] < 0 || p[0] as usize >= self.len() {
                return Err(IsaError::InvalidInput(format!(
                    "parts[{k}]: image index {} out of range (have {} images)",
                    p[0],
                    self.len()
                )));
            }
            let (w, h) = self.dims(p[0] as usize);
            if p[1] < 0 || p[1] as usize >= w || p[2] < 0 || p[2] as usize >= h {
                return Err(IsaError::InvalidInput(format!(
                    "parts[{k}]: pixel (u={}, v={}) outside image {} of size {h}x{w}",
                    p[1], p[2], p[0]
                )));
            }
            if self.center_depth(p) == 0 {
                return Err(IsaError::InvalidInput(format!(
                    "parts[{k}]: pixel (u={}, v={}) of image {} has no depth (0)",
                    p[1], p[2], p[0]
                )));
            }
        }
        Ok(())
    }
}

/// Samples parts on a regular grid: every pixel with `u % stride == 0 && v % stride == 0` and
/// depth > 0, image by image, row by row.
///
/// * Test time (`max_per_image = None`): every valid pixel on the stride.
/// * Training (`max_per_image = Some(k)`): the same foreground pixels (training crops are
///   rendered foreground-only, so depth > 0 *is* the object mask), then at most `k` of them per
///   image, drawn without replacement from `seed` and the image index, kept in grid order.
pub fn sample_parts(
    store: &DepthStore,
    stride: usize,
    max_per_image: Option<usize>,
    seed: u64,
) -> Result<Vec<Part>> {
    if stride == 0 {
        return Err(IsaError::InvalidParameter(
            "stride must be at least 1".into(),
        ));
    }
    let mut out = Vec::new();
    let mut grid = Vec::new();
    for i in 0..store.len() {
        let img = store.image(i);
        grid.clear();
        for v in (0..img.height).step_by(stride) {
            for u in (0..img.width).step_by(stride) {
                if img.get(u, v) > 0 {
                    grid.push([i as i32, u, v]);
                }
            }
        }
        match max_per_image {
            Some(k) if grid.len() > k => {
                let mut rng =
                    ChaCha8Rng::seed_from_u64(crate::rng::mix(&[seed, i as u64, 0x5eed_9a27]));
                let mut pick: Vec<usize> = sample(&mut rng, grid.len(), k).into_vec();
                pick.sort_unstable();
                out.extend(pick.into_iter().map(|j| grid[j]));
            }
            _ => out.extend_from_slice(&grid),
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn store() -> DepthStore {
        let mut s = DepthStore::new();
        let mut px = vec![0u16; 6 * 4];
        for v in 0..4 {
            for u in 0..6 {
                if u >= 2 {
                    px[v * 6 + u] = 1000 + (v * 6 + u) as u16;
                }
            }
        }
        s.push(6, 4, &px).unwrap();
        s
    }

    #[test]
    fn get_and_bounds() {
        let s = store();
        let im = s.image(0);
        assert_eq!(im.get(2, 1), 1008);
        assert_eq!(im.get(-1, 0), 0);
        assert_eq!(im.get(6, 0), 0);
        assert_eq!(im.get(0, 4), 0);
        assert!(s.validate_parts(&[[0, 2, 1]]).is_ok());
        assert!(s.validate_parts(&[[0, 0, 1]]).is_err());
        assert!(s.validate_parts(&[[1, 2, 1]]).is_err());
        assert!(s.validate_parts(&[[0, 9, 1]]).is_err());
    }

    #[test]
    fn sampling() {
        let s = store();
        let all = sample_parts(&s, 1, None, 0).unwrap();
        assert_eq!(all.len(), 16);
        let st2 = sample_parts(&s, 2, None, 0).unwrap();
        assert_eq!(st2, vec![[0, 2, 0], [0, 4, 0], [0, 2, 2], [0, 4, 2]]);
        let capped = sample_parts(&s, 1, Some(5), 3).unwrap();
        assert_eq!(capped.len(), 5);
        assert_eq!(capped, sample_parts(&s, 1, Some(5), 3).unwrap());
        assert!(capped
            .windows(2)
            .all(|w| (w[0][2], w[0][1]) < (w[1][2], w[1][1])));
    }
}
