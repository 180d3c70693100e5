//! Depth as users have it, to the core's units, with the checks that catch a wrong scale or an
//! image that does not belong to its intrinsics: integer or float values times
//! [`DepthParams::mm_per_unit`] ([`to_mm`], [`to_metres`]), a warning when the scaled depth is
//! implausible for a depth sensor ([`DepthSummary::warning`]), the image size against the
//! intrinsics ([`check_image_size`]), and point clouds projected to a depth image
//! ([`depth_from_points`]). Every front end (binding, CLI) goes through these, so a given input
//! is read and warned about the same way everywhere.

use crate::error::{IsaError, Result};
use crate::params::{DepthParams, Valid};
use crate::vote::Intrinsics;

/// Median depths (metres) outside this range draw a warning: no depth sensor of furniture
/// sees its median pixel nearer than 15 cm or beyond 10 m, while the usual unit mistakes land
/// far outside (millimetres read as metres: x1000; metres as millimetres: /1000; 0.1-mm units as
/// millimetres: x10).
pub const PLAUSIBLE_MEDIAN_M: (f64, f64) = (0.15, 10.0);

/// Depth values as stored: integers (uint16) or floats.
#[derive(Clone, Copy, Debug)]
pub enum DepthValues<'a> {
    U16(&'a [u16]),
    F32(&'a [f32]),
    F64(&'a [f64]),
}

impl DepthValues<'_> {
    pub fn len(&self) -> usize {
        match self {
            DepthValues::U16(v) => v.len(),
            DepthValues::F32(v) => v.len(),
            DepthValues::F64(v) => v.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn is_float(&self) -> bool {
        !matches!(self, DepthValues::U16(_))
    }

    /// Value `i` in metres under `mm_per_unit`; missing (0, negative, non-finite) is 0.
    #[inline]
    fn metres(&self, i: usize, mm_per_unit: f64) -> f64 {
        let v = match self {
            DepthValues::U16(v) => f64::from(v[i]),
            DepthValues::F32(v) => f64::from(v[i]),
            DepthValues::F64(v) => v[i],
        };
        let m = v * mm_per_unit * 1e-3;
        if m.is_finite() && m > 0.0 {
            m
        } else {
            0.0
        }
    }
}

/// What a frame's scaled depth looks like, for [`warning`](Self::warning).
#[derive(Clone, Debug, PartialEq)]
pub struct DepthSummary {
    /// Pixels with depth (finite, > 0).
    pub valid: usize,
    /// Their median depth, metres (over an even subsample of at most 16k pixels).
    pub median_m: Option<f64>,
    /// Pixels dropped as missing because they lie beyond uint16 millimetres (65.535 m).
    pub beyond_range: usize,
    /// The millimetres per unit used, and whether they were given or came from the type.
    pub mm_per_unit: f64,
    pub scale_given: bool,
}

impl DepthSummary {
    fn of(values: DepthValues<'_>, p: &DepthParams, metres: impl Fn(usize) -> f64) -> Self {
        let n = values.len();
        let step = (n / 16384).max(1);
        let mut sample: Vec<f64> = (0..n)
            .step_by(step)
            .map(&metres)
            .filter(|&m| m > 0.0)
            .collect();
        let valid = (0..n).filter(|&i| metres(i) > 0.0).count();
        let median_m = if sample.is_empty() {
            None
        } else {
            let mid = sample.len() / 2;
            Some(*sample.select_nth_unstable_by(mid, f64::total_cmp).1)
        };
        DepthSummary {
            valid,
            median_m,
            beyond_range: 0,
            mm_per_unit: p.mm_per_unit(values.is_float()),
            scale_given: p.depth_scale.is_some(),
        }
    }

    /// A sentence when the depth is implausible for a depth sensor in metres (the median
    /// outside [`PLAUSIBLE_MEDIAN_M`]), naming the scale used and the usual fixes; `None` when
    /// it looks right (or the frame has no depth).
    pub fn warning(&self) -> Option<String> {
        let m = self.median_m?;
        let (lo, hi) = PLAUSIBLE_MEDIAN_M;
        if (lo..=hi).contains(&m) {
            return None;
        }
        let how = if self.scale_given {
            "given"
        } else {
            "the default for this type: 1 for integers, 1000 for floats"
        };
        let lost = if self.beyond_range > 0 {
            format!(
                "; {} of {} pixels lie beyond 65.5 m and are dropped",
                self.beyond_range, self.valid
            )
        } else {
            String::new()
        };
        Some(format!(
            "depth: median {m:.4} m over {} pixels with depth_scale {} mm per unit ({how}){lost}; \
             a depth sensor sees {lo}-{hi} m, so the scale is probably wrong: float millimetres \
             need depth_scale 1, TUM's 5000 per metre 0.2, 0.1-mm sensors 0.1, float metres 1000",
            self.valid, self.mm_per_unit
        ))
    }
}

/// `values` (row-major, `len` = width x height) in uint16 millimetres, the core's image unit
/// (0 = missing; beyond 65.535 m dropped and counted), and their summary.
pub fn to_mm(values: DepthValues<'_>, params: &Valid<DepthParams>) -> (Vec<u16>, DepthSummary) {
    let s = params.mm_per_unit(values.is_float());
    let metres = |i| values.metres(i, s);
    let mut summary = DepthSummary::of(values, params, metres);
    let mm: Vec<u16> = match values {
        // The common case, unchanged values: a copy.
        DepthValues::U16(v) if s == 1.0 => v.to_vec(),
        _ => (0..values.len())
            .map(|i| {
                let mm = (metres(i) * 1000.0).round();
                if mm > 65535.0 {
                    summary.beyond_range += 1;
                    0
                } else {
                    mm as u16
                }
            })
            .collect(),
    };
    (mm, summary)
}

/// `values` in float32 metres (0 = missing) and their summary.
pub fn to_metres(values: DepthValues<'_>, params: &Valid<DepthParams>) -> (Vec<f32>, DepthSummary) {
    let s = params.mm_per_unit(values.is_float());
    let metres = |i| values.metres(i, s);
    let summary = DepthSummary::of(values, params, metres);
    (
        (0..values.len()).map(|i| metres(i) as f32).collect(),
        summary,
    )
}

/// Checks a `width x height` image against its intrinsics and, when the camera states one, its
/// image size. Errors: the stated size differs (saying so when the image is the transpose), or
/// the principal point lies outside the image. Returns a warning when nothing states a size but
/// the principal point sits near the centre of the transposed image and far from this one's (an
/// image transposed against its intrinsics). `source` names where the intrinsics came from.
pub fn check_image_size(
    k: &Intrinsics,
    width: usize,
    height: usize,
    expected: Option<(usize, usize)>,
    source: &str,
) -> Result<Option<String>> {
    let bad = |m: String| Err(IsaError::InvalidInput(m));
    if let Some((w, h)) = expected {
        if (w, h) == (height, width) && w != h {
            return bad(format!(
                "depth image is {width}x{height} (width x height) but {source} gives {w}x{h}: \
                 the image is transposed (rows and columns swapped)"
            ));
        }
        if (w, h) != (width, height) {
            return bad(format!(
                "depth image is {width}x{height} (width x height) but {source} gives {w}x{h}: \
                 wrong-size image for these intrinsics"
            ));
        }
    }
    let off = |w: usize, h: usize| {
        (k.cx - (w as f64 - 1.0) / 2.0).abs() + (k.cy - (h as f64 - 1.0) / 2.0).abs()
    };
    let (here, swapped) = (off(width, height), off(height, width));
    let looks_transposed =
        width != height && swapped < 0.5 * here && here > 0.05 * (width + height) as f64 / 2.0;
    if k.validate_for(width, height).is_err() {
        let hint = if looks_transposed {
            ": the image looks transposed (rows and columns swapped)"
        } else {
            ": wrong-size image for these intrinsics"
        };
        return bad(format!(
            "depth image is {width}x{height} (width x height), but the principal point ({}, {}) \
             of {source} lies outside it{hint}",
            k.cx, k.cy
        ));
    }
    Ok(looks_transposed.then(|| {
        format!(
            "depth image is {width}x{height} (width x height), but the principal point ({}, {}) of \
             {source} is near the centre of a {height}x{width} image: is the image transposed \
             (rows and columns swapped)? Give the image size with the intrinsics to make this an error",
            k.cx, k.cy
        )
    }))
}

/// A float32 metre depth image (0 = missing) of `width x height` from camera-frame points
/// (metres): each point projected through `k`, the nearest kept per pixel. Points behind the
/// camera, non-finite or outside the image are skipped; returns also how many were.
pub fn depth_from_points(
    points: &[[f64; 3]],
    k: &Intrinsics,
    width: usize,
    height: usize,
) -> Result<(Vec<f32>, usize)> {
    k.validate()?;
    if width == 0 || height == 0 {
        return Err(IsaError::InvalidInput(format!(
            "points: image size {width}x{height} must be positive"
        )));
    }
    let mut depth = vec![0f32; width * height];
    let mut skipped = 0;
    for p in points {
        let [x, y, z] = *p;
        if !(x.is_finite() && y.is_finite() && z.is_finite() && z > 0.0) {
            skipped += 1;
            continue;
        }
        let (u, v) = (
            (k.fx * x / z + k.cx + 0.5).floor(),
            (k.fy * y / z + k.cy + 0.5).floor(),
        );
        if !(u >= 0.0 && v >= 0.0 && u < width as f64 && v < height as f64) {
            skipped += 1;
            continue;
        }
        let d = &mut depth[v as usize * width + u as usize];
        let zf = z as f32;
        if *d == 0.0 || zf < *d {
            *d = zf;
        }
    }
    Ok((depth, skipped))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::expect_err;

    fn p(scale: Option<f64>) -> Valid<DepthParams> {
        DepthParams { depth_scale: scale }.check().unwrap()
    }

    #[test]
    fn units_follow_the_scale_and_wrong_scales_warn() {
        // 2 m as the formats store it: uint16 mm, TUM (5000 per metre), float m, float mm.
        let (mm, s) = to_mm(DepthValues::U16(&[2000, 0]), &p(None));
        assert_eq!((mm, s.warning()), (vec![2000, 0], None));
        let (mm, s) = to_mm(DepthValues::U16(&[10000, 0]), &p(Some(0.2)));
        assert_eq!((mm, s.warning()), (vec![2000, 0], None));
        let (m, s) = to_metres(DepthValues::F32(&[2.0, f32::NAN]), &p(None));
        assert_eq!((m, s.warning()), (vec![2.0, 0.0], None));
        let (m, s) = to_metres(DepthValues::F64(&[2000.0, -1.0]), &p(Some(1.0)));
        assert_eq!((m, s.warning()), (vec![2.0, 0.0], None));
        // Float millimetres read as metres: every pixel beyond range, dropped, and said.
        let (mm, s) = to_mm(DepthValues::F32(&[2000.0, 2000.0]), &p(None));
        assert_eq!((mm, s.beyond_range), (vec![0, 0], 2));
        let w = s.warning().unwrap();
        assert!(
            w.contains("median 2000") && w.contains("2 of 2") && w.contains("depth_scale 1,"),
            "{w}"
        );
        // 0.1-mm units read as millimetres: 20 m, in range of uint16 but not of a sensor.
        let (mm, s) = to_mm(DepthValues::U16(&[20000; 3]), &p(None));
        assert_eq!(mm, vec![20000; 3]);
        assert!(s.warning().unwrap().contains("median 20.0000 m"));
        // Metres read as millimetres: 2 mm.
        let (_, s) = to_metres(DepthValues::F32(&[2.0; 4]), &p(Some(1.0)));
        assert!(s.warning().unwrap().contains("(given)"));
        // No depth: nothing to judge.
        assert_eq!(to_mm(DepthValues::U16(&[0; 4]), &p(None)).1.warning(), None);
    }

    #[test]
    fn transposed_images_are_refused_or_warned() {
        let k = Intrinsics {
            fx: 525.0,
            fy: 525.0,
            cx: 319.5,
            cy: 239.5,
        };
        assert_eq!(
            check_image_size(&k, 640, 480, Some((640, 480)), "cam").unwrap(),
            None
        );
        assert_eq!(check_image_size(&k, 640, 480, None, "cam").unwrap(), None);
        expect_err(
            check_image_size(&k, 480, 640, Some((640, 480)), "cam"),
            &["transposed", "cam gives 640x480"],
        );
        expect_err(
            check_image_size(&k, 320, 240, Some((640, 480)), "cam"),
            &["wrong-size"],
        );
        // No stated size: the principal point fits a 480x640 image too, so only a warning.
        let w = check_image_size(&k, 480, 640, None, "cam")
            .unwrap()
            .unwrap();
        assert!(w.contains("transposed"), "{w}");
        // A principal point outside the image is an error, with the transposition named.
        let k2 = Intrinsics {
            cx: 600.0,
            cy: 100.0,
            ..k
        };
        expect_err(
            check_image_size(&k2, 200, 640, None, "cam"),
            &["lies outside", "transposed"],
        );
    }

    #[test]
    fn points_project_back_to_their_depth_image() {
        // The back-projection of a depth image, projected again: the same image (an analytic
        // round trip), with the nearer of two points on one pixel kept.
        let k = Intrinsics {
            fx: 50.0,
            fy: 52.0,
            cx: 9.5,
            cy: 7.0,
        };
        let (w, h) = (20, 15);
        let depth: Vec<f32> = (0..w * h)
            .map(|i| {
                if i % 7 == 0 {
                    0.0
                } else {
                    1.0 + (i % 13) as f32 * 0.1
                }
            })
            .collect();
        let mut pts = Vec::new();
        for v in 0..h {
            for u in 0..w {
                let z = f64::from(depth[v * w + u]);
                if z > 0.0 {
                    pts.push(k.back_project(u as f64, v as f64, z));
                }
            }
        }
        pts.push(k.back_project(3.0, 4.0, 0.5)); // nearer, same pixel
        pts.push([0.0, 0.0, -1.0]); // behind
        pts.push([100.0, 0.0, 1.0]); // outside
        let (got, skipped) = depth_from_points(&pts, &k, w, h).unwrap();
        let mut want = depth.clone();
        want[4 * w + 3] = 0.5;
        assert_eq!(skipped, 2);
        for (a, b) in got.iter().zip(&want) {
            assert!((a - b).abs() < 1e-6, "{a} {b}");
        }
    }
}
